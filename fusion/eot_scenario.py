"""Seed 004's scenarios (S2 ellipse, S3 rectangle) as :class:`~zentrack.fusion.scenario.ScenarioData`.

The object follows the paper's S2 path (:func:`~zentrack.fusion.extent.s2_trajectory`: headings -pi/4, 0,
pi/2, pi with the stated turns, 103 scans of T = 10 s at 500/36 m/s), aligned with its velocity
(``alpha`` = heading), with the scenario's semi-axes.  The truth ``[m1, m2, v1, v2, alpha, l1, l2]`` is the
same in every run (the path is given, not drawn); what a run draws is the scans and the initial estimate:

- each sensor node sees the object at every scan (the paper's simulations give its sensors no field-of-view
  limit) and gets a Poisson(``rate``) number of points ``y = m + S h + v``, ``h`` uniform on the unit disc
  (ellipse) or the square ``[-1, 1]^2`` (rectangle), ``v ~ N(0, C^v)``
  (:func:`~zentrack.fusion.extent.sample_extent_points`), capped at ``max_points``;
- the initial estimate is drawn from the prior around the truth at the first scan, ``N(truth_1, P0)``
  (the paper gives the prior covariances, not how its initial estimates were drawn).

The network (``nodes`` nodes of which ``sensors`` measure, links up to ``link_range``, Metropolis weights)
is placed once from ``network_seed`` (:func:`~zentrack.fusion.extent.place_network`) and is the same in
every run; the other nodes are relays.  Run ``r`` draws from child ``r`` of ``SeedSequence(seed)`` alone.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .extent import place_network, s2_trajectory, sample_extent_points
from .models import EXTENT_MEASUREMENTS  # measurement kind -> (object shape, C^h)

if TYPE_CHECKING:
    from .scenario import ScenarioData, ScenarioSpec

Array = np.ndarray



@dataclass
class ExtentSpec:
    """The object and network of an extended-object scenario (module docstring)."""

    semi_axes: tuple[float, float] = (170.0, 40.0)
    speed: float = 500.0 / 36.0
    rate: float = 5.0
    max_points: int = 40
    noise_diag: tuple[float, float] = (200.0, 8.0)  #: C^v = diag(.)
    sensors: int = 6
    link_range: float = 2000.0
    network_seed: int = 4

    def validate(self, nodes: int) -> None:
        if len(self.semi_axes) != 2 or not all(np.isfinite(a) and a > 0 for a in self.semi_axes):
            raise ValueError(f"extent semi_axes: two positive numbers, got {list(self.semi_axes)}")
        if not (np.isfinite(self.rate) and 0 < self.rate <= 1000):
            raise ValueError(f"extent rate (points per scan): must be in (0, 1000], got {self.rate}")
        if not 1 <= self.max_points <= 1000:
            raise ValueError(f"extent max_points: must be from 1 to 1000, got {self.max_points}")
        if len(self.noise_diag) != 2 or not all(np.isfinite(v) and v > 0 for v in self.noise_diag):
            raise ValueError(f"extent noise_diag: two positive variances, got {list(self.noise_diag)}")
        if not 1 <= self.sensors <= nodes:
            raise ValueError(f"extent sensors: must be from 1 to the node count {nodes}, got {self.sensors}")
        if not (np.isfinite(self.link_range) and self.link_range > 0) or not np.isfinite(self.speed):
            raise ValueError(f"extent link_range and speed must be positive, got {self.link_range}, {self.speed}")


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
    from .graphs import metropolis_weights
    from .scenario import ScenarioData

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
