"""Track initiation for bearing-only sensors: triangulating a node's leftover returns with its neighbours'.

A bearing return ``z = (az, el)`` of a sensor at ``p`` is a ray ``p + r u(z)``,
``u = (cos el cos az, cos el sin az, sin el)`` (the convention of :func:`~zentrack.fusion.measurement.bearing`).
:class:`TriangulationInitiator` pairs every return no track gated in the node's own scan (``births_from_returns``)
with the same step's leftover returns of its neighbours' scans (:meth:`TriangulationInitiator.add_neighbour_scans`,
or scans of other sensors handed to ``births_from_returns`` before the own one, as a tracker stepping on
``[neighbours..., own]`` does).

**Every sensor's.** A tracker that takes every sensor's scan of a step (a centralized one,
:func:`~zentrack.fusion.multitarget.central.make_central_tracker`) has no own sensor (``sensor=None``): each
scan's leftovers in turn are the own returns, triangulated with the leftovers of the step's scans before it,
and then join them as partners of the scans after it. The rays a birth took (its own return and its partners)
leave that pool, so each ray starts at most one track: a target seen by many sensors starts once, as soon as
three of its rays have come in (with ``require_confirmation``). Every pair of scans is thus met once, not once
per own sensor.

**Pair gate.** Two rays ``p_a + s u_a``, ``p_b + t u_b`` come closest at ``s = (b e - d) / (1 - b^2)``,
``t = (e - b d) / (1 - b^2)`` (``b = u_a.u_b``, ``d = u_a.(p_a - p_b)``, ``e = u_b.(p_a - p_b)``), their miss
``delta = n.(q_a - q_b)`` along the common normal ``n = u_a x u_b / |u_a x u_b|``. A ray's point at range ``r``
is off by ``J v``, ``J = r [cos(el) e_az, e_el]`` (``e_az``, ``e_el`` the unit vectors of growing azimuth and
elevation, ``v ~ N(0, R)`` the angular noise), so ``delta`` has variance ``sigma^2 = n^T (J_a R_a J_a^T +
J_b R_b J_b^T) n`` and a pair is kept when ``delta^2 / sigma^2 <= chi2_1(P_G)``, both ranges are positive (in
front of both sensors) and at most ``max_range``. Near-parallel rays (``1 - b^2`` tiny) are refused.

**Position and covariance.** The pair's point is the midpoint of the closest approach (the midpoint method,
Hartley & Zisserman 2004, Ch. 12), refined by Gauss-Newton on the angles of every ray kept for it (the maximum
likelihood triangulation; its covariance is the inverse Fisher information, the Cramer-Rao bound, Bar-Shalom,
Li & Kirubarajan 2001, Ch. 2-3, as for bearings-only localisation in Bar-Shalom, Willett & Tian 2011): with
``H_i = dh/dx`` the bearing Jacobian at ``x`` (:func:`~zentrack.fusion.measurement.bearing_linearize`),

    P = (sum_i H_i^T R_i^-1 H_i)^-1,    x <- x + P sum_i H_i^T R_i^-1 W(z_i - h(x, p_i)),

``P`` the inverse Fisher information at the estimate (the Cramer-Rao bound, which the linearised ML estimate
attains when the angular errors are small against the ray angle: the Jacobian of the triangulation w.r.t. the
angles times ``R``). The fit's ``sum_i |W(z_i - h(x))|^2_{R_i^-1}`` is ``chi2_{2N-3}`` for ``N`` rays of one
target. The velocity is unknown: mean 0 and ``prior_cov``'s velocity block; the other components from
``prior_cov`` too (no cross terms).

**Ghosts** (rays of different targets meeting within the gate) are what kills bearing triangulation with many
targets. What it does: (1) each own return takes at most one return of each neighbour and each neighbour return
serves at most one own return, by 2-D assignment on ``chi2_1(P_G) - delta^2/sigma^2``
(:func:`~zentrack.fusion.multitarget.gnn.best_assignment`); (2) a pair whose point a third sensor's return
confirms (inside that return's 2-D gate ``nu^T (H P H^T + R)^-1 nu <= chi2_2(P_G)``) gets a bonus of
``chi2_1(P_G)`` in that assignment, so confirmed points win over unconfirmed ones; (3) the rays an own return
keeps from several neighbours are fitted together and kept only if the fit passes ``chi2_{2N-3}(P_G)``, else
only its best pair is kept; (4) ``require_confirmation`` starts tracks only from confirmed points (or fits of
three rays or more); (5) a birth needs a neighbour ray no track gated ("fresh"). What it does
not: it does not enumerate the S-D assignment over all sensors (ranked hypotheses), so a ghost that no third
ray contradicts can start a tentative track; M-of-N confirmation (:mod:`.lifecycle`) kills it when the next
scans do not follow it, but a ghost two sensors keep seeing consistently (slow targets) is held by their
returns, and a tracker counts a hit from any one scan, so it can live on (see the tests' counts): the centralized
tracker deletes a held track without a third ray (:class:`~.lifecycle.RayConfirmationDeleter`), a node does not.
It knows nothing of the tracks: a target two sensors see on one line of sight gives one return there.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..linalg import GaussianState
from ..measurement import MeasurementModel, bearing_linearize, wrap_angle
from ..scan import Scan
from .base import Birth, Initiator, check_gaussian
from .gating import gate_gamma, scan_likelihood
from .gnn import best_assignment

Array = np.ndarray
#: rays closer to parallel than this (``1 - (u_a.u_b)^2``) locate nothing
PARALLEL = 1e-8


def ray_directions(returns: Array) -> Array:
    """Unit directions ``(J, 3)`` of bearing returns ``(J, 2)`` (azimuth, elevation)."""
    az, el = returns[:, 0], returns[:, 1]
    return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def ray_point_jacobian(returns: Array, ranges: Array) -> Array:
    """``J = d(p + r u)/d(az, el)`` ``(..., 3, 2)`` at ``ranges`` ``(...)`` along the rays of ``returns`` ``(..., 2)``."""
    az, el = returns[..., 0], returns[..., 1]
    e_az = np.stack([-np.sin(az), np.cos(az), np.zeros_like(az)], axis=-1)
    e_el = np.stack([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)], axis=-1)
    return ranges[..., None, None] * np.stack([np.cos(el)[..., None] * e_az, e_el], axis=-1)


def closest_approach(pa: Array, za: Array, ra: Array, pb: Array, zb: Array, rb: Array) -> tuple[Array, ...]:
    """Every pair of rays of ``za`` ``(A, 2)`` from ``pa`` and ``zb`` ``(B, 2)`` from ``pb`` (noises ``ra``,
    ``rb``): the ranges ``s``, ``t``, the midpoints ``(A, B, 3)`` and the miss statistic ``delta^2 / sigma^2``
    (module docstring), all ``(A, B)`` but the points; near-parallel pairs get ``inf``."""
    ua, ub = ray_directions(za)[:, None, :], ray_directions(zb)[None, :, :]
    w0 = pa - pb
    b = np.sum(ua * ub, axis=-1)
    d, e = ua @ w0, ub @ w0
    denom = 1.0 - b**2
    ok = denom > PARALLEL
    safe = np.where(ok, denom, 1.0)
    s, t = (b * e - d) / safe, (e - b * d) / safe
    qa, qb = pa + s[..., None] * ua, pb + t[..., None] * ub
    normal = np.cross(ua, ub)
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-300)
    delta = np.sum((qa - qb) * normal, axis=-1)
    ja = ray_point_jacobian(np.broadcast_to(za[:, None, :], s.shape + (2,)), s)
    jb = ray_point_jacobian(np.broadcast_to(zb[None, :, :], t.shape + (2,)), t)
    na, nb = np.einsum("abk,abkm->abm", normal, ja), np.einsum("abk,abkm->abm", normal, jb)
    var = np.einsum("abm,mn,abn->ab", na, ra, na) + np.einsum("abm,mn,abn->ab", nb, rb, nb)
    stat = np.where(ok, delta**2 / np.maximum(var, 1e-300), np.inf)
    return s, t, 0.5 * (qa + qb), stat


def information(x: Array, poses: Array, noises: Sequence[Array]) -> tuple[Array, Array]:
    """``sum_i H_i^T R_i^-1 H_i`` ``(B, 3, 3)`` of positions ``x`` ``(B, 3)`` seen by ``poses`` ``(N, 3)``, and the
    predicted bearings ``(B, N, 2)``."""
    b, n = x.shape[0], poses.shape[0]
    z, jac = bearing_linearize(x, np.broadcast_to(poses, (b, n, 3)), 3)
    jac = jac.reshape(b, n, 2, 3)
    r_inv = np.stack([np.linalg.inv(r) for r in noises])
    return np.einsum("bnki,nkl,bnlj->bij", jac, r_inv, jac), z.reshape(b, n, 2)


def triangulate(x0: Array, poses: Array, returns: Array, noises: Sequence[Array], iterations: int = 3
                ) -> tuple[Array, Array, float]:
    """Maximum-likelihood point ``(3,)`` of rays ``returns`` ``(N, 2)`` from ``poses`` ``(N, 3)`` by Gauss-Newton from
    ``x0``, its covariance ``(3, 3)`` (the inverse information) and the fit's chi-square (module docstring)."""
    x = np.asarray(x0, dtype=float)
    r_inv = [np.linalg.inv(r) for r in noises]
    for it in range(iterations + 1):
        z, jac = bearing_linearize(x[None], poses[None], 3)
        jac, nu = jac[0].reshape(-1, 2, 3), wrap_angle(returns - z[0].reshape(-1, 2))
        info = np.einsum("nki,nkl,nlj->ij", jac, np.stack(r_inv), jac)
        grad = np.einsum("nki,nkl,nl->i", jac, np.stack(r_inv), nu)
        cov = np.linalg.inv(info)
        chi2 = float(sum(v @ ri @ v for ri, v in zip(r_inv, nu)))
        if it < iterations:
            x = x + cov @ grad
    return x, 0.5 * (cov + cov.T), chi2


