"""Paper 4's network algorithms for extended objects, batched over Monte Carlo runs and nodes.

Every node holds the information of two blocks, the kinematics ``x = [m1, m2, v1, v2]`` and the extent
``p = [alpha, l1, l2]`` (:class:`ExtentInformation`).  One scan step ``k`` processes the points of the
sensors *sequentially*, point index ``i = 1..n_k`` (``n_k``: the most points any sensor of the run saw), as
the paper's algorithms do:

- **CEOT** (Algorithm 1, eqs. 18-19): one centre adds every sensor's contribution of point ``i``, all
  linearised at the same current estimate.
- **CI**, consensus on information (Algorithm 2): a sensor node with an ``i``-th point adds its contribution
  (eqs. 22-23; a relay or a sensor without one keeps its information, eq. 24); then ``L`` rounds of the
  convex combination (Definition 1, Metropolis weights) on ``(q^x, Omega^x, q^p, Omega^p)``.
- **CM**, consensus on measurements (Algorithm 3): the contributions themselves (eq. 25; zero, eq. 26,
  without a point) go through ``L`` rounds of the convex combination, and every node adds ``omega`` times the
  result (eqs. 27-28) with ``omega = |G|`` (the number of nodes, ref. [36]: the centralized filter as
  L -> infinity).
- **DEOT**, the diffusion baseline (ref. [35]): each sensor node runs the sequential MEM-EKF* on its own
  points, then every node replaces its estimate by the equal-weight average of its own and its neighbours'
  means and covariances -- relays included, as if every node observed the object.

After the last point the estimates are read out (Algorithm 2/3 outputs 1-2) and predicted (eqs. 20-21,
computed in moment form, which is the same map).  The orientation ``alpha`` is continuous in the state
(never wrapped), and before every average each sender's ``alpha`` is brought to within pi of the receiver's
own (:func:`align_orientation`), so estimates on either side of +-pi average as angles and a node's
orientation never jumps by 2 pi.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from zentrack.fusion.filters.mem import mem_information_increment, mem_point_update
from zentrack.fusion.linalg import InformationPair, spd_inverse, symmetrize
from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.motion_eot import ExtendedObjectMotion

if TYPE_CHECKING:
    from zentrack.truth.simulation.scenario import ScenarioData

Array = np.ndarray

ALGORITHMS = ("ceot", "ci", "cm", "deot")
ALPHA = 0  # index of the orientation in the extent block


@dataclass
class ExtentInformation:
    """Information of both blocks, stacked: ``ox (..., 4, 4)``, ``qx (..., 4)``, ``op (..., 3, 3)``, ``qp (..., 3)``."""

    ox: Array
    qx: Array
    op: Array
    qp: Array

    def moments(self) -> tuple[Array, Array, Array, Array]:
        """``(x, C^x, p, C^p)`` (Algorithm 2, outputs 1-2)."""
        cx = spd_inverse(self.ox)
        cp = spd_inverse(self.op)
        return np.einsum("...ij,...j->...i", cx, self.qx), cx, np.einsum("...ij,...j->...i", cp, self.qp), cp

    @classmethod
    def from_moments(cls, x: Array, cx: Array, p: Array, cp: Array) -> ExtentInformation:
        ox, op = spd_inverse(cx), spd_inverse(cp)
        return cls(ox, np.einsum("...ij,...j->...i", ox, x), op, np.einsum("...ij,...j->...i", op, p))

    def plus(self, kin: InformationPair, ext: InformationPair, scale: float | Array = 1.0) -> ExtentInformation:
        """This information plus ``scale`` times the contributions (eqs. 22-23, 27-28)."""
        s = np.asarray(scale, dtype=float)
        return ExtentInformation(self.ox + s[..., None, None] * kin.matrix, self.qx + s[..., None] * kin.vector,
                                 self.op + s[..., None, None] * ext.matrix, self.qp + s[..., None] * ext.vector)

    def where(self, mask: Array, other: ExtentInformation) -> ExtentInformation:
        """Rows of ``self`` where ``mask`` (leading axes), else ``other``'s."""
        return ExtentInformation(np.where(mask[..., None, None], self.ox, other.ox),
                                 np.where(mask[..., None], self.qx, other.qx),
                                 np.where(mask[..., None, None], self.op, other.op),
                                 np.where(mask[..., None], self.qp, other.qp))


