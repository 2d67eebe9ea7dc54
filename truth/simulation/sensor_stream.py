"""A sensor of its own, simulated: when it samples, what it reports, what its clock says and when it publishes.

Sensors of their own (issue 52) do not sample on the run's grid. Sensor s samples the scenario's world at its own
rate and phase, ``t_n = phase_s + n / rate_hz`` seconds after the run's start, detects the target with probability
``detection_prob`` and reports ``h(x(t_n), pose) + v``, v ~ N(0, R_s) (the scenario's noise of sensor s). It stamps
the measurement with its own clock, ``stamp = t0 + t_n + offset_s + drift_ppm 1e-6 t_n``, and publishes it after
a latency drawn per detection (:class:`Latency`); a share ``reorder`` of the detections is held one sample period
more, so it arrives after the next one. Every draw comes from the sensor's own stream (``SeedSequence([seed,
SENSOR_SEED, s])``), so a sensor process and the batched bench draw the same detections.

The world between the truth's samples (``ScenarioData.truth``, ``ts`` apart) is the cubic Hermite interpolation of
position and velocity for the plants whose state is [p, v] (and linear interpolation of the rest): within a
sample period of a manoeuvring target its error is centimetres, far below any sensor's noise here.

A scenario with clutter (``[clutter]``) or many targets (``[targets]``) is sampled the same way, each scan drawn by
the code that draws the synchronous truth's scans, at the sensor's times instead of the steps: one target among
uniform clutter (:func:`~.clutter.generate_clutter_scans`, P_D the scenario's times ``detection_prob``), or
every target present and in view, each detected with the scenario's P_D times ``detection_prob``, among Poisson
clutter in the field of view (:func:`~.mt_sensors.sense_at`; a target is present at a time when it is at both
steps around it). These draws come from the children of the sensor's own ``[seed, SENSOR_SEED, s, WORLD_SEED]``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.models import make_measurement

from .clutter import ClutterSpec, generate_clutter_scans
from .mt_sensors import sense_at
from .scenario import ScenarioData

if TYPE_CHECKING:
    from .multitarget import MultiTargetData, MultiTargetSpec

Array = np.ndarray

#: the sensor streams' seed stream (beside the truth's and the clutter's); a sensor's detections, noise and clutter
#: of a cluttered or many-target world draw from the children of its own ``[seed, SENSOR_SEED, s, WORLD_SEED]``
SENSOR_SEED, WORLD_SEED = 52, 1
#: plants whose state is [p, v] in 3-D: interpolated by cubic Hermite on the position
HERMITE_PLANTS = ("cv3d", "cv3d-cd")
#: latency distributions a sensor may have
LATENCY_KINDS = ("fixed", "uniform", "exponential")


@dataclass(frozen=True)
class Latency:
    """A detection's latency (s): ``fixed`` (``low_s``), ``uniform`` (``low_s`` to ``high_s``) or ``exponential``
    (``low_s`` plus an exponential of mean ``mean_s``, capped at ``high_s``)."""

    kind: str = "fixed"
    low_s: float = 0.0
    high_s: float = 0.0
    mean_s: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in LATENCY_KINDS:
            raise ValueError(f"latency kind {self.kind!r}: choose one of {', '.join(LATENCY_KINDS)}")
        if not (0 <= self.low_s <= 60 and (self.kind == "fixed" or self.low_s <= self.high_s <= 60)
                and 0 <= self.mean_s <= 60):
            raise ValueError(f"latency: need 0 <= low_s <= high_s <= 60 s and 0 <= mean_s <= 60 s, got {self}")

    def draw(self, rng: np.random.Generator, count: int) -> Array:
        if self.kind == "fixed":
            return np.full(count, self.low_s)
        if self.kind == "uniform":
            return rng.uniform(self.low_s, self.high_s, count)
        return np.minimum(self.low_s + rng.exponential(self.mean_s, count), self.high_s)


@dataclass(frozen=True)
class SensorStreamSpec:
    """Sensor ``sensor``'s own timing (module docstring)."""

    sensor: int
    rate_hz: float
    phase_s: float = 0.0
    offset_s: float = 0.0
    drift_ppm: float = 0.0
    latency: Latency = Latency()
    reorder: float = 0.0
    detection_prob: float = 1.0

    def __post_init__(self) -> None:
        where = f"sensor {self.sensor}"
        if not 0 < self.rate_hz <= 1000:
            raise ValueError(f"{where}: rate_hz must be above 0 and at most 1000, got {self.rate_hz}")
        if not 0 <= self.phase_s < 1.0 / self.rate_hz:
            raise ValueError(f"{where}: phase_s must be from 0 to one period ({1.0 / self.rate_hz:g} s), got {self.phase_s}")
        if not (abs(self.offset_s) <= 3600 and abs(self.drift_ppm) <= 1e4):
            raise ValueError(f"{where}: offset_s within 3600 s and drift_ppm within 10000, got {self.offset_s}, {self.drift_ppm}")
        if not (0 <= self.reorder <= 1 and 0 < self.detection_prob <= 1):
            raise ValueError(f"{where}: reorder from 0 to 1 and detection_prob above 0 up to 1, got {self.reorder}, "
                             f"{self.detection_prob}")


