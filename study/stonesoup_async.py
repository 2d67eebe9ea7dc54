"""Stone Soup on the detections of ``zentrack bench async``, in one process: its out-of-sequence processing, and its
time-buffered feeder.

Both are one **centralized** track fed every sensor's detections in the order they arrive (their publication time),
each at its measurement time on the trackers' clocks (the stamp less the offset, as the trackers are told), with

- motion: the scenario's plant over each interval, ``(A(dt), Q(dt))`` of :func:`~zentrack.fusion.models.plant_over`
  (what zentrack's filters predict with; exp2's velocity-dependent acceleration is not in it: Stone Soup's filter is a
  plain Kalman filter, where zentrack's TESKF estimates that term as its lumped state);
- measurement: each bearing sensor's ``CartesianToElevationBearing``
  (:func:`~zentrack.study.stonesoup_bearing.angle_model`), a point sensor's ``LinearGaussian``, linearised at the
  predicted state as its ``ExtendedKalmanUpdater`` does;
- the prior: each run's initial estimate and ``P0`` at time 0.

**ASD** (:func:`run_stonesoup_asd`): accumulated state densities (Koch & Govaers, "On accumulated state densities with
applications to out-of-sequence measurement processing", IEEE TAES 47(4), 2011; Govaers & Koch, IEEE TAES 50(3),
2014): ``ASDKalmanPredictor`` and ``ASDKalmanUpdater`` carry the joint density of the states at the last
``max_nstep`` detection times, so a late detection is predicted from the state before it and updates all of them at
once (exact for a linear-Gaussian model). Its updater takes the measurement matrix of a linear model only, so for
bearings it gets the Jacobian the way the ``ExtendedKalmanUpdater`` does (``_measurement_matrix``), at the state of
the detection's time. ``max_nstep`` covers the latest detection of the stream; one older than every time kept is
counted too old.

**Time-buffered** (:func:`run_stonesoup_buffered`): Stone Soup's ``TimeBufferedFeeder`` holds ``buffer_size``
detections and gives out the oldest when a new one comes (dropping one older than all it holds); what it gives out,
in time order, goes through ``KalmanPredictor`` and ``ExtendedKalmanUpdater``.

At every fusion tick the newest state is predicted to ``t_k`` (``KalmanPredictor``) and scored like the trackers'
published estimates; nothing waits, so the age is the processor time. A run whose estimate stops being finite and
positive definite (or whose filter raises) is diverged from that tick.
"""
from __future__ import annotations

import datetime
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.sensor_stream import SensorStreamSpec, SimulatedDetection

from .async_network import interval_plant, tick_times, tracker_time
from .stonesoup_bearing import angle_detection, angle_model

Array = np.ndarray
START = datetime.datetime(2000, 1, 1)
#: Stone Soup keeps at most this many detection times (its matrices grow with their square)
MAX_NSTEP = 64


@dataclass
class StoneSoupRun:
    """One run: the estimate at every tick ``mean`` ``(K, 1, n)``, ``cov`` ``(K, 1, n, n)`` (NaN from a tick it
    diverged at), its age ``(K, 1)`` s, the processor time (s) and what became of the detections."""

    mean: Array
    cov: Array
    age: Array
    cpu_s: float
    arrived: int = 0
    applied: int = 0  #: in time order
    late: int = 0  #: older than the newest state, applied all the same (ASD)
    too_old: int = 0  #: dropped: older than every time it keeps (ASD), or than every detection in its buffer
    diverged_at: int = -1  #: the tick from which its estimate stopped being finite and positive definite (-1: never)