def align_orientation(alpha: Array, weights: Array) -> Array:
    """Sender orientations as each receiver averages them: ``(R, M)`` -> ``(R, receivers, senders)`` with
    ``alpha_j`` moved by multiples of 2 pi to within pi of the receiver's own (so it never jumps at +-pi)."""
    ref = alpha[:, : np.shape(weights)[0]]  # (R, receivers)
    return ref[:, :, None] + wrap_angle(alpha[:, None, :] - ref[:, :, None])


def _combine_info(info: ExtentInformation, weights: Array) -> ExtentInformation:
    """One round of Definition 1 on ``(R, M, ...)`` stacks: receiver s gets ``sum_j pi_sj (.)_j``.  The extent's
    information vector is re-formed from each sender's aligned orientation (:func:`align_orientation`)."""
    _, _, p, _ = info.moments()
    aligned = align_orientation(p[..., ALPHA], weights)  # (R, s, j)
    shift = aligned - p[:, None, :, ALPHA]  # what each sender's alpha moves by, per receiver
    # q^p = Omega^p p: moving alpha by d adds Omega^p[:, alpha] d
    qp = info.qp[:, None, :, :] + info.op[:, None, :, :, ALPHA] * shift[..., None]  # (R, s, j, 3)
    return ExtentInformation(
        np.einsum("st,rtij->rsij", weights, info.ox), np.einsum("st,rti->rsi", weights, info.qx),
        np.einsum("st,rtij->rsij", weights, info.op), np.einsum("st,rsti->rsi", weights, qp),
    )


def _combine_pairs(kin: InformationPair, ext: InformationPair, weights: Array) -> tuple[InformationPair, InformationPair]:
    """One round of Definition 1 on contributions (CM): a plain weighted sum (they are linear in the points)."""
    return (InformationPair(np.einsum("st,rtij->rsij", weights, kin.matrix), np.einsum("st,rti->rsi", weights, kin.vector)),
            InformationPair(np.einsum("st,rtij->rsij", weights, ext.matrix), np.einsum("st,rti->rsi", weights, ext.vector)))


def _reshape(pair: InformationPair, shape: tuple[int, ...]) -> InformationPair:
    n = pair.vector.shape[-1]
    return InformationPair(pair.matrix.reshape(shape + (n, n)), pair.vector.reshape(shape + (n,)))


@dataclass
class EotResult:
    """Per run, step and node (``M = 1`` for CEOT): the read-out estimates after the scan's last point."""

    algorithm: str
    x: Array  # (R, K, M, 4)
    cx: Array  # (R, K, M, 4, 4)
    p: Array  # (R, K, M, 3)
    cp: Array  # (R, K, M, 3, 3)
    wall_s: float = 0.0  # set by a caller that times the run (the fusion core reads no clock)


