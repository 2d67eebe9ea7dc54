"""Many targets seen by a sensor network: births and deaths, missed detections, a limited field of view, clutter.

A :class:`MultiTargetSpec` adds to a :class:`~zentrack.truth.simulation.scenario.ScenarioSpec` (plant, sensors,
measurement model, noise, graph) what a many-target scenario needs:

- :class:`TargetsSpec`: the targets present at the start (``layout``: ``"crossing"`` lines through one point,
  met at the same time, the hard case for association; ``"random"`` positions in a region with random headings;
  ``"explicit"`` initial states), when each appears and leaves (``birth_times``/``death_times``), Poisson births
  in the region (``birth_rate`` per second) and a per-step survival probability (a geometric lifetime);
- :class:`SensingSpec`: each sensor's detection probability P_D, its range and field of view (an azimuth
  width centred on the direction to the targets' ``centre``, an elevation window), and Poisson clutter.

:func:`simulate_multitarget` draws one run into a :class:`MultiTargetData`. Targets move by the plant of
:mod:`zentrack.fusion.models` (``x+ = f(x) + w``, ``w ~ N(0, Q)``; the position-velocity plants ``cv3d`` and
``cv3d-cd``); a target inside a sensor's field of view and range is detected with probability P_D and
measured by the scenario's model of :mod:`zentrack.fusion.measurement` (``point``: Cartesian position;
``bearing``: azimuth/elevation), ``z = h(x) + v``, ``v ~ N(0, sigma^2 I)``. Clutter is the usual Poisson point
process (Bar-Shalom, Willett & Tian, *Tracking and Data Fusion*, 2011, Sec. 3.4): Poisson(``clutter_rate``)
returns per scan, uniform in the field of view (in angle for bearing sensors, in volume for point sensors).
Each scan's returns are shuffled; which return came from which target is kept apart (``origin``) for
evaluation and tests, as is the truth (``truth``/``alive``): a tracker sees only :meth:`MultiTargetData.scan`.

Truth, detections and clutter draw from three children of ``SeedSequence(seed)``, so clutter settings never
move the targets. (Seed 001's :mod:`~zentrack.truth.simulation.clutter` draws one target per scan in fixed
bearing windows; these scans are many-target and sensor-relative, so only its angle wrapping is shared.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.models import make_measurement, make_plant
from zentrack.fusion.scan import Scan

from .recorded.recording import RecordedTargets, RecordingSpec, recorded_targets
from .scenario import POSITION_VELOCITY_PLANTS, ScenarioSpec

Array = np.ndarray

TARGET_LAYOUTS = ("crossing", "random", "explicit", "recorded")
#: plants whose state is [position (3), velocity (3)], the only ones a many-target scenario moves
MULTITARGET_PLANTS = POSITION_VELOCITY_PLANTS
MULTITARGET_MEASUREMENTS = ("point", "bearing")
#: ``origin`` of a clutter return and of a padding slot
CLUTTER, PADDING = -1, -2


@dataclass(frozen=True)
class TargetsSpec:
    """The targets (module docstring). ``centre`` ``(3,)`` is where crossing targets meet and what the sensors
    face; ``region`` ``(3, 2)`` the ``[lo, hi]`` box random and Poisson-born targets start in. Times are seconds;
    a target is present at steps ``birth_step <= k < death_step``."""

    layout: str
    count: int
    speed: float
    centre: Array
    region: Array
    spread: float = 1000.0  #: crossing: start distance from the centre (they meet there at spread / speed s)
    initial: Array | None = None  #: explicit: ``(count, 6)`` states at birth
    birth_times: Array | None = None  #: ``(count,)`` s; None: every one at 0
    death_times: Array | None = None  #: ``(count,)`` s, ``inf``: never; None: by survival alone
    birth_rate: float = 0.0  #: Poisson births per second after the start
    survival_prob: float = 1.0  #: per step
    max_targets: int = 200  #: births stop at this many targets in the run
    #: recorded: the recording whose targets are the truth (:mod:`~zentrack.truth.simulation.recorded.recording`)
    recording: RecordingSpec | None = None
    #: the GOSPA cut-off (m) these targets are scored with; None: the default
    #: (:data:`~zentrack.fusion.multitarget.metrics.GOSPA_CUTOFF`)
    gospa_cutoff: float | None = None

    def initial_states(self, rng: np.random.Generator) -> Array:
        """The ``(count, 6)`` states the layout gives the first ``count`` targets."""
        if self.layout == "explicit":
            return np.array(self.initial, dtype=float)
        if self.layout == "crossing":  # headings pi i / count: no two on one line, all at the centre at once
            heading = np.pi * np.arange(self.count) / self.count
            unit = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(self.count)])
            return np.hstack([self.centre - self.spread * unit, self.speed * unit])
        return self.random_states(self.count, rng)

    def random_states(self, count: int, rng: np.random.Generator) -> Array:
        """``count`` states uniform in ``region`` with uniform horizontal headings at ``speed``."""
        pos = self.region[:, 0] + rng.random((count, 3)) * (self.region[:, 1] - self.region[:, 0])
        heading = rng.uniform(-np.pi, np.pi, count)
        vel = self.speed * np.column_stack([np.cos(heading), np.sin(heading), np.zeros(count)])
        return np.hstack([pos, vel])


@dataclass(frozen=True)
class SensingSpec:
    """What each sensor sees: ``detection_prob`` (P_D), ``max_range`` (m; ``inf``: unlimited, bearing sensors
    only), ``fov_azimuth`` (full width, rad, centred on the sensor's boresight; 2 pi: all round),
    ``fov_elevation`` ``(lo, hi)`` rad and ``clutter_rate`` (mean clutter returns per scan)."""

    detection_prob: float
    max_range: float
    fov_azimuth: float
    fov_elevation: tuple[float, float]
    clutter_rate: float


@dataclass(frozen=True)
class MultiTargetSpec:
    """A many-target scenario's targets and sensing (the network is its :class:`ScenarioSpec`)."""

    targets: TargetsSpec
    sensing: SensingSpec


@dataclass
class MultiTargetData:
    """One simulated run. K steps, M sensors, T targets over the run (target id = index, in birth order), J the
    largest scan, m the measurement dimension:

    - ``truth`` ``(K, T, 6)`` (NaN where absent), ``alive`` ``(K, T)``, ``in_view`` ``(K, M, T)`` (present, in
      range and field of view: what P_D applies to);
    - ``returns`` ``(K, M, J, m)`` (shuffled, padding 0), ``counts`` ``(K, M)``, ``origin`` ``(K, M, J)`` (the
      target id, :data:`CLUTTER` or :data:`PADDING`) — ``origin`` and the truth are for evaluation only.
    """

    name: str
    measurement: str
    ts: float
    seed: int
    sensors: Array
    boresight: Array  #: ``(M,)`` azimuth each sensor faces, rad
    noise_cov: Array  #: ``(M, m, m)``
    truth: Array
    alive: Array
    in_view: Array
    returns: Array
    counts: Array
    origin: Array
    #: a recorded truth: each target's recorded id and name or call sign, the geodetic origin of the local
    #: frame (lat deg, lon deg, height m) and the first scan's UTC time (s); None for a simulated one
    recorded: RecordedTargets | None = None
    geodetic_origin: tuple[float, float, float] | None = None
    #: the GOSPA cut-off (m) every evaluation of this run uses (the recorder, the viewer, the bench)
    gospa_cutoff: float = 50.0

    def target_label(self, target: int) -> str:
        """What the viewer calls target ``target``: its name or call sign when recorded, else ``t<id>``."""
        if self.recorded is not None and 0 <= target < len(self.recorded.labels):
            return self.recorded.labels[target]
        return f"t{target}"

    @property
    def steps(self) -> int:
        return int(self.alive.shape[0])

    @property
    def nodes(self) -> int:
        """The sensors, one tracker each."""
        return int(self.sensors.shape[0])

    def truth_at(self, step: int) -> tuple[Array, Array]:
        """The targets present at ``step``: their ids ``(N,)`` and states ``(N, 6)``."""
        ids = np.flatnonzero(self.alive[step])
        return ids, self.truth[step, ids]

    def scan(self, step: int, sensor: int) -> Scan:
        """What sensor ``sensor`` reports at ``step``: its shuffled returns, unlabelled."""
        j = int(self.counts[step, sensor])
        return Scan(step, sensor, self.returns[step, sensor, :j].copy(), self.sensors[sensor], self.noise_cov[sensor])

    def origins(self, step: int, sensor: int) -> Array:
        """The target id of each return of that scan, :data:`CLUTTER` for clutter (evaluation only)."""
        return self.origin[step, sensor, : int(self.counts[step, sensor])].copy()


def view_volume(sensing: SensingSpec) -> float:
    """The volume (m^3) of a point sensor's field of view: range ``R``, azimuth width ``W``, elevations
    ``[lo, hi]``: ``V = W (sin hi - sin lo) R^3 / 3`` (the integral of ``r^2 cos(el)`` over the view)."""
    lo, hi = sensing.fov_elevation
    return float(min(sensing.fov_azimuth, 2 * np.pi) * (np.sin(hi) - np.sin(lo)) * sensing.max_range**3 / 3.0)


def clutter_density(sensing: SensingSpec, measurement: str = "point") -> float:
    """``lambda``, clutter returns per scan and unit of measurement space: a point sensor's per m^3 (the rate
    over :func:`view_volume`), a bearing sensor's per rad^2 of (azimuth, elevation) (the rate over the view's
    width times its elevation span: its clutter is uniform in angle). It must be positive for the associators,
    so a scenario without clutter gets one return per 1000 views."""
    if measurement == "bearing":
        lo, hi = sensing.fov_elevation
        return max(sensing.clutter_rate, 1e-3) / (min(sensing.fov_azimuth, 2 * np.pi) * (hi - lo))
    return max(sensing.clutter_rate, 1e-3) / view_volume(sensing)


def boresights(sensors: Array, centre: Array) -> Array:
    """The azimuth ``(M,)`` from each sensor to ``centre`` (what its field of view is centred on)."""
    d = np.asarray(centre, dtype=float)[None, :2] - np.asarray(sensors, dtype=float)[:, :2]
    return np.arctan2(d[:, 1], d[:, 0])


def in_field_of_view(points: Array, sensors: Array, boresight: Array, sensing: SensingSpec) -> Array:
    """Whether each of ``points`` ``(..., M, P, 3)`` lies in range and in the field of view of sensor m
    (``sensors`` ``(M, 3)``, ``boresight`` ``(M,)``): a ``(..., M, P)`` bool array (NaN points: False)."""
    d = points - sensors[:, None, :]
    horizontal = np.hypot(d[..., 0], d[..., 1])
    az_off = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - boresight[:, None])
    el = np.arctan2(d[..., 2], horizontal)
    lo, hi = sensing.fov_elevation
    with np.errstate(invalid="ignore"):
        return ((np.hypot(horizontal, d[..., 2]) <= sensing.max_range) & (np.abs(az_off) <= sensing.fov_azimuth / 2)
                & (el >= lo) & (el <= hi))


