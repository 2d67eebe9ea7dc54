"""Paper 4's scenarios (S2 ellipse, S3 rectangle) as :class:`~zentrack.truth.simulation.scenario.ScenarioData`.

The object follows the paper's S2 path (:func:`~zentrack.truth.simulation.eot_scenario.s2_trajectory`: headings -pi/4, 0,
pi/2, pi with the stated turns, 103 scans of T = 10 s at 500/36 m/s), aligned with its velocity
(``alpha`` = heading), with the scenario's semi-axes.  The truth ``[m1, m2, v1, v2, alpha, l1, l2]`` is the
same in every run (the path is given, not drawn); what a run draws is the scans and the initial estimate:

- each sensor node sees the object at every scan (the paper's simulations give its sensors no field-of-view
  limit) and gets a Poisson(``rate``) number of points ``y = m + S h + v``, ``h`` uniform on the unit disc
  (ellipse) or the square ``[-1, 1]^2`` (rectangle), ``v ~ N(0, C^v)``
  (:func:`~zentrack.truth.simulation.eot_scenario.sample_extent_points`), capped at ``max_points``;
- the initial estimate is drawn from the prior around the truth at the first scan, ``N(truth_1, P0)``
  (the paper gives the prior covariances, not how its initial estimates were drawn).

The network (``nodes`` nodes of which ``sensors`` measure, links up to ``link_range``, Metropolis weights)
is placed once from ``network_seed`` (:func:`~zentrack.truth.simulation.eot_scenario.place_network`) and is the same in
every run; the other nodes are relays.  Run ``r`` draws from child ``r`` of ``SeedSequence(seed)`` alone.
"""
from __future__ import annotations

from typing import Literal

import numpy as np

from zentrack.fusion.extent import shape_factor
from zentrack.fusion.graphs import is_connected, metropolis_weights, radius_adjacency
from zentrack.fusion.models import EXTENT_MEASUREMENTS  # measurement kind -> (object shape, C^h)

from .scenario import ScenarioData
from .scenario_spec import ScenarioSpec

Array = np.ndarray


def extent_truth(spec: ScenarioSpec, ts: float) -> Array:
    """The true state ``(K, 7)`` ``[m1, m2, v1, v2, alpha, l1, l2]`` along the S2 path."""
    assert spec.extent is not None
    centres, velocities, headings = s2_trajectory(spec.steps, ts, spec.extent.speed)
    l1, l2 = spec.extent.semi_axes
    return np.concatenate([centres, velocities, headings[:, None], np.full((spec.steps, 1), l1),
                           np.full((spec.steps, 1), l2)], axis=1)


def extent_network(spec: ScenarioSpec, ts: float) -> tuple[Array, Array, Array]:
    """Node positions ``(M, 3)`` (on the sea surface, z = 0), roles ``(M,)`` and adjacency ``(M, M)``."""
    assert spec.extent is not None
    truth = extent_truth(spec, ts)
    pos, is_sensor, adjacency = place_network(np.random.default_rng(spec.extent.network_seed), truth[:, :2],
                                              spec.nodes, spec.extent.sensors, spec.extent.link_range)
    positions = np.concatenate([pos, np.zeros((spec.nodes, 1))], axis=1)
    return positions, np.where(is_sensor, "sensor", "relay"), adjacency


def simulate_extent(spec: ScenarioSpec, runs: int, seed: int, ts: float) -> ScenarioData:
    """``runs`` runs of an extended-object scenario (module docstring)."""
    ext = spec.extent
    assert ext is not None
    shape, _ = EXTENT_MEASUREMENTS[spec.measurement]
    truth1 = extent_truth(spec, ts)
    k_steps, n, m_nodes = spec.steps, truth1.shape[1], spec.nodes
    sensors, roles, adjacency = extent_network(spec, ts)
    measuring = np.flatnonzero(roles == "sensor")
    noise = np.diag(np.asarray(ext.noise_diag, dtype=float))
    returns = np.zeros((runs, k_steps, m_nodes, ext.max_points, 2))
    counts = np.zeros((runs, k_steps, m_nodes), dtype=int)
    x0_est = np.empty((runs, n))
    l_p0 = np.linalg.cholesky(spec.p0)
    where = np.broadcast_to(truth1[:, None, :2], (k_steps, measuring.size, 2))
    extent = np.broadcast_to(truth1[:, None, 4:], (k_steps, measuring.size, 3))
    for r, child in enumerate(np.random.SeedSequence(seed).spawn(runs)):
        rng = np.random.default_rng(child)
        x0_est[r] = truth1[0] + l_p0 @ rng.standard_normal(n)
        pts, cnt = sample_extent_points(rng, where, extent, ext.rate, shape, noise, ext.max_points)  # type: ignore[arg-type]
        returns[r][:, measuring] = pts
        counts[r][:, measuring] = cnt
    present = counts > 0
    first = returns[:, :, :, 0]  # one return per scan for code that wants one (the first point)
    return ScenarioData(
        name=spec.name, plant=spec.plant, plant_params=dict(spec.plant_params), measurement=spec.measurement,
        ts=ts, truth=np.broadcast_to(truth1, (runs, k_steps, n)).copy(), lumped=np.zeros((runs, k_steps, 0)),
        sensors=sensors, measurements=np.where(present[..., None], first, 0.0), present=present,
        noise_cov=np.broadcast_to(noise, (m_nodes, 2, 2)).copy(), adjacency=adjacency,
        weights=metropolis_weights(adjacency), x0_estimate=x0_est, p0=np.asarray(spec.p0, dtype=float),
        lumped_var=spec.lumped_var, seed=seed, roles=roles, scan_returns=returns, scan_counts=counts,
        scan_target=np.full((runs, k_steps, m_nodes), -1),
    )