def run_eot_network(
    algorithm: str,
    points: Array,
    counts: Array,
    is_sensor: Array,
    weights: Array,
    motion: ExtendedObjectMotion,
    noise_cov: Array,
    spread: Array,
    x0: Array,
    cx0: Array,
    p0: Array,
    cp0: Array,
    rounds: int = 6,
    adjacency: Array | None = None,
) -> EotResult:
    """Run ``algorithm`` (one of :data:`ALGORITHMS`) over every run.

    ``points (R, K, M, J, 2)`` padded scans, ``counts (R, K, M)`` (0 for relays), ``is_sensor (M,)``,
    ``weights (M, M)`` the consensus weights (CI, CM), ``noise_cov (2, 2)`` C^v, ``spread (2, 2)`` C^h,
    ``x0 (R, 4)``, ``p0 (R, 3)`` the runs' initial estimates with covariances ``cx0 (4, 4)``, ``cp0 (3, 3)``.
    ``adjacency (M, M)`` is DEOT's graph (default: where ``weights`` is non-zero off the diagonal).
    """
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {algorithm!r}")
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    r_runs, k_steps, m_nodes, _, _ = points.shape
    counts = np.where(np.asarray(is_sensor, dtype=bool)[None, None, :], counts, 0)
    nodes = 1 if algorithm == "ceot" else m_nodes
    out_x = np.empty((r_runs, k_steps, nodes, 4))
    out_cx = np.empty((r_runs, k_steps, nodes, 4, 4))
    out_p = np.empty((r_runs, k_steps, nodes, 3))
    out_cp = np.empty((r_runs, k_steps, nodes, 3, 3))
    x = np.repeat(np.asarray(x0, float)[:, None], nodes, axis=1)
    p = np.repeat(np.asarray(p0, float)[:, None], nodes, axis=1)
    cx = np.broadcast_to(cx0, (r_runs, nodes, 4, 4)).copy()
    cp = np.broadcast_to(cp0, (r_runs, nodes, 3, 3)).copy()
    if adjacency is None:
        adjacency = (np.asarray(weights) > 0) & ~np.eye(m_nodes, dtype=bool)
    equal = (np.asarray(adjacency, bool) | np.eye(m_nodes, dtype=bool)).astype(float)
    equal /= equal.sum(axis=1, keepdims=True)  # DEOT: equal weights over the closed neighbourhood
    for k in range(k_steps):
        n_k = counts[:, k].max(axis=1)  # (R,) the points processed this step
        if algorithm == "deot":
            x, cx, p, cp = _deot_step(points[:, k], counts[:, k], x, cx, p, cp, equal, noise_cov, spread)
        else:
            info = ExtentInformation.from_moments(x, cx, p, cp)
            for i in range(int(n_k.max(initial=0))):
                active = i < n_k  # (R,) runs that still have an i-th point somewhere
                has = i < counts[:, k]  # (R, M)
                info = _point_step(algorithm, info, points[:, k, :, i], has, active, weights, rounds,
                                   noise_cov, spread, m_nodes)
            x, cx, p, cp = info.moments()
        out_x[:, k], out_cx[:, k], out_p[:, k], out_cp[:, k] = x, cx, p, cp
        x, cx = x @ motion.A[:4, :4].T, symmetrize(motion.A[:4, :4] @ cx @ motion.A[:4, :4].T + motion.Q[:4, :4])
        cp = symmetrize(cp + motion.Q[4:, 4:])  # F^p = I (eq. 21)
    return EotResult(algorithm, out_x, out_cx, out_p, out_cp)


def _increments(info: ExtentInformation, y: Array, has: Array, noise_cov: Array, spread: Array,
                at: tuple[Array, Array, Array, Array] | None = None) -> tuple[InformationPair, InformationPair]:
    """Every row's contribution of its point ``y (..., 2)`` (zero where not ``has``), linearised at its own
    estimate (or at ``at``)."""
    x, cx, p, cp = info.moments() if at is None else at
    lead = has.shape
    b = int(np.prod(lead))
    kin, ext = mem_information_increment(
        x.reshape(b, 4), cx.reshape(b, 4, 4), p.reshape(b, 3), cp.reshape(b, 3, 3),
        y.reshape(b, 1, 2), has.reshape(b, 1), noise_cov, spread)
    return _reshape(kin, lead), _reshape(ext, lead)


