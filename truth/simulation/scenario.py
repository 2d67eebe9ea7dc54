"""Scenarios: what is simulated (plant, sensors, noise, graph) and one or more simulated runs of it.

A :class:`ScenarioSpec` describes a scenario (with an extended object's :class:`ExtentSpec`);
:func:`~zentrack.truth.simulation.simulate.simulate` draws R independent runs of it (truth states, every node's
measurements, initial estimates) into a :class:`ScenarioData`, which is what the batched
simulator, the truth process and scenario files (``zentrack.config.scenario_file``) all exchange.
Run r uses its own child of ``SeedSequence(seed)``, so it is identical whatever R is.

The built-in scenarios are scenario files, every one of them in the catalogue (``deploy/scenarios/``,
``zentrack scenarios``; :func:`zentrack.config.scenario_config.builtin_spec` is one's spec), among them seed
000 Section 6's ``exp1`` (eq. 63, linear measurements) and ``exp2`` (eq. 66, 3-D bearing-only ring of
photoelectric sensors).

Scenarios with clutter (seed 001) add a :class:`~zentrack.truth.simulation.clutter.ClutterSpec` to the spec;
their data then holds ragged scans (``scan_returns`` ``(R, K, M, Jmax, m)`` padded, ``scan_counts`` ``(R, K, M)``):
the target's return with probability P_D among uniform clutter, shuffled. ``measurements``/``present`` then
hold the target's return where it was detected (for evaluation; a clutter filter never sees them).

Seed 002's UAV scenarios add moving sensors (``sensor_velocity``/``sensor_accel``: constant-acceleration
platforms, their positions per step in ``ScenarioData.sensor_track`` and sent with every scan), a noise level
per sensor (``noise_stds``), an explicit communication graph (``adjacency``, with Metropolis or centrality
consensus weights) and a manoeuvre schedule of the target's acceleration (``accel_schedule``).

A ``trajectory`` (a recording's target, issue 34, or a patrol loop, issue 36: ``truth/simulation/patrol.py``) is the
target's path, its state at step 0 the initial state (not ``x0``); the plant (:data:`TRAJECTORY_PLANTS`) only what the
filters and the bound assume.

Nodes have roles (:data:`ROLES`): a ``"sensor"`` measures and fuses, a ``"relay"`` never measures (its
``present`` is false at every step) and estimates through fusion alone.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from zentrack.fusion.graphs import check_weights, metropolis_weights, ring_adjacency, self_weighted
from zentrack.fusion.measurement import MeasurementModel
from zentrack.fusion.models import MEASUREMENTS, PLANTS, make_measurement, make_plant
from zentrack.fusion.motion import MotionModel

from .clutter import ClutterSpec
from .patrol import PatrolSpec
from .recorded.recording import RecordingSpec

Array = np.ndarray

ROLES = ("sensor", "relay")
GRAPHS = ("ring", "metropolis-ring", "explicit")
#: consensus weights of an explicit graph (seed 002): Metropolis, or the centrality-based weights
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
    #: detection probability and clutter of every sensor (seed 001); None: one return per scan, no clutter
    clutter: ClutterSpec | None = None
    #: measurement noise standard deviation per sensor ``(M,)``; None: ``noise_std`` for every sensor
    noise_stds: Array | None = None
    #: constant-acceleration sensor platforms (seed 002): velocity and acceleration ``(M, 3)`` at t = 0
    sensor_velocity: Array | None = None
    sensor_accel: Array | None = None
    #: the communication graph when ``graph == "explicit"`` ``(M, M)`` bool, and its consensus weights
    adjacency: Array | None = None
    consensus_weights: str = "metropolis"
    #: piecewise-constant target acceleration: ``[(t_start, [ax, ay, az]), ...]`` (plant ``ca9``)
    accel_schedule: list[tuple[float, list[float]]] | None = None
    #: satellites on Kepler orbits (seed 003), one per node, seen from the ENU frame of ``site``
    orbits: list | None = None
    #: ``(lat, lon)`` in radians of the ENU origin (the target's initial position) for orbiting sensors
    site: tuple[float, float] | None = None
    #: seconds since the orbits' epoch at step 0, and the Greenwich sidereal angle at the epoch (rad)
    orbit_t0: float = 0.0
    gmst0: float = 0.0
    #: an extended object seen as points by a placed network (seed 004; plant ``eot``)
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


@dataclass
class ScenarioData:
    """R simulated runs of one scenario. Shapes: K steps, M nodes, n state, m measurement, l lumped."""

    name: str
    plant: str
    plant_params: dict[str, float]
    measurement: str
    ts: float
    truth: Array  # (R, K, n) true state at sample k
    lumped: Array  # (R, K, l) true lumped term F(x_k, k)
    sensors: Array  # (M, 3)
    measurements: Array  # (R, K, M, m)
    present: Array  # (R, K, M) bool: measurement available
    noise_cov: Array  # (M, m, m)
    adjacency: Array  # (M, M) bool
    weights: Array  # (M, M) row-stochastic
    x0_estimate: Array  # (R, n)
    p0: Array  # (n, n)
    lumped_var: float
    seed: int
    linear_matrix: Array | None = None
    meta: dict = field(default_factory=dict)
    #: (M,) str, "sensor" or "relay" per node (None: all sensors, filled in on construction)
    roles: Array = None  # type: ignore[assignment]
    #: ragged scans with clutter (None: one return per scan, ``measurements``): ``(R, K, M, Jmax, m)`` padded
    scan_returns: Array | None = None
    #: returns per scan ``(R, K, M)`` (0: the sensor looked and saw nothing)
    scan_counts: Array | None = None
    #: where the target's return sits in each scan ``(R, K, M)``, -1 when missed (evaluation only)
    scan_target: Array | None = None
    #: positions of moving sensors at every step ``(K, M, 3)`` (the same in every run); None: ``sensors``
    sensor_track: Array | None = None

    def __post_init__(self) -> None:
        if self.roles is None:
            self.roles = default_roles(int(np.shape(self.sensors)[0]))

    @property
    def runs(self) -> int:
        return int(self.truth.shape[0])

    @property
    def steps(self) -> int:
        return int(self.truth.shape[1])

    @property
    def nodes(self) -> int:
        return int(self.sensors.shape[0])

    def motion_model(self) -> MotionModel:
        return make_plant(self.plant, self.ts, self.plant_params)

    def measurement_model(self) -> MeasurementModel:
        return make_measurement(self.measurement, self.linear_matrix)

    def run(self, r: int) -> ScenarioData:
        """The single run ``r`` as a scenario of its own (R = 1)."""
        sl = slice(r, r + 1)
        return replace(
            self,
            truth=self.truth[sl],
            lumped=self.lumped[sl],
            measurements=self.measurements[sl],
            present=self.present[sl],
            x0_estimate=self.x0_estimate[sl],
            scan_returns=None if self.scan_returns is None else self.scan_returns[sl],
            scan_counts=None if self.scan_counts is None else self.scan_counts[sl],
            scan_target=None if self.scan_target is None else self.scan_target[sl],
        )

    def sensors_at(self, step: int) -> Array:
        """Every sensor's position at ``step`` ``(M, 3)``."""
        return self.sensors if self.sensor_track is None else self.sensor_track[step]

    def sensor_pose(self, step: int, node: int) -> Array:
        """Sensor ``node``'s position at ``step`` ``(3,)`` (what the truth sends with the scan)."""
        return self.sensors_at(step)[node]

    @property
    def has_scans(self) -> bool:
        """Whether the scenario has ragged scans (clutter) instead of one return per scan."""
        return self.scan_returns is not None

    def scan(self, run: int, step: int, node: int) -> Array | None:
        """The ``(J, m)`` returns of one scan, or None when the node has no sensor or no scan at that step."""
        if self.scan_returns is not None and self.scan_counts is not None:
            if self.roles[node] == "relay":
                return None
            return self.scan_returns[run, step, node, : int(self.scan_counts[run, step, node])].copy()
        return self.measurements[run, step, node][None].copy() if self.present[run, step, node] else None

    def validate(self) -> None:
        """Check shapes and values; raise ValueError naming the offending field."""
        r, k, n = _shape(self.truth, "truth", 3)
        m_nodes, sensor_dim = _shape(self.sensors, "sensors", 2)
        if sensor_dim != 3:
            raise ValueError(f"sensors: expected shape (M, 3), got {np.shape(self.sensors)}")
        meas = make_measurement(self.measurement, self.linear_matrix)
        m = meas.dim
        expect = {
            "measurements": (r, k, m_nodes, m),
            "present": (r, k, m_nodes),
            "noise_cov": (m_nodes, m, m),
            "adjacency": (m_nodes, m_nodes),
            "weights": (m_nodes, m_nodes),
            "x0_estimate": (r, n),
            "p0": (n, n),
        }
        for key, shape in expect.items():
            got = np.shape(getattr(self, key))
            if got != shape:
                raise ValueError(f"{key}: expected shape {shape}, got {got}")
        plant = make_plant(self.plant, self.ts, self.plant_params)
        if plant.dim != n:
            raise ValueError(f"truth: plant {self.plant!r} has state dimension {plant.dim}, truth has {n}")
        for key in ("truth", "sensors", "noise_cov", "weights", "x0_estimate", "p0"):
            if not np.all(np.isfinite(getattr(self, key))):
                raise ValueError(f"{key}: contains NaN or Inf")
        present = np.asarray(self.present, dtype=bool)
        if not np.all(np.isfinite(self.measurements[present])):
            raise ValueError("measurements: NaN or Inf where present is true")
        if not (self.ts > 0):
            raise ValueError(f"ts must be positive, got {self.ts}")
        for i, c in enumerate(self.noise_cov):
            if not np.allclose(c, c.T) or np.linalg.eigvalsh(c)[0] <= 0:
                raise ValueError(f"noise_cov[{i}] is not symmetric positive definite")
        if np.linalg.eigvalsh(self.p0)[0] <= 0 or not np.allclose(self.p0, self.p0.T):
            raise ValueError("p0 is not symmetric positive definite")
        try:
            check_weights(self.weights, self.adjacency)
        except ValueError as exc:
            raise ValueError(f"weights: {exc}") from None
        if self.measurement == "bearing":
            check_bearings(self.measurements, present, self.noise_cov)
        roles = check_roles(self.roles, m_nodes)
        if np.any(present[..., roles == "relay"]):
            raise ValueError("present: a relay node never measures (present must be false for relays)")
        if self.scan_returns is not None or self.scan_counts is not None:
            if self.scan_returns is None or self.scan_counts is None or self.scan_target is None:
                raise ValueError("scan_returns, scan_counts and scan_target come together")
            got = np.shape(self.scan_returns)
            if len(got) != 5 or got[:3] != (r, k, m_nodes) or got[4] != m:
                raise ValueError(f"scan_returns: expected shape {(r, k, m_nodes, 'J', m)}, got {got}")
            for key in ("scan_counts", "scan_target"):
                if np.shape(getattr(self, key)) != (r, k, m_nodes):
                    raise ValueError(f"{key}: expected shape {(r, k, m_nodes)}, got {np.shape(getattr(self, key))}")
            counts = np.asarray(self.scan_counts)
            if counts.min(initial=0) < 0 or counts.max(initial=0) > got[3]:
                raise ValueError(f"scan_counts: must lie in [0, {got[3]}]")
            if not np.all(np.isfinite(self.scan_returns)):
                raise ValueError("scan_returns: contains NaN or Inf")
        if self.sensor_track is not None:
            if np.shape(self.sensor_track) != (k, m_nodes, 3):
                raise ValueError(f"sensor_track: expected shape {(k, m_nodes, 3)}, got {np.shape(self.sensor_track)}")
            if not np.all(np.isfinite(self.sensor_track)):
                raise ValueError("sensor_track: contains NaN or Inf")