@dataclass
class SimulatedDetection:
    """One scan of a sensor: when it was measured (run time, s after t0), its stamp less t0 on the sensor's clock,
    when it is published (run time), its sequence number and returns ``(J, m)`` (J = 0: missed)."""

    seq: int
    t: float
    stamp: float
    t_publish: float
    returns: Array


def interpolate(truth: Array, ts: float, t: Array, hermite: bool) -> tuple[Array, Array]:
    """States sampled every ``ts`` s, ``truth`` ``(K, ..., n)`` (NaN: absent), at the times ``t`` (s after the first
    sample; module docstring): ``(len(t), ..., n)``, and where each is present ``(len(t), ...)``: at both samples
    around its time (at one exactly, that one). ``hermite``: a [p, v] state, cubic Hermite on the position."""
    t = np.asarray(t, dtype=float)
    k = np.clip(np.floor(t / ts).astype(int), 0, truth.shape[0] - 2)
    u = np.clip(t / ts - k, 0.0, 1.0)
    a, b = truth[k], truth[k + 1]
    a_in, b_in = np.isfinite(a).all(axis=-1), np.isfinite(b).all(axis=-1)
    w = u.reshape((-1,) + (1,) * (truth.ndim - 1))
    present = np.where(w[..., 0] == 0, a_in, np.where(w[..., 0] == 1, b_in, a_in & b_in))
    a, b = np.where(a_in[..., None], a, b), np.where(b_in[..., None], b, a)  # (one end absent: not present anyway)
    out = (1 - w) * a + w * b
    if hermite:  # cubic Hermite on position, velocity given
        h00, h10, h01, h11 = 2 * w**3 - 3 * w**2 + 1, w**3 - 2 * w**2 + w, -2 * w**3 + 3 * w**2, w**3 - w**2
        out[..., :3] = h00 * a[..., :3] + h10 * ts * a[..., 3:] + h01 * b[..., :3] + h11 * ts * b[..., 3:]
    return np.where(present[..., None], out, np.nan), present


def state_at(scn: ScenarioData, run: int, t: Array) -> Array:
    """The true state ``(len(t), n)`` of run ``run`` at run times ``t`` (s after t0; module docstring)."""
    truth = scn.truth[run]
    return interpolate(truth, scn.ts, t, truth.shape[1] == 6 and scn.plant in HERMITE_PLANTS)[0]


def sample_times(steps: int, ts: float, spec: SensorStreamSpec) -> Array:
    """When sensor ``spec`` samples a run of ``steps`` steps ``ts`` apart (run time, up to its last step)."""
    horizon = (steps - 1) * ts
    t = spec.phase_s + np.arange(int(np.floor((horizon - spec.phase_s) * spec.rate_hz)) + 1) / spec.rate_hz
    return t[t <= horizon]


def published(spec: SensorStreamSpec, t: Array, returns: list[Array], rng: np.random.Generator) -> list[SimulatedDetection]:
    """The scans ``returns`` measured at ``t``, stamped on the sensor's clock and published after their latency."""
    count = t.size
    latency = spec.latency.draw(rng, count) + np.where(rng.random(count) < spec.reorder, 1.0 / spec.rate_hz, 0.0)
    stamp = t + spec.offset_s + spec.drift_ppm * 1e-6 * t
    return [SimulatedDetection(n, float(t[n]), float(stamp[n]), float(t[n] + latency[n]), returns[n])
            for n in range(count)]