def returns_outside_gates(measurement: MeasurementModel, state: GaussianState, scan: Scan, gamma: float) -> Scan:
    """``scan`` with only the returns inside no track's gate (``state``: the tracks predicted to its step): what a
    node whose tracker does not update on a neighbour's scan hands to :meth:`TriangulationInitiator.add_neighbour_scans`."""
    lik = scan_likelihood(measurement, state, scan, gamma)
    keep = ~lik.gated.any(axis=0)
    return Scan(scan.step, scan.sensor, scan.returns[keep], scan.pose, scan.noise_cov)


class TriangulationInitiator(Initiator):
    """Births from the own scan's leftovers triangulated with the neighbours' (module docstring).

    ``sensor``: the own sensor's index (a scan of another sensor given to ``births_from_returns`` is taken as a
    neighbour's leftovers of that step), or None for a tracker of every sensor's scans (module docstring,
    **Every sensor's**); ``prior_cov`` ``(6, 6)``: position-velocity prior (its velocity block is a
    birth's); ``max_range``: the sensing range (inf: none); ``require_confirmation``: only points a third ray
    confirms start tracks."""

    def __init__(self, sensor: int | None, prior_cov: Array, max_range: float = math.inf, gate_prob: float = 0.999,
                 require_confirmation: bool = False) -> None:
        super().__init__()
        k = np.shape(prior_cov)[0] if np.ndim(prior_cov) == 2 else 0
        _, self.prior_cov = check_gaussian(np.zeros(k), prior_cov, "prior_cov")
        if k < 3:
            raise ValueError(f"prior_cov must cover position (3) at least, got {k} components")
        if not max_range > 0:
            raise ValueError(f"max_range must be positive, got {max_range}")
        self.sensor = None if sensor is None else int(sensor)
        self.max_range, self.require_confirmation = float(max_range), require_confirmation
        self.gamma1, self.gamma2 = gate_gamma(1, gate_prob), gate_gamma(2, gate_prob)
        self.gate_prob = float(gate_prob)
        #: sensor -> its returns to pair with at step ``_step`` and which of them are fresh (no track's)
        self._neighbours: dict[int, tuple[Scan, Array]] = {}
        self._step: int | None = None

    def add_neighbour_scans(self, step: int, scans: Sequence[Scan]) -> None:
        """The neighbours' returns of ``step`` to pair the own leftovers with (scans of other sensors, returns
        ``(J, 2)``): their leftovers (:func:`returns_outside_gates`), or all their returns. In the latter case
        the leftovers of the same scans the tracker hands to ``births_from_returns`` (a tracker that updates on
        them) mark which are fresh: a birth needs a fresh neighbour ray, the others may be held by tracks (a
        return a track holds can be a second target's on the same line of sight of that neighbour)."""
        self._start(step)
        for scan in scans:
            if scan.sensor != self.sensor:
                self._neighbours[scan.sensor] = (scan, np.ones(scan.count, dtype=bool))

    def _start(self, step: int) -> None:
        if self._step != step:
            self._neighbours, self._step = {}, step

    def births_from_returns(self, returns: Array, scan: Scan, step: int) -> list[Birth]:
        if self.sensor is not None and scan.sensor != self.sensor:  # a neighbour's leftovers
            self._start(step)
            returns = np.asarray(returns, dtype=float).reshape(-1, 2)
            given = self._neighbours.get(scan.sensor)
            if given is None:
                self._neighbours[scan.sensor] = (Scan(step, scan.sensor, returns, scan.pose, scan.noise_cov),
                                                 np.ones(len(returns), dtype=bool))
            else:
                fresh = (given[0].returns[:, None, :] == returns[None, :, :]).all(axis=-1).any(axis=1)
                self._neighbours[scan.sensor] = (given[0], given[1] & fresh)
            return []
        own = np.asarray(returns, dtype=float).reshape(-1, 2)
        held = [(j, h) for j, h in self._neighbours.items() if h[0].count] if self._step == step else []
        births, used_own, used = self._triangulate(own, scan, [h[0] for _, h in held], [h[1] for _, h in held])
        if self.sensor is not None:
            self._neighbours, self._step = {}, None
            return births
        self._start(step)  # every sensor's: the rays no birth took are the next scans' partners
        for (j, (nb, fresh)), taken in zip(held, used):
            keep = np.ones(nb.count, dtype=bool)
            keep[taken] = False
            self._neighbours[j] = (Scan(step, j, nb.returns[keep], nb.pose, nb.noise_cov), fresh[keep])
        keep = np.ones(len(own), dtype=bool)
        keep[used_own] = False
        self._neighbours[scan.sensor] = (Scan(step, scan.sensor, own[keep], scan.pose, scan.noise_cov),
                                         np.ones(int(keep.sum()), dtype=bool))
        return births

    def _triangulate(self, own: Array, scan: Scan, neighbours: list[Scan], fresh: list[Array]
                     ) -> tuple[list[Birth], list[int], list[list[int]]]:
        """The births of the own returns ``own`` with the neighbours' rays (module docstring), the own returns
        they took and, per neighbour, its returns they took."""
        used_own: list[int] = []
        used: list[list[int]] = [[] for _ in neighbours]
        if not len(own) or not neighbours or not any(f.any() for f in fresh):
            return [], used_own, used
        pairs = [self._pairs(own, scan, nb) for nb in neighbours]
        scores = []
        for i, (stat, ok, mid, cov) in enumerate(pairs):
            confirmed = np.zeros(ok.shape, dtype=bool)
            for j, other in enumerate(neighbours):
                if j != i:
                    confirmed |= self._confirmed(mid, cov, ok, other)
            scores.append((self.gamma1 - stat + self.gamma1 * confirmed, confirmed))
        chosen = [best_assignment(score, ok) for (score, _), (_, ok, _, _) in zip(scores, pairs)]
        births = []
        for a in range(len(own)):
            rays = [(i, int(c[a])) for i, c in enumerate(chosen) if c[a] >= 0]
            rays = [r for r in rays if fresh[r[0]][r[1]]] + [r for r in rays if not fresh[r[0]][r[1]]]
            if not rays or not fresh[rays[0][0]][rays[0][1]]:
                continue
            n_fresh = sum(bool(fresh[i][b]) for i, b in rays)
            fit = self._fit(own[a], scan, [(neighbours[i], b) for i, b in rays], pairs, rays, a, scores, n_fresh)
            if fit is not None:
                births.append(fit[0])
                used_own.append(a)
                for u in fit[1]:
                    used[rays[u][0]].append(rays[u][1])
        return births, used_own, used

    def _pairs(self, own: Array, scan: Scan, nb: Scan) -> tuple[Array, Array, Array, Array]:
        """Miss statistic, gate mask, midpoints and (inside the gate) their covariances of own x neighbour
        returns."""
        s, t, mid, stat = closest_approach(scan.pose, own, scan.noise_cov, nb.pose, nb.returns, nb.noise_cov)
        ok = (stat <= self.gamma1) & (s > 0) & (t > 0) & (s <= self.max_range) & (t <= self.max_range)
        cov = np.zeros(mid.shape + (3,))
        if ok.any():
            info, _ = information(mid[ok], np.stack([scan.pose, nb.pose]), [scan.noise_cov, nb.noise_cov])
            det = np.linalg.det(info)
            good = np.isfinite(det) & (det > 0)
            cov.reshape(-1, 3, 3)[np.flatnonzero(ok)[good]] = np.linalg.inv(info[good])
            ok[ok] = good
        return stat, ok, mid, cov

    def _confirmed(self, mid: Array, cov: Array, ok: Array, other: Scan) -> Array:
        """``(A, B)``: the pair is in the gate (``ok``) and some return of ``other`` lies in the 2-D gate of the
        pair's point seen from its sensor."""
        out = np.zeros(ok.shape, dtype=bool)
        if not ok.any() or not other.count:
            return out
        flat, pcov = mid[ok], cov[ok]
        z, jac = bearing_linearize(flat, np.broadcast_to(other.pose, (flat.shape[0], 1, 3)), 3)
        s = np.einsum("bki,bij,blj->bkl", jac, pcov, jac) + other.noise_cov
        nu = wrap_angle(other.returns[None, :, :] - z[:, None, :])  # (P, C, 2)
        d2 = np.einsum("bck,bkl,bcl->bc", nu, np.linalg.inv(s), nu)
        seen = np.linalg.norm(flat - other.pose, axis=-1) <= self.max_range
        out[ok] = (d2 <= self.gamma2).any(axis=1) & seen
        return out

    def _fit(self, z_own: Array, scan: Scan, partners: list[tuple[Scan, int]],
             pairs: list[tuple[Array, Array, Array, Array]], rays: list[tuple[int, int]], a: int,
             scores: list[tuple[Array, Array]], n_fresh: int) -> tuple[Birth, list[int]] | None:
        """The birth of one own return and its partner rays (the first ``n_fresh`` fresh): all rays fitted
        together if they agree, else the best-scoring pair with a fresh ray alone; and which of ``rays`` it took."""
        best = max(range(len(rays)), key=lambda r: (r < n_fresh, scores[rays[r][0]][0][a, rays[r][1]]))
        attempts = [list(range(len(rays)))] + ([[best]] if len(rays) > 1 else [])
        for use in attempts:
            poses = np.stack([scan.pose] + [partners[u][0].pose for u in use])
            zs = np.stack([z_own] + [partners[u][0].returns[partners[u][1]] for u in use])
            noises = [scan.noise_cov] + [partners[u][0].noise_cov for u in use]
            i0, b0 = rays[use[0]]
            x, pcov, chi2 = triangulate(pairs[i0][2][a, b0], poses, zs, noises)
            if chi2 <= gate_gamma(2 * len(zs) - 3, self.gate_prob) and np.all(np.isfinite(x)):
                confirmed = len(zs) >= 3 or bool(scores[i0][1][a, b0])
                if self.require_confirmation and not confirmed:
                    return None
                return self._birth(x, pcov), use
        return None

    def _birth(self, x: Array, pcov: Array) -> Birth:
        k = self.prior_cov.shape[0]
        mean = np.zeros(k)
        mean[:3] = x
        cov = self.prior_cov.copy()
        cov[:3, :] = 0.0
        cov[:, :3] = 0.0
        cov[:3, :3] = pcov
        return Birth(mean, cov)