def _classes() -> tuple[type, type]:
    """The interval plant as a Stone Soup transition model, and the ASD updater with the EKF's Jacobian (defined
    once Stone Soup is imported: it is optional)."""
    from stonesoup.base import Property
    from stonesoup.models.base import TimeVariantModel
    from stonesoup.models.transition.linear import LinearGaussianTransitionModel
    from stonesoup.types.array import CovarianceMatrix
    from stonesoup.updater.asd import ASDKalmanUpdater
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    class IntervalPlant(LinearGaussianTransitionModel, TimeVariantModel):
        """``x+ = A(dt) x + w``, ``w ~ N(0, Q(dt))``: the scenario's plant over the interval (identity for none)."""

        over: Any = Property(doc="dt -> (A, Q) (zentrack.study.async_network.interval_plant)")
        dim: int = Property(doc="the state's dimension")

        @property
        def ndim_state(self) -> int:
            return int(self.dim)

        def matrix(self, time_interval: datetime.timedelta, **kwargs) -> np.ndarray:
            dt = time_interval.total_seconds()
            return np.eye(self.dim) if dt <= 1e-9 else self.over(dt)[0]

        def covar(self, time_interval: datetime.timedelta, **kwargs) -> CovarianceMatrix:
            dt = time_interval.total_seconds()
            return CovarianceMatrix(np.zeros((self.dim, self.dim)) if dt <= 1e-9 else self.over(dt)[1])

    class ASDExtendedKalmanUpdater(ASDKalmanUpdater):
        """Stone Soup's ASD updater with the measurement matrix of its ``ExtendedKalmanUpdater`` (the Jacobian of a
        nonlinear model at the state of the detection's time)."""

        _measurement_matrix = ExtendedKalmanUpdater._measurement_matrix

    return IntervalPlant, ASDExtendedKalmanUpdater


def max_nstep(rate_hz: float, latest_s: float) -> int:
    """Detection times Stone Soup keeps: those of the network's ``rate_hz`` detections a second over ``latest_s``,
    two more, at most :data:`MAX_NSTEP`."""
    return min(MAX_NSTEP, int(math.ceil(rate_hz * latest_s)) + 2)


def _detections(scn: ScenarioData, detections: Sequence[Sequence[SimulatedDetection]],
                specs: Sequence[SensorStreamSpec]) -> list[tuple[float, int, float, int, Any]]:
    """The trackers' order of events for one run: ``(wall time, 0 tick / 1 detection, time, node, Stone Soup
    detection or None)``, a tick before a detection at one instant; each detection made before the clock starts (as
    zentrack's scans are), stamped with its measurement time on the trackers' clocks."""
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection

    n, bearing = scn.truth.shape[-1], scn.measurement == "bearing"
    models = [angle_model(scn.sensors[i], scn.noise_cov[i]) if bearing else
              LinearGaussian(ndim_state=n, mapping=tuple(range(scn.noise_cov.shape[-1])), noise_covar=scn.noise_cov[i])
              for i in range(scn.nodes)]
    ticks = tick_times(scn)
    events: list[tuple[float, int, float, int, Any]] = [(round(float(t), 9), 0, float(t), -1, None) for t in ticks]
    for i, dets in enumerate(detections):
        for d in dets:
            if d.returns.shape[0] == 0 or d.t_publish > ticks[-1]:
                continue
            when = START + datetime.timedelta(seconds=tracker_time(d, specs[i]))
            z = d.returns[0]
            made = (angle_detection(z, when, models[i]) if bearing
                    else Detection(StateVector(z), timestamp=when, measurement_model=models[i]))
            events.append((round(d.t_publish, 9), 1, d.t, i, made))
    events.sort(key=lambda e: e[:4])
    return events


def _run(scn: ScenarioData, events: list[tuple[float, int, float, int, Any]], take: Callable[[Any], None],
         latest: Callable[[], Any], out: StoneSoupRun) -> StoneSoupRun:
    """The event loop: ``take(detection)`` on each arrival, and at each tick the newest state ``latest()`` predicted to
    it and scored into ``out``. A tick whose estimate is not finite and positive definite, or a filter that raises,
    ends the run there (NaN from that tick: diverged)."""
    from stonesoup.predictor.kalman import KalmanPredictor

    plant_class, _ = _classes()
    n = scn.truth.shape[-1]
    to_tick = KalmanPredictor(plant_class(over=interval_plant(scn), dim=n))
    ticks = tick_times(scn)
    clock, k = time.process_time_ns, 0
    for _, kind, _, _, det in events:
        c0 = clock()
        try:
            if kind == 1:
                out.arrived += 1
                take(det)
                out.cpu_s += (clock() - c0) * 1e-9
                continue
            when = START + datetime.timedelta(seconds=float(ticks[k]))
            state = latest()
            at_tick = state if state.timestamp == when else to_tick.predict(state, timestamp=when)
            m, p = np.ravel(at_tick.state_vector).astype(float), np.asarray(at_tick.covar, dtype=float)
            if not (np.isfinite(m).all() and np.isfinite(p).all() and np.linalg.eigvalsh(p).min() > 0):
                raise np.linalg.LinAlgError("the estimate is not finite and positive definite")
        except np.linalg.LinAlgError:
            out.diverged_at = k
            break
        out.mean[k, 0], out.cov[k, 0] = m, p
        spent = (clock() - c0) * 1e-9
        out.age[k, 0] = spent
        out.cpu_s += spent
        k += 1
    return out