def world_rngs(seed: int, spec: SensorStreamSpec) -> tuple[np.random.Generator, np.random.Generator]:
    """The generators of a sensor's detections and noise, and of its clutter (apart from its timing's)."""
    a, b = np.random.SeedSequence([seed, SENSOR_SEED, spec.sensor, WORLD_SEED]).spawn(2)
    return np.random.default_rng(a), np.random.default_rng(b)


def sensor_stream(scn: ScenarioData, spec: SensorStreamSpec, seed: int, run: int = 0,
                  clutter: ClutterSpec | None = None) -> list[SimulatedDetection]:
    """Every scan sensor ``spec.sensor`` makes during the run ``run`` of ``scn`` (up to its last sample time), in the
    order it measures them (module docstring); ``clutter``: the scenario's ``[clutter]``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, SENSOR_SEED, spec.sensor]))
    t = sample_times(scn.steps, scn.ts, spec)
    count = t.size
    meas = make_measurement(scn.measurement, scn.linear_matrix)
    pose = scn.sensors[spec.sensor]
    x = state_at(scn, run, t)
    if clutter is not None:  # the synchronous truth's clutter, P_D and noise (clutter.py), at the sensor's times
        az, el = clutter.windows(scn.nodes)
        own = replace(clutter, p_d=clutter.p_d * spec.detection_prob, az_window=az[spec.sensor],
                      el_window=el[spec.sensor])
        drawn = generate_clutter_scans(x[None], pose[None], scn.noise_cov[spec.sensor], own,
                                       world_rngs(seed, spec)[1])
        return published(spec, t, [drawn.scan(0, n, 0) for n in range(count)], rng)
    z = meas.h(x, np.broadcast_to(pose, (count, 1, 3)))
    z = z + rng.multivariate_normal(np.zeros(meas.dim), scn.noise_cov[spec.sensor], count)
    if scn.measurement == "bearing":
        z = wrap_angle(z)
    detected = rng.random(count) < spec.detection_prob
    return published(spec, t, [z[n][None] if detected[n] else np.zeros((0, meas.dim)) for n in range(count)], rng)


def multitarget_truth_at(data: MultiTargetData, t: Array) -> tuple[Array, Array]:
    """The targets of the many-target run ``data`` at run times ``t`` (s after t0, between its steps): their states
    ``(len(t), T, 6)`` (NaN: absent) and where each is present ``(len(t), T)`` (the plants are [p, v]: Hermite)."""
    return interpolate(data.truth, data.ts, t, hermite=True)


def multitarget_stream(data: MultiTargetData, mt: MultiTargetSpec, std: float, spec: SensorStreamSpec,
                       seed: int) -> list[SimulatedDetection]:
    """Every scan sensor ``spec.sensor`` of the many-target run ``data`` (targets and sensing ``mt``, noise level
    ``std``) makes, in the order it measures them: the targets present and in its view at its own times, each
    detected with the scenario's P_D times its ``detection_prob``, measured with its noise, among the scenario's
    Poisson clutter, shuffled (the truth's own draws for the synchronous runs, :func:`~.mt_sensors.sense_at`)."""
    t = sample_times(data.steps, data.ts, spec)
    truth, present = multitarget_truth_at(data, t)
    kind = data.kind(spec.sensor)
    sensing = mt.sensing_of(kind)
    sensing = replace(sensing, detection_prob=sensing.detection_prob * spec.detection_prob)
    detect_rng, clutter_rng = world_rngs(seed, spec)
    got = sense_at(data.sensors[[spec.sensor]], np.array([std]), (kind,), {kind: sensing}, mt.targets.centre,
                   truth, present, detect_rng, clutter_rng)
    dim = make_measurement(kind).dim
    returns = [got.returns[n, 0, : int(got.counts[n, 0]), :dim].copy() for n in range(t.size)]
    return published(spec, t, returns, np.random.default_rng(np.random.SeedSequence([seed, SENSOR_SEED, spec.sensor])))