def _noise_factor(q: Array) -> Array:
    """A square root ``L`` with ``L L^T = Q`` for a positive semi-definite ``Q`` (eigen-decomposition)."""
    w, v = np.linalg.eigh(q)
    return v * np.sqrt(np.clip(w, 0.0, None))


def _lifetimes(mt: TargetsSpec, steps: int, ts: float, rng: np.random.Generator) -> tuple[Array, Array, Array]:
    """Birth steps, death steps and birth states of every target of the run: the layout's, then Poisson
    births; a lifetime is geometric in ``survival_prob`` and cut at a given death time."""
    def to_step(times: Array) -> Array:  # the first step at or after each time
        return np.ceil(np.asarray(times, dtype=float) / ts - 1e-9)

    first = mt.initial_states(rng)
    birth = np.zeros(mt.count) if mt.birth_times is None else to_step(mt.birth_times)
    per_step = rng.poisson(mt.birth_rate * ts, steps)
    per_step[0] = 0
    later = np.repeat(np.arange(steps), per_step)[: max(mt.max_targets - mt.count, 0)]
    birth = np.concatenate([birth, later])
    states = np.vstack([first, mt.random_states(later.size, rng)])
    death = np.full(birth.size, np.inf)
    if mt.death_times is not None:
        death[: mt.count] = to_step(mt.death_times)
    if mt.survival_prob < 1.0:
        death = np.minimum(death, birth + rng.geometric(1.0 - mt.survival_prob, birth.size))
    return birth, death, states