#: the S2/S3 heading schedule as (start, end, samples); a turn lists both end headings (see s2_trajectory)
_S2_SEGMENTS: tuple[tuple[float, float, int], ...] = (
    (-np.pi / 4, -np.pi / 4, 20),
    (-np.pi / 4, 0.0, 11),
    (0.0, 0.0, 10),
    (0.0, np.pi / 2, 11),
    (np.pi / 2, np.pi / 2, 20),
    (np.pi / 2, np.pi, 11),
    (np.pi, np.pi, 20),
)
S2_STEPS = sum(n for _, _, n in _S2_SEGMENTS)  # 103


# --------------------------------------------------------------------------------------------------------
# truth path


def s2_headings(steps: int = S2_STEPS) -> Array:
    """The S2/S3 heading schedule, ``(steps,)``; see :func:`s2_trajectory`."""
    parts = [np.linspace(a, b, n) for a, b, n in _S2_SEGMENTS]
    h = np.concatenate(parts)
    if steps <= len(h):
        return h[:steps].copy()
    return np.concatenate([h, np.full(steps - len(h), h[-1])])


def s2_trajectory(
    steps: int = S2_STEPS,
    ts: float = 10.0,
    speed: float = 500.0 / 36.0,
    start: tuple[float, float] = (0.0, 0.0),
) -> tuple[Array, Array, Array]:
    """Truth path of S2 (ellipse) and S3 (rectangle): ``(centres (K, 2), velocities (K, 2), headings (K,))``.

    From the paper: T = 10 s (Tables 2-3), speed 50 km/h = 500/36 m/s, the shape of Fig. 8, the object
    aligned with its velocity (so extent alpha = heading). The paper's text gives no numbers for the path;
    the schedule below is the one of Yang & Baum's MEM-EKF* simulation ([23], the source of the S2 setup:
    same 170 m x 40 m ellipse, C^v = diag(200, 8), T, speed), which Fig. 8 reproduces:

    heading -pi/4 for 20 steps; a turn to 0 in 11 samples; 0 for 10; a turn to pi/2 in 11; pi/2 for 20; a
    turn to pi in 11; pi for 20: 103 steps. A turn is a linear heading ramp whose 11 samples include both
    end headings (so the first turn changes the heading by pi/40 per step, the other two by pi/20), which
    makes e.g. -pi/4 appear 21 times in a row. The start is the origin, and the centre advances with the
    current step's velocity: m_0 = start, m_k = m_{k-1} + T v_k (as in [23]'s code; the NCV model would use
    v_{k-1}, which differs only during the turns). ``steps`` < 103 truncates the schedule, more steps keep
    the last heading (pi).
    """
    if steps < 1:
        raise ValueError("steps must be >= 1")
    headings = s2_headings(steps)
    vel = speed * np.stack([np.cos(headings), np.sin(headings)], axis=-1)
    disp = ts * vel
    disp[0] = 0.0
    centres = np.asarray(start, dtype=float) + np.cumsum(disp, axis=0)
    return centres, vel, headings


# --------------------------------------------------------------------------------------------------------
# measurements