def _point_step(algorithm: str, info: ExtentInformation, y: Array, has: Array, active: Array, weights: Array,
                rounds: int, noise_cov: Array, spread: Array, m_nodes: int) -> ExtentInformation:
    """Point ``i`` of one step: CEOT (eqs. 18-19), CI (eqs. 22-24 and L rounds), CM (eqs. 25-28)."""
    if algorithm == "ceot":  # every sensor's contribution at the centre's one estimate
        x, cx, p, cp = info.moments()
        at = (np.repeat(x, m_nodes, axis=1), np.repeat(cx, m_nodes, axis=1), np.repeat(p, m_nodes, axis=1),
              np.repeat(cp, m_nodes, axis=1))
        kin, ext = _increments(info, y, has, noise_cov, spread, at)  # (R, M, ...)
        return info.plus(InformationPair(kin.matrix.sum(1, keepdims=True), kin.vector.sum(1, keepdims=True)),
                         InformationPair(ext.matrix.sum(1, keepdims=True), ext.vector.sum(1, keepdims=True)))
    kin, ext = _increments(info, y, has, noise_cov, spread)
    if algorithm == "ci":
        info = info.plus(kin, ext)
        for _ in range(rounds):
            info = _combine_info(info, weights).where(active[:, None], info)
        return info
    for _ in range(rounds):  # CM: zero contributions average to zero, so inactive runs need no mask
        kin, ext = _combine_pairs(kin, ext, weights)
    return info.plus(kin, ext, scale=float(m_nodes))


def _deot_step(points: Array, counts: Array, x: Array, cx: Array, p: Array, cp: Array, equal: Array,
               noise_cov: Array, spread: Array) -> tuple[Array, Array, Array, Array]:
    """DEOT: sequential MEM-EKF* on each sensor's own points, then the equal-weight average of the closed
    neighbourhood's means and covariances (orientation aligned as in CI)."""
    r, m = counts.shape
    b = r * m
    xs, cxs, ps, cps = x.reshape(b, 4), cx.reshape(b, 4, 4), p.reshape(b, 3), cp.reshape(b, 3, 3)
    flat_counts = counts.reshape(b)
    flat_points = points.reshape(b, points.shape[2], 2)
    for i in range(int(flat_counts.max(initial=0))):
        has = i < flat_counts
        nx, ncx, npp, ncp = mem_point_update(xs, cxs, ps, cps, flat_points[:, i], noise_cov, spread)
        xs, cxs = np.where(has[:, None], nx, xs), np.where(has[:, None, None], ncx, cxs)
        ps, cps = np.where(has[:, None], npp, ps), np.where(has[:, None, None], ncp, cps)
    x, cx, p, cp = xs.reshape(r, m, 4), cxs.reshape(r, m, 4, 4), ps.reshape(r, m, 3), cps.reshape(r, m, 3, 3)
    aligned = align_orientation(p[..., ALPHA], equal)  # (R, s, j)
    p_send = np.repeat(p[:, None], m, axis=1)
    p_send[..., ALPHA] = aligned
    return (np.einsum("st,rti->rsi", equal, x), np.einsum("st,rtij->rsij", equal, cx),
            np.einsum("st,rsti->rsi", equal, p_send), np.einsum("st,rtij->rsij", equal, cp))


def run_eot_scenario(algorithm: str, scn: ScenarioData, rounds: int = 6) -> EotResult:
    """:func:`run_eot_network` on an extended-object scenario (``plant = "eot"``; its scans, network, noise and
    the runs' initial estimates)."""
    if scn.plant != "eot" or scn.scan_returns is None or scn.scan_counts is None:
        raise ValueError(f"scenario {scn.name!r} is not an extended-object scenario (plant 'eot' with scans)")
    motion: Any = scn.motion_model()
    measurement: Any = scn.measurement_model()
    return run_eot_network(
        algorithm, scn.scan_returns, scn.scan_counts, np.asarray(scn.roles) == "sensor", scn.weights,
        motion, scn.noise_cov[0], np.asarray(measurement.spread, dtype=float), scn.x0_estimate[:, :4],
        scn.p0[:4, :4], scn.x0_estimate[:, 4:], scn.p0[4:, 4:], rounds=rounds, adjacency=scn.adjacency)
