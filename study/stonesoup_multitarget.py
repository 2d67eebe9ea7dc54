"""Stone Soup's multi-target tracker on the returns zentrack's centralized tracker gets: the peer in ``zentrack bench
multitarget``.

Stone Soup (``stonesoup``, the ``bench`` extra) is put together from its components with zentrack's models and
parameters (:class:`~zentrack.study.multitarget_runs.TrackerSettings`):

- motion: :class:`SampledLinearGaussian`, the scenario plant's own ``(A, Q)`` per scan period (zentrack's
  ``cv3d-cd`` is the Euler-Maruyama discretisation the truth moves by; Stone Soup's ``ConstantVelocity`` would be the
  exact one, a slightly different ``Q``), ``A^0 = I`` and no noise between the scans of one step;
- measurement: ``LinearGaussian`` on the position components with each sensor's noise covariance;
- :class:`~stonesoup.predictor.kalman.KalmanPredictor` and :class:`~stonesoup.updater.kalman.KalmanUpdater`;
- association: ``GNNWith2DAssignment`` on ``PDAHypothesiser`` hypotheses with the same P_D, clutter density and gate
  probability, which maximises the same event likelihood as zentrack's GNN
  (:mod:`zentrack.fusion.multitarget.gnn`: ``P_D l / lambda`` per pair against ``1 - P_D P_G`` per miss);
- initiation: ``MultiMeasurementInitiator`` (a held track starts at one return with the position of the return, the
  new-track covariance for the velocity, mean 0, and is released after ``M + 1`` updates: zentrack's two-point
  initiation plus M-of-N confirmation need ``1 + M`` returns), its held tracks given up after ``N - M + 1`` steps
  without an update (when zentrack's M of N is out of reach);
- deletion: ``UpdateTimeStepsDeleter`` after K steps without an update.

Stone Soup's tracker adds one state to every track per detection set, so the scans of a step go in one after the
other (like zentrack's centralized tracker, one scan after another) and its step counts are scans: K steps are
``K x M`` scans for M sensors.
"""
from __future__ import annotations

import datetime
import time

import numpy as np

from zentrack.truth.simulation.multitarget import MultiTargetData

from .multitarget_runs import MethodRun, TrackerSettings

Array = np.ndarray


def stonesoup_version() -> str | None:
    """Stone Soup's version, or None if it is not installed (``pip install 'zentrack[bench]'``)."""
    try:
        import stonesoup
    except ImportError:
        return None
    return str(stonesoup.__version__)


def _transition_model_class() -> type:
    """:class:`SampledLinearGaussian`, defined once Stone Soup is imported (it is optional)."""
    from stonesoup.base import Property
    from stonesoup.models.base import TimeVariantModel
    from stonesoup.models.transition.linear import LinearGaussianTransitionModel
    from stonesoup.types.array import CovarianceMatrix

    class SampledLinearGaussian(LinearGaussianTransitionModel, TimeVariantModel):
        """``x+ = A^n x + w``, ``w ~ N(0, sum_{j<n} A^j Q A^jT)`` over ``n`` periods (``n = 0``: identity)."""

        transition_matrix: np.ndarray = Property(doc="A over one period")
        covariance_matrix: np.ndarray = Property(doc="Q over one period")
        period: float = Property(doc="the period, seconds")

        @property
        def ndim_state(self) -> int:
            return int(self.transition_matrix.shape[0])

        def periods(self, time_interval: datetime.timedelta) -> int:
            n = time_interval.total_seconds() / self.period
            if n < -1e-9 or abs(n - round(n)) > 1e-6:
                raise ValueError(f"time interval {time_interval} is not a whole number of {self.period} s periods")
            return int(round(n))

        def matrix(self, time_interval: datetime.timedelta, **kwargs) -> np.ndarray:
            return np.linalg.matrix_power(self.transition_matrix, self.periods(time_interval))

        def covar(self, time_interval: datetime.timedelta, **kwargs) -> CovarianceMatrix:
            a, q = self.transition_matrix, self.covariance_matrix
            total = np.zeros_like(q)
            for _ in range(self.periods(time_interval)):
                total = a @ total @ a.T + q
            return CovarianceMatrix(total)

    return SampledLinearGaussian


def run_stonesoup(data: MultiTargetData, s: TrackerSettings) -> MethodRun:
    """Stone Soup's ``MultiTargetTracker`` (module docstring) on every sensor's scan of each step, in sensor order.
    The returns are turned into Stone Soup detections before the clock starts."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetTracker
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState

    nodes = data.sensors.shape[0]
    models = [LinearGaussian(ndim_state=6, mapping=(0, 1, 2), noise_covar=data.noise_cov[i]) for i in range(nodes)]
    from stonesoup.updater.kalman import KalmanUpdater

    predictor = KalmanPredictor(_transition_model_class()(
        transition_matrix=np.asarray(s.motion.A), covariance_matrix=np.asarray(s.motion.Q), period=s.ts))
    updater = KalmanUpdater(models[0])

    def associator() -> GNNWith2DAssignment:
        return GNNWith2DAssignment(PDAHypothesiser(predictor, updater, clutter_spatial_density=s.clutter_density,
                                                   prob_detect=s.detection_prob, prob_gate=s.gate_prob))

    start = datetime.datetime(2000, 1, 1)
    detections = []
    for k in range(data.steps):
        when = start + datetime.timedelta(seconds=k * s.ts)
        for i in range(nodes):
            returns = data.scan(k, i).returns
            detections.append((when, {Detection(z[:, None], timestamp=when, measurement_model=models[i])
                                       for z in returns}))
    initiator = MultiMeasurementInitiator(
        GaussianState(np.zeros((6, 1)), s.p0), UpdateTimeStepsDeleter((s.confirm_n - s.confirm_m + 1) * nodes),
        associator(), updater, models[0], min_points=s.confirm_m + 1)
    tracker = MultiTargetTracker(initiator=initiator, deleter=UpdateTimeStepsDeleter(s.max_misses * nodes),
                                 detector=detections, data_associator=associator(), updater=updater)
    out, seconds = [], 0.0
    scans = iter(tracker)
    for _ in range(data.steps):
        t0 = time.perf_counter()
        for _ in range(nodes):
            _, tracks = next(scans)
        seconds += time.perf_counter() - t0
        ordered = sorted(tracks, key=lambda t: t.id)
        out.append(([t.id for t in ordered], np.array([np.ravel(t.state_vector)[:3] for t in ordered],
                                                       dtype=float).reshape(-1, 3)))
    return MethodRun("stonesoup", [out], seconds, data.steps * nodes)