def sample_extent_points(
    rng: np.random.Generator,
    centres: Array,
    extents: Array,
    rate: float,
    shape: Literal["ellipse", "rectangle"],
    noise_cov: Array,
    max_points: int,
) -> tuple[Array, Array]:
    """One scan per batch entry of the MEM measurement model (paper eq. 3): ``(points, counts)``.

    For each entry of the broadcast batch of ``centres (..., 2)`` and ``extents (..., 3)``:
    n ~ Poisson(``rate``) clipped to ``max_points``, and n points y = m + S h + v with S = R(alpha)
    diag(l1, l2), h uniform on the unit disc (``"ellipse"``: C^h = I/4) or on the square [-1, 1]^2
    (``"rectangle"``: C^h = I/3), v ~ N(0, ``noise_cov``). ``points`` is ``(..., max_points, 2)`` with the
    first ``counts[...]`` rows valid and the rest zero; ``counts`` is ``(...)`` int.
    """
    centres = np.asarray(centres, dtype=float)
    extents = np.asarray(extents, dtype=float)
    batch = np.broadcast_shapes(centres.shape[:-1], extents.shape[:-1])
    if max_points < 0:
        raise ValueError("max_points must be >= 0")
    counts = np.minimum(rng.poisson(rate, size=batch), max_points).astype(int)
    size = batch + (max_points,)
    if shape == "ellipse":
        r = np.sqrt(rng.uniform(size=size))  # radius density 2r on [0, 1]: uniform on the disc
        t = rng.uniform(0.0, 2.0 * np.pi, size=size)
        h = np.stack([r * np.cos(t), r * np.sin(t)], axis=-1)
    elif shape == "rectangle":
        h = rng.uniform(-1.0, 1.0, size=size + (2,))
    else:
        raise ValueError(f"shape must be 'ellipse' or 'rectangle', got {shape!r}")
    v = rng.multivariate_normal(np.zeros(2), np.asarray(noise_cov, dtype=float), size=size)
    s = shape_factor(extents)  # (..., 2, 2)
    pts = centres[..., None, :] + np.einsum("...ij,...kj->...ki", s, h) + v
    valid = np.arange(max_points) < counts[..., None]
    return np.where(valid[..., None], pts, 0.0), counts


# --------------------------------------------------------------------------------------------------------
# network


def _spread_sensors(positions: Array, path: Array, sensors: int) -> Array:
    """Indices of ``sensors`` distinct nodes: for anchors spaced evenly by arc length along ``path``
    (first and last point included), greedily the nearest node not yet chosen."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=-1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    targets = np.linspace(0.0, arc[-1], sensors)
    anchors = np.stack([np.interp(targets, arc, path[:, 0]), np.interp(targets, arc, path[:, 1])], axis=-1)
    chosen: list[int] = []
    for a in anchors:
        d = np.linalg.norm(positions - a, axis=-1)
        d[chosen] = np.inf
        chosen.append(int(np.argmin(d)))
    return np.array(chosen, dtype=int)


def place_network(
    rng: np.random.Generator,
    trajectory_centres: Array,
    nodes: int = 20,
    sensors: int = 6,
    link_range: float = 2000.0,
    tries: int = 1000,
    margin: float | None = None,
) -> tuple[Array, Array, Array]:
    """Node positions, sensor flags and the communication graph: ``(positions (M, 2), is_sensor (M,),
    adjacency (M, M))``.

    From the paper (Sec. 7, Fig. 4): |G| = 20 nodes, 6 sensor nodes and 14 communication (relay) nodes,
    a link between nodes at most R = 2000 m apart; the consensus weights are Metropolis weights
    (:func:`zentrack.fusion.graphs.metropolis_weights` on ``adjacency``). The positions exist only as a
    figure, so the placement is our choice: nodes uniform in the bounding box of ``trajectory_centres``
    enlarged by ``margin`` (default ``link_range / 2``) on every side, redrawn until the disc graph is
    connected (at most ``tries`` draws, else ValueError). Sensors are spread along the path: for
    ``sensors`` anchor points evenly spaced by arc length along the trajectory, the nearest node not yet
    taken becomes a sensor, so the object passes different sensors over time as in the paper (a node
    sees the object only part of the time). Deterministic for a given ``rng`` state.
    """
    path = np.asarray(trajectory_centres, dtype=float)
    if not 0 <= sensors <= nodes:
        raise ValueError(f"need 0 <= sensors <= nodes, got {sensors} of {nodes}")
    margin = link_range / 2.0 if margin is None else float(margin)
    lo, hi = path.min(axis=0) - margin, path.max(axis=0) + margin
    for _ in range(tries):
        pos = rng.uniform(lo, hi, size=(nodes, 2))
        adj = radius_adjacency(pos, link_range)
        if is_connected(adj):
            break
    else:
        raise ValueError(f"no connected {nodes}-node network with range {link_range} m in {tries} draws")
    is_sensor = np.zeros(nodes, dtype=bool)
    if sensors:
        is_sensor[_spread_sensors(pos, path, sensors)] = True
    return pos, is_sensor, adj