def simulate_multitarget(spec: ScenarioSpec, mt: MultiTargetSpec, seed: int = 0, ts: float = 0.1) -> MultiTargetData:
    """One run of many targets over ``spec``'s sensors (module docstring); deterministic in ``seed``."""
    from zentrack.fusion.multitarget.metrics import GOSPA_CUTOFF  # SciPy's assignment: the simulation's side only

    spec.validate()
    if spec.plant not in MULTITARGET_PLANTS or spec.measurement not in MULTITARGET_MEASUREMENTS or spec.moving:
        raise ValueError(f"many targets need fixed sensors, plant in {MULTITARGET_PLANTS} and measurement in "
                         f"{MULTITARGET_MEASUREMENTS}, got {spec.plant!r} and {spec.measurement!r}")
    truth_rng, detect_rng, clutter_rng = (np.random.default_rng(c) for c in np.random.SeedSequence(seed).spawn(3))
    steps, sensors = spec.steps, np.asarray(spec.sensors, dtype=float)
    plant = make_plant(spec.plant, ts, spec.plant_params)
    recorded = None
    if mt.targets.recording is not None:  # the recording's targets, interpolated to the scans
        recorded = recorded_targets(mt.targets.recording, steps, ts)
        truth, alive = recorded.truth, recorded.alive
        n_targets = truth.shape[1]
    else:
        truth, alive = _simulated_truth(mt.targets, plant, steps, ts, truth_rng)
        n_targets = truth.shape[1]
    sensing = mt.sensing
    boresight = boresights(sensors, mt.targets.centre)
    n_sensors = sensors.shape[0]
    positions = np.broadcast_to(truth[:, None, :, :3], (steps, n_sensors, n_targets, 3))
    in_view = in_field_of_view(positions, sensors, boresight, sensing) & alive[:, None, :]
    detected = in_view & (detect_rng.random(in_view.shape) < sensing.detection_prob)
    model = make_measurement(spec.measurement)
    m = model.dim
    stds = spec.noise_levels()
    flat = np.nan_to_num(truth).reshape(steps * n_targets, 6)
    z = model.h(flat, np.broadcast_to(sensors, (flat.shape[0], n_sensors, 3)))  # (K*T, M*m)
    z = z.reshape(steps, n_targets, n_sensors, m).transpose(0, 2, 1, 3)
    z = z + stds[None, :, None, None] * detect_rng.standard_normal(z.shape)
    n_clutter = clutter_rng.poisson(sensing.clutter_rate, (steps, n_sensors))
    clutter = _clutter(spec.measurement, sensors, boresight, sensing, int(n_clutter.max(initial=0)), steps, clutter_rng)
    if spec.measurement == "bearing":
        z[..., 0] = wrap_angle(z[..., 0])
    # every candidate of a scan (each target, then each clutter slot), shuffled by random keys; invalid ones last
    values = np.concatenate([z, clutter], axis=2)
    ids = np.concatenate([np.broadcast_to(np.arange(n_targets), (steps, n_sensors, n_targets)),
                          np.full((steps, n_sensors, clutter.shape[2]), CLUTTER)], axis=2)
    valid = np.concatenate([detected, np.arange(clutter.shape[2]) < n_clutter[..., None]], axis=2)
    keys = np.where(valid, clutter_rng.random(valid.shape), 2.0)
    counts = valid.sum(axis=2)
    order = np.argsort(keys, axis=2, kind="stable")[..., : int(counts.max(initial=0))]
    kept = np.take_along_axis(valid, order, axis=2)
    returns = np.where(kept[..., None], np.take_along_axis(values, order[..., None], axis=2), 0.0)
    origin = np.where(kept, np.take_along_axis(ids, order, axis=2), PADDING)
    return MultiTargetData(
        name=spec.name, measurement=spec.measurement, ts=ts, seed=seed, sensors=sensors, boresight=boresight,
        noise_cov=(stds**2)[:, None, None] * np.eye(m), truth=truth, alive=alive, in_view=in_view, returns=returns,
        counts=counts, origin=origin, recorded=recorded,
        geodetic_origin=None if mt.targets.recording is None else mt.targets.recording.origin,
        gospa_cutoff=GOSPA_CUTOFF if mt.targets.gospa_cutoff is None else mt.targets.gospa_cutoff)


