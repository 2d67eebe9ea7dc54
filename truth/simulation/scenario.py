"""Scenarios: what is simulated (plant, sensors, noise, graph) and one or more simulated runs of it.

A :class:`~zentrack.truth.simulation.scenario_spec.ScenarioSpec` (``scenario_spec.py``) describes a scenario;
:func:`~zentrack.truth.simulation.simulate.simulate` draws R independent runs of it (truth states, every node's
measurements, initial estimates) into a :class:`ScenarioData`, which is what the batched
simulator, the truth process and scenario files (``zentrack.config.scenario_file``) all exchange.
Run r uses its own child of ``SeedSequence(seed)``, so it is identical whatever R is.

The built-in scenarios are scenario files, every one of them in the catalogue (``deploy/scenarios/``,
``zentrack scenarios``; :func:`zentrack.config.scenario_config.builtin_spec` is one's spec), among them seed
000 Section 6's ``exp1`` (eq. 63, linear measurements) and ``exp2`` (eq. 66, 3-D bearing-only ring of
photoelectric sensors).

Scenarios with clutter (paper 1) add a :class:`~zentrack.truth.simulation.clutter.ClutterSpec` to the spec;
their data then holds ragged scans (``scan_returns`` ``(R, K, M, Jmax, m)`` padded, ``scan_counts`` ``(R, K, M)``):
the target's return with probability P_D among uniform clutter, shuffled. ``measurements``/``present`` then
hold the target's return where it was detected (for evaluation; a clutter filter never sees them).

Paper 2's UAV scenarios add moving sensors (``sensor_velocity``/``sensor_accel``: constant-acceleration
platforms, their positions per step in ``ScenarioData.sensor_track`` and sent with every scan), a noise level
per sensor (``noise_stds``), an explicit communication graph (``adjacency``, with Metropolis or centrality
consensus weights) and a manoeuvre schedule of the target's acceleration (``accel_schedule``).

A ``trajectory`` (a recording's target, issue 34, or a patrol loop, issue 36: ``truth/simulation/patrol.py``) is the
target's path, its state at step 0 the initial state (not ``x0``); the plant
(:data:`~zentrack.truth.simulation.scenario_spec.TRAJECTORY_PLANTS`) only what the filters and the bound assume.

Nodes have roles (:data:`~zentrack.truth.simulation.scenario_spec.ROLES`): a ``"sensor"`` measures and fuses, a
``"relay"`` never measures (its ``present`` is false at every step) and estimates through fusion alone.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from zentrack.fusion.graphs import check_weights
from zentrack.fusion.measurement import MeasurementModel
from zentrack.fusion.models import make_measurement, make_plant
from zentrack.fusion.motion import MotionModel

from .scenario_spec import check_roles, default_roles

Array = np.ndarray


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


def state_groups(scn: ScenarioData) -> dict[str, list[int]]:
    """The component groups the papers report: x1/x2 for Experiment 1, position and speed for the ship
    ([x, y, z, v, psi], paper 3), p/v for the 3-D plants. One grouping for every figure of a run: the batched
    simulator's (:mod:`zentrack.study.simulator`) and a live run's recorder report the same groups."""
    if scn.plant == "exp1":
        return {"x1": [0], "x2": [1]}
    if scn.plant.startswith("ship"):
        return {"p": [0, 1, 2], "speed": [3]}
    return {"p": [0, 1, 2], "v": [3, 4, 5]}


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