#: an elevation may exceed pi/2 in magnitude by this many noise standard deviations (a target overhead)
ELEVATION_NOISE_SIGMAS = 6.0


def check_bearings(measurements: Array, present: Array, noise_cov: Array) -> None:
    """Raise ValueError unless every present bearing is in radians where the measurement model puts it: azimuth
    in (-pi, pi], elevation in [-pi/2, pi/2] (widened by :data:`ELEVATION_NOISE_SIGMAS` of the sensor's
    elevation noise, since noise can carry a target overhead past the pole). Bearings in degrees fail this."""
    z = np.asarray(measurements, dtype=float)
    ok = np.asarray(present, dtype=bool)
    az, el = z[..., 0], z[..., 1]
    bad_az = ok & ~((az > -np.pi) & (az <= np.pi))
    limit = np.pi / 2 + ELEVATION_NOISE_SIGMAS * np.sqrt(np.asarray(noise_cov, dtype=float)[:, 1, 1])
    bad_el = ok & ~(np.abs(el) <= limit)
    for bad, what, rng in ((bad_az, "azimuth", "(-pi, pi]"), (bad_el, "elevation", "[-pi/2, pi/2]")):
        if bad.any():
            r, k, i = (int(v[0]) for v in np.nonzero(bad))
            raise ValueError(f"measurements: {int(bad.sum())} {what}(s) outside {rng} radians, the first at run {r} "
                             f"step {k} node {i}: {z[r, k, i, 0 if what == 'azimuth' else 1]:.6g} (degrees?)")


