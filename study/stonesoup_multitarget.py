"""Stone Soup's multi-target tracker on the returns zentrack's centralized tracker gets: the peer in ``zentrack bench
multitarget``.

Stone Soup (``stonesoup``, the ``bench`` extra) is put together from its components with zentrack's models and
parameters (:class:`~zentrack.study.multitarget_runs.TrackerSettings`):

- motion: :class:`SampledLinearGaussian`, the scenario plant's own ``(A, Q)`` per scan period (zentrack's
  ``cv3d-cd`` is the Euler-Maruyama discretisation the truth moves by; Stone Soup's ``ConstantVelocity`` would be the
  exact one, a slightly different ``Q``), ``A^0 = I`` and no noise between the scans of one step;
- measurement: ``LinearGaussian`` on the position components with each sensor's noise covariance (bearing
  sensors: Stone Soup's ``CartesianToElevationBearing``, :mod:`.stonesoup_bearing`);
- :class:`~stonesoup.predictor.kalman.KalmanPredictor` and :class:`~stonesoup.updater.kalman.KalmanUpdater`
  (with bearing sensors :class:`~stonesoup.updater.kalman.ExtendedKalmanUpdater`, zentrack's EKF);
- association: ``GNNWith2DAssignment`` on ``PDAHypothesiser`` hypotheses with the same P_D, clutter density and gate
  probability (a mixed network: its sensor kind's, per scan), which maximises the same event likelihood as
  zentrack's GNN (:mod:`zentrack.fusion.multitarget.gnn`: ``P_D l / lambda`` per pair against ``1 - P_D P_G`` per
  miss);
- initiation: ``MultiMeasurementInitiator`` (a held track starts at one return with the position of the return, the
  new-track covariance for the velocity, mean 0, and is released after ``M + 1`` updates: zentrack's two-point
  initiation plus M-of-N confirmation need ``1 + M`` returns), its held tracks given up after ``N - M + 1`` steps
  without an update (when zentrack's M of N is out of reach). Bearing sensors: its held tracks start at points
  zentrack's triangulation makes of the leftover bearings (what exactly Stone Soup gets from zentrack there:
  :mod:`.stonesoup_bearing`);
- deletion: ``UpdateTimeStepsDeleter`` after K steps without an update;
- the tracker: ``MultiTargetTracker`` with the GNN above (``association="gnn"``), or Stone Soup's JPDA
  (``association="jpda"``: ``JPDAwithEHM2``, the efficient hypothesis management of Horridge & Maskell 2006 over
  the same ``PDAHypothesiser``, in a ``MultiTargetMixtureTracker``, which updates each track with the Gaussian
  mixture of its association events reduced to one Gaussian, and takes a return whose event weight beats the
  track's missed detection as used). Its initiator is the GNN one's (the held tracks are associated by GNN).

Stone Soup's tracker adds one state to every track per detection set, so the scans of a step go in one after the
other (like zentrack's centralized tracker, one scan after another), all with the step's timestamp. Its
initiator's points count updates, i.e. scans; its deleters count distinct **timestamps**, i.e. steps. (Until
2026-12 the comparator gave them ``K x M`` and ``(N - M + 1) x M``, taking them for scans: its tracks lived 40
steps without a return, its held tracks 16, where zentrack's live 5 and 2.)
"""
from __future__ import annotations

import datetime
import time
from collections.abc import Sequence

import numpy as np

from zentrack.truth.simulation.multitarget import MultiTargetData

from .multitarget_runs import MethodRun, TrackerSettings
from .stonesoup_bearing import detections_of, kind_hypothesiser, measurement_model, triangulating_initiator

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


#: Stone Soup's trackers beside zentrack's: the method's name in ``zentrack bench multitarget`` -> its association
ASSOCIATIONS = {"stonesoup": "gnn", "stonesoup-jpda": "jpda"}


def run_stonesoup(data: MultiTargetData, s: TrackerSettings | Sequence[TrackerSettings],
                  association: str = "gnn") -> MethodRun:
    """Stone Soup's tracker (module docstring; ``association``: ``gnn`` or ``jpda``) on every sensor's scan of each
    step, in sensor order (``s``: every node's settings, or one for all; bearing and mixed networks:
    :mod:`.stonesoup_bearing`). The returns are turned into Stone Soup detections before the clock starts."""
    if association not in ASSOCIATIONS.values():
        raise ValueError(f"association {association!r}: one of {', '.join(ASSOCIATIONS.values())}")
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDAwithEHM2
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetMixtureTracker, MultiTargetTracker
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater, KalmanUpdater

    nodes = data.sensors.shape[0]
    settings = [s] * nodes if isinstance(s, TrackerSettings) else list(s)
    first, kinds = settings[0], {x.measurement: x for x in settings}
    models = [measurement_model(data, i) for i in range(nodes)]
    predictor = KalmanPredictor(_transition_model_class()(
        transition_matrix=np.asarray(first.motion.A), covariance_matrix=np.asarray(first.motion.Q), period=first.ts))
    point = set(kinds) == {"point"}
    updater = KalmanUpdater(models[0]) if point else ExtendedKalmanUpdater(models[0])
    by_kind = {kind: PDAHypothesiser(predictor, updater, clutter_spatial_density=x.clutter_density,
                                     prob_detect=x.detection_prob, prob_gate=x.gate_prob) for kind, x in kinds.items()}

    def hypothesiser():
        return by_kind["point"] if point else kind_hypothesiser(by_kind)

    def associator() -> GNNWith2DAssignment:
        return GNNWith2DAssignment(hypothesiser())

    start = datetime.datetime(2000, 1, 1)
    detections = []
    for k in range(data.steps):
        when = start + datetime.timedelta(seconds=k * first.ts)
        for i in range(nodes):
            detections.append((when, detections_of(data, k, i, models[i], when)))
    prior = GaussianState(np.zeros((6, 1)), first.p0)
    # UpdateTimeStepsDeleter counts distinct timestamps, i.e. steps (a step's scans share theirs)
    initiator = MultiMeasurementInitiator(
        prior, UpdateTimeStepsDeleter(first.confirm_n - first.confirm_m + 1), associator(), updater, models[0],
        min_points=first.confirm_m + 1,
        initiator=None if point else triangulating_initiator(data, settings, prior, start))
    tracker_class, data_associator = ((MultiTargetTracker, associator()) if association == "gnn"
                                      else (MultiTargetMixtureTracker, JPDAwithEHM2(hypothesiser())))
    tracker = tracker_class(initiator=initiator, deleter=UpdateTimeStepsDeleter(first.max_misses),
                            detector=detections, data_associator=data_associator, updater=updater)
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
    return MethodRun(next(m for m, a in ASSOCIATIONS.items() if a == association), [out], seconds, data.steps * nodes)