def _empty(scn: ScenarioData) -> StoneSoupRun:
    k, n = scn.steps, scn.truth.shape[-1]
    return StoneSoupRun(np.full((k, 1, n), np.nan), np.full((k, 1, n, n), np.nan), np.zeros((k, 1)), 0.0)


def run_stonesoup_asd(scn: ScenarioData, run: int, detections: Sequence[Sequence[SimulatedDetection]],
                      specs: Sequence[SensorStreamSpec], nstep: int) -> StoneSoupRun:
    """Run ``run``: every node's detections to one Stone Soup ASD track in arrival order (module docstring)."""
    from stonesoup.predictor.asd import ASDKalmanPredictor
    from stonesoup.types.array import StateVector
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import ASDGaussianState

    plant_class, updater_class = _classes()
    predictor = ASDKalmanPredictor(plant_class(over=interval_plant(scn), dim=scn.truth.shape[-1]))
    updater = updater_class(None)
    track = [ASDGaussianState(multi_state_vector=StateVector(np.asarray(scn.x0_estimate[run], dtype=float)),
                              multi_covar=np.asarray(scn.p0, dtype=float), timestamps=[START], max_nstep=nstep)]

    out = _empty(scn)

    def take(det: Any) -> None:
        state = track[0]
        if det.timestamp < state.timestamps[-1]:
            out.too_old += 1  # older than every time it keeps
            return
        if det.timestamp < state.timestamp:
            out.late += 1
        else:
            out.applied += 1
        track[0] = updater.update(SingleHypothesis(predictor.predict(state, timestamp=det.timestamp), det))

    return _run(scn, _detections(scn, detections, specs), take, lambda: track[0].state, out)


def run_stonesoup_buffered(scn: ScenarioData, run: int, detections: Sequence[Sequence[SimulatedDetection]],
                           specs: Sequence[SensorStreamSpec], buffer_size: int) -> StoneSoupRun:
    """Run ``run`` through Stone Soup's ``TimeBufferedFeeder`` (module docstring): the detections in arrival order
    go into its buffer of ``buffer_size``, which gives out the oldest once full (and drops one older than all it
    holds); those it gives out update one track by ``KalmanPredictor`` and ``ExtendedKalmanUpdater`` in time order."""
    import warnings

    from stonesoup.feeder.time import TimeBufferedFeeder
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import StateVector
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    plant_class, _ = _classes()
    predictor = KalmanPredictor(plant_class(over=interval_plant(scn), dim=scn.truth.shape[-1]))
    updater = ExtendedKalmanUpdater(None)
    events = _detections(scn, detections, specs)
    arrived = [det for _, kind, _, _, det in events if kind == 1]
    # what the feeder gives out after each arrival: it reads one arrival at a time and yields when its buffer is full
    read = [0]

    def reader():
        for det in arrived:
            read[0] += 1
            yield det.timestamp, {det}

    released: dict[int, list[Any]] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # its '"Old" detection dropped'
        for _, dets in TimeBufferedFeeder(reader(), buffer_size=buffer_size):
            if read[0] < len(arrived):  # (what it flushes once the reader is done comes after the run)
                released.setdefault(read[0] - 1, []).extend(dets)
    track = [GaussianState(StateVector(np.asarray(scn.x0_estimate[run], dtype=float)), np.asarray(scn.p0, dtype=float),
                           timestamp=START)]
    index = {id(det): j for j, det in enumerate(arrived)}
    out = _empty(scn)
    # what it neither gave out during the run nor holds at its end it dropped as too old
    out.too_old = max(0, len(arrived) - buffer_size - sum(len(v) for v in released.values()))

    def take(det: Any) -> None:
        for given in released.get(index[id(det)], []):
            state = track[0]
            track[0] = updater.update(SingleHypothesis(predictor.predict(state, timestamp=given.timestamp), given))
            out.applied += 1

    return _run(scn, events, take, lambda: track[0], out)