def _shape(a: Array, key: str, ndim: int) -> tuple[int, ...]:
    if np.ndim(a) != ndim:
        raise ValueError(f"{key}: expected {ndim} dimensions, got shape {np.shape(a)}")
    return np.shape(a)


def ring_sensor_positions(m: int, radius: float = 400.0, height: float = 50.0) -> Array:
    """s_i = [r cos th_i, r sin th_i, h sin(2 th_i)], th_i = 2 pi (i-1)/M (seed 000 eq. 67)."""
    th = 2.0 * np.pi * np.arange(m) / m
    return np.stack([radius * np.cos(th), radius * np.sin(th), height * np.sin(2.0 * th)], axis=1)


def graph_weights(spec: ScenarioSpec) -> tuple[Array, Array]:
    """The scenario's communication graph and its row-stochastic weights."""
    if spec.graph == "explicit":
        from zentrack.fusion.consensus import centrality_weights

        adj = np.asarray(spec.adjacency, dtype=bool)
        if spec.consensus_weights == "centrality":
            return adj, centrality_weights(adj)
        return adj, metropolis_weights(adj)
    adj = ring_adjacency(spec.nodes)
    if spec.graph == "metropolis-ring":
        return adj, metropolis_weights(adj)
    return adj, self_weighted(adj, spec.self_weight)
