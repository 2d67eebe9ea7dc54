"""What a scenario is: its :class:`ScenarioSpec` (plant, sensors, noise, graph, roles, trajectory, with an
extended object's :class:`ExtentSpec`), checked field by field, the ring of paper 0's sensors and the graph's
weights. One or more simulated runs of it are a :class:`~zentrack.truth.simulation.scenario.ScenarioData`
(``zentrack.truth.simulation.scenario``, whose docstring says what each kind of scenario holds).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zentrack.fusion.graphs import metropolis_weights, ring_adjacency, self_weighted
from zentrack.fusion.models import MEASUREMENTS, PLANTS

from .clutter import ClutterSpec
from .patrol import PatrolSpec
from .recorded.recording import RecordingSpec

Array = np.ndarray

ROLES = ("sensor", "relay")
GRAPHS = ("ring", "metropolis-ring", "explicit")
#: consensus weights of an explicit graph (paper 2): Metropolis, or the centrality-based weights
CONSENSUS_WEIGHTS = ("metropolis", "centrality")
#: the plants whose state is [position (3), velocity (3)]: what a recorded trajectory and many targets move by
POSITION_VELOCITY_PLANTS = ("cv3d", "cv3d-cd")
#: the plants a recorded trajectory (position and velocity) can be the truth of
TRAJECTORY_PLANTS = POSITION_VELOCITY_PLANTS


def default_roles(nodes: int) -> Array:
    """Every node a sensor: a ``(M,)`` array of str."""
    return np.full(nodes, "sensor")


def check_roles(roles: object, nodes: int, key: str = "roles") -> Array:
    """``roles`` as a ``(M,)`` str array; ValueError naming ``key`` for a wrong length or value."""
    arr = np.asarray(roles)
    if arr.shape != (nodes,):
        raise ValueError(f"{key}: expected {nodes} roles (one per node), got shape {arr.shape}")
    bad = sorted({str(r) for r in arr.tolist() if not isinstance(r, str) or r not in ROLES})
    if bad:
        raise ValueError(f"{key}: roles must be one of {ROLES}, got {bad}")
    return arr.astype(str)


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


@dataclass
class ScenarioSpec:
    """Everything needed to simulate a scenario (all fields validated by :meth:`validate`)."""

    name: str
    plant: str
    plant_params: dict[str, float]
    measurement: str
    noise_std: float
    sensors: Array  # (M, 3)
    x0: Array  # (n,)
    p0: Array  # (n, n) kinematic prior covariance of the filters
    steps: int
    lumped_var: float = 1.0
    linear_matrix: Array | None = None
    graph: str = "ring"
    self_weight: float = 0.5
    #: "sensor" or "relay" per node; None: every node is a sensor
    roles: list[str] | None = None
    #: detection probability and clutter of every sensor (paper 1); None: one return per scan, no clutter
    clutter: ClutterSpec | None = None
    #: measurement noise standard deviation per sensor ``(M,)``; None: ``noise_std`` for every sensor
    noise_stds: Array | None = None
    #: constant-acceleration sensor platforms (paper 2): velocity and acceleration ``(M, 3)`` at t = 0
    sensor_velocity: Array | None = None
    sensor_accel: Array | None = None
    #: the communication graph when ``graph == "explicit"`` ``(M, M)`` bool, and its consensus weights
    adjacency: Array | None = None
    consensus_weights: str = "metropolis"
    #: piecewise-constant target acceleration: ``[(t_start, [ax, ay, az]), ...]`` (plant ``ca9``)
    accel_schedule: list[tuple[float, list[float]]] | None = None
    #: satellites on Kepler orbits (paper 3), one per node, seen from the ENU frame of ``site``
    orbits: list | None = None
    #: ``(lat, lon)`` in radians of the ENU origin (the target's initial position) for orbiting sensors
    site: tuple[float, float] | None = None
    #: seconds since the orbits' epoch at step 0, and the Greenwich sidereal angle at the epoch (rad)
    orbit_t0: float = 0.0
    gmst0: float = 0.0
    #: an extended object seen as points by a placed network (paper 4; plant ``eot``)
    extent: ExtentSpec | None = None
    #: the target's path: a recording's (one selected target) or a patrol loop; None: the plant's, from ``x0``
    trajectory: RecordingSpec | PatrolSpec | None = None

    @property
    def nodes(self) -> int:
        return int(self.sensors.shape[0])

    @property
    def moving(self) -> bool:
        """Whether the sensors move."""
        return self.sensor_velocity is not None or self.sensor_accel is not None or self.orbits is not None

    def noise_levels(self) -> Array:
        """The noise standard deviation of every sensor ``(M,)``."""
        if self.noise_stds is not None:
            return np.asarray(self.noise_stds, dtype=float)
        return np.full(self.nodes, float(self.noise_std))

    def sensor_track(self, steps: int, ts: float) -> Array | None:
        """Sensor positions at every step ``(K, M, 3)`` (constant acceleration), or None for fixed sensors."""
        if not self.moving:
            return None
        if self.orbits is not None:
            from .orbit import sensor_track_enu

            if self.site is None:
                raise ValueError("orbiting sensors need the site (lat, lon) of the ENU frame")
            times = self.orbit_t0 + ts * np.arange(steps)
            return np.stack([sensor_track_enu(o, times, self.site[0], self.site[1], 0.0, self.gmst0)
                             for o in self.orbits], axis=1)
        t = ts * np.arange(steps)[:, None, None]
        v = np.zeros((self.nodes, 3)) if self.sensor_velocity is None else np.asarray(self.sensor_velocity, float)
        a = np.zeros((self.nodes, 3)) if self.sensor_accel is None else np.asarray(self.sensor_accel, float)
        return np.asarray(self.sensors, dtype=float)[None] + v[None] * t + 0.5 * a[None] * t * t

    def validate(self) -> None:
        if self.plant not in PLANTS:
            raise ValueError(f"plant must be one of {PLANTS}, got {self.plant!r}")
        if self.measurement not in MEASUREMENTS:
            raise ValueError(f"measurement must be one of {MEASUREMENTS}, got {self.measurement!r}")
        if self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")
        if self.nodes < 1:
            raise ValueError("a scenario needs at least one node")
        if not (np.isfinite(self.noise_std) and self.noise_std > 0):
            raise ValueError(f"noise_std must be positive, got {self.noise_std}")
        if self.graph not in GRAPHS:
            raise ValueError(f"graph must be one of {GRAPHS}, got {self.graph!r}")
        if (self.graph == "explicit") != (self.adjacency is not None):
            raise ValueError("an explicit graph needs an adjacency matrix, and only an explicit graph takes one")
        if self.adjacency is not None:
            adj = np.asarray(self.adjacency)
            if adj.shape != (self.nodes, self.nodes) or not np.array_equal(adj, adj.T) or np.any(np.diag(adj)):
                raise ValueError(f"adjacency: expected a symmetric ({self.nodes}, {self.nodes}) matrix without "
                                 "self loops")
        if self.consensus_weights not in CONSENSUS_WEIGHTS:
            raise ValueError(f"consensus_weights must be one of {CONSENSUS_WEIGHTS}, got {self.consensus_weights!r}")
        if self.noise_stds is not None:
            stds = np.asarray(self.noise_stds, dtype=float)
            if stds.shape != (self.nodes,) or not np.all(np.isfinite(stds) & (stds > 0)):
                raise ValueError(f"noise_stds: expected {self.nodes} positive numbers, got {stds.tolist()}")
        for key in ("sensor_velocity", "sensor_accel"):
            value = getattr(self, key)
            if value is not None and (np.shape(value) != (self.nodes, 3) or not np.all(np.isfinite(value))):
                raise ValueError(f"{key}: expected {self.nodes} finite rows of [x, y, z], got shape {np.shape(value)}")
        if self.moving and self.clutter is not None:
            raise ValueError("clutter windows are fixed in bearing: they need fixed sensors")
        if self.orbits is not None and len(self.orbits) != self.nodes:
            raise ValueError(f"orbits: expected one per node ({self.nodes}), got {len(self.orbits)}")
        if self.accel_schedule is not None and self.plant != "ca9":
            raise ValueError(f"an acceleration schedule needs the constant-acceleration plant ca9, not {self.plant!r}")
        if self.roles is not None:
            check_roles(self.roles, self.nodes)
        if self.clutter is not None and self.measurement != "bearing":
            raise ValueError(f"clutter needs bearing measurements, got {self.measurement!r}")
        extended = self.measurement.startswith("extent-")
        if extended != (self.plant == "eot") or extended != (self.extent is not None):
            raise ValueError("an extended object needs plant 'eot', an extent-* measurement and the extent "
                             "settings together")
        if self.extent is not None:
            self.extent.validate(self.nodes)
        if self.trajectory is not None:
            if self.plant not in TRAJECTORY_PLANTS or self.accel_schedule is not None:
                raise ValueError(f"a recorded trajectory needs plant {' or '.join(TRAJECTORY_PLANTS)} (position and "
                                 f"velocity) and no acceleration schedule, not {self.plant!r}")
            if isinstance(self.trajectory, PatrolSpec):
                self.trajectory.validate()
            elif len(self.trajectory.select) != 1:
                raise ValueError(f"trajectory select: must name exactly one target, got {list(self.trajectory.select)}")


def ring_sensor_positions(m: int, radius: float = 400.0, height: float = 50.0) -> Array:
    """s_i = [r cos th_i, r sin th_i, h sin(2 th_i)], th_i = 2 pi (i-1)/M (paper 0 eq. 67)."""
    th = 2.0 * np.pi * np.arange(m) / m
    return np.stack([radius * np.cos(th), radius * np.sin(th), height * np.sin(2.0 * th)], axis=1)


def graph_weights(spec: ScenarioSpec) -> tuple[Array, Array]:
    """The scenario's communication graph and its row-stochastic weights."""
    if spec.graph == "explicit":
        from zentrack.fusion.consensus_weights import centrality_weights

        adj = np.asarray(spec.adjacency, dtype=bool)
        if spec.consensus_weights == "centrality":
            return adj, centrality_weights(adj)
        return adj, metropolis_weights(adj)
    adj = ring_adjacency(spec.nodes)
    if spec.graph == "metropolis-ring":
        return adj, metropolis_weights(adj)
    return adj, self_weighted(adj, spec.self_weight)