def _simulated_truth(targets: TargetsSpec, plant, steps: int, ts: float,
                     rng: np.random.Generator) -> tuple[Array, Array]:
    """Truth ``(K, T, 6)`` and presence ``(K, T)`` of simulated targets: each starts from its birth state and
    moves by the plant while present."""
    birth, death, states = _lifetimes(targets, steps, ts, rng)
    n_targets = birth.size
    k = np.arange(steps)[:, None]
    alive = (k >= birth) & (k < death)
    noise = rng.standard_normal((steps, n_targets, 6)) @ _noise_factor(plant.Q).T
    truth = np.full((steps, n_targets, 6), np.nan)
    x = np.zeros((n_targets, 6))
    for step in range(steps):
        x = np.where((birth == step)[:, None], states, x)
        truth[step] = np.where(alive[step][:, None], x, np.nan)
        x = plant.f(x) + noise[step]
    return truth, alive


def _clutter(kind: str, sensors: Array, boresight: Array, sensing: SensingSpec, most: int, steps: int,
             rng: np.random.Generator) -> Array:
    """``most`` clutter returns per scan ``(K, M, most, m)`` uniform in each sensor's field of view: in angle
    (azimuth, elevation) for bearing sensors, in volume for point sensors (range ~ R u^(1/3), sin(elevation)
    uniform), positions in the world frame."""
    u = rng.random((steps, sensors.shape[0], most, 3))
    az = boresight[:, None] + (u[..., 0] - 0.5) * min(sensing.fov_azimuth, 2 * np.pi)
    lo, hi = sensing.fov_elevation
    if kind == "bearing":
        return np.stack([wrap_angle(az), lo + u[..., 1] * (hi - lo)], axis=-1)
    el = np.arcsin(np.sin(lo) + u[..., 1] * (np.sin(hi) - np.sin(lo)))
    r = sensing.max_range * np.cbrt(u[..., 2])
    offset = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=-1)
    return sensors[:, None, :] + offset
