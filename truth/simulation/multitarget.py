"""Many targets seen by a sensor network: births and deaths, missed detections, a limited field of view, clutter.

A :class:`MultiTargetSpec` adds to a :class:`~zentrack.truth.simulation.scenario_spec.ScenarioSpec` (plant, sensors,
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
move the targets. (Paper 1's :mod:`~zentrack.truth.simulation.clutter` draws one target per scan in fixed
bearing windows; these scans are many-target and sensor-relative, so only its angle wrapping is shared.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zentrack.fusion.models import make_measurement, make_plant
from zentrack.fusion.scan import Scan

from .mt_sensors import CLUTTER, PADDING, SensingSpec, boresights, in_field_of_view, sense
from .recorded.recording import RecordedTargets, RecordingSpec, recorded_targets
from .scenario_spec import POSITION_VELOCITY_PLANTS, ScenarioSpec

Array = np.ndarray

TARGET_LAYOUTS = ("crossing", "random", "explicit", "recorded")
#: plants whose state is [position (3), velocity (3)], the only ones a many-target scenario moves
MULTITARGET_PLANTS = POSITION_VELOCITY_PLANTS
MULTITARGET_MEASUREMENTS = ("point", "bearing")
__all__ = ["CLUTTER", "PADDING", "SensingSpec", "boresights", "in_field_of_view"]  # (mt_sensors') names this module's users import


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
class MultiTargetSpec:
    """A many-target scenario's targets and sensing (the network is its :class:`ScenarioSpec`)."""

    targets: TargetsSpec
    sensing: SensingSpec
    #: each sensor's measurement kind in a mixed network (bearing-only cameras and point radars); empty: every
    #: sensor measures by the scenario's kind
    kinds: tuple[str, ...] = ()
    #: ``(kind, sensing)``: a kind's own sensing where it differs from ``sensing`` (``[sensing.<kind>]``)
    kind_sensing: tuple[tuple[str, SensingSpec], ...] = ()

    def sensor_kinds(self, default: str, nodes: int) -> tuple[str, ...]:
        """Every sensor's measurement kind (``default``: the scenario's)."""
        return self.kinds or (default,) * nodes

    def sensing_of(self, kind: str) -> SensingSpec:
        """What a sensor of measurement kind ``kind`` sees."""
        return dict(self.kind_sensing).get(kind, self.sensing)


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
    measurement: str  #: the sensors' kind, ``"mixed"`` when they differ (``kinds``)
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
    #: each sensor's measurement kind (empty: every one ``measurement``)
    kinds: tuple[str, ...] = ()

    def kind(self, sensor: int) -> str:
        """Sensor ``sensor``'s measurement kind."""
        return self.kinds[sensor] if self.kinds else self.measurement

    def target_label(self, target: int) -> str:
        """What the viewer calls target ``target``: its name or call sign when recorded, else ``t<id>``."""
        if self.recorded is not None and 0 <= target < len(self.recorded.labels):
            return self.recorded.labels[target]
        return f"t{target}"

    def target_name(self, target: int) -> str | None:
        """Target ``target``'s vessel name or call sign, where the recording has one (None: only an id)."""
        if self.recorded is None or not 0 <= target < len(self.recorded.labels):
            return None
        label = self.recorded.labels[target]
        return label if label != self.recorded.ids[target] else None

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
        j, m = int(self.counts[step, sensor]), make_measurement(self.kind(sensor)).dim
        return Scan(step, sensor, self.returns[step, sensor, :j, :m].copy(), self.sensors[sensor],
                    self.noise_cov[sensor, :m, :m])

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
    else:
        truth, alive = _simulated_truth(mt.targets, plant, steps, ts, truth_rng)
    kinds = mt.sensor_kinds(spec.measurement, spec.nodes)
    got = sense(spec, kinds, {k: mt.sensing_of(k) for k in kinds}, mt.targets.centre, truth, alive, detect_rng,
                clutter_rng)
    kinds = kinds if len(set(kinds)) > 1 else ()
    return MultiTargetData(
        name=spec.name, measurement="mixed" if kinds else spec.measurement, ts=ts, seed=seed, sensors=sensors,
        boresight=got.boresight, noise_cov=got.noise_cov, truth=truth, alive=alive, in_view=got.in_view,
        returns=got.returns, counts=got.counts, origin=got.origin, recorded=recorded, kinds=kinds,
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
