"""The multi-target tracker of one node: predict, associate, update, life cycle, initiate, one scan at a time.

One :meth:`MultiTargetTracker.step` at step ``k`` with that step's scans (none: every track coasts)::

    predict every track to k                       (one batched call of the local filter)
    add the tracks of the priors queued by Initiator.from_prior (estimates at k: they are associated too)
    for each scan (with its sensor's measurement model, filter and associator):
        gate and weigh tracks x returns            (gating.scan_likelihood)
        associate                                  (GNN: an assignment; JPDA: the marginals beta)
        update                                     (combine.associated_update: assigned return / PDA mixture)
    record hit or miss (a camera node: two sensors' returns); confirm (M of N); delete (K misses, ...)
    start tracks from returns in no track's gate

Any registered batched local filter (:data:`~zentrack.fusion.filters.FILTER_REGISTRY`: EKF, UKF, CKF, the
extended-state filters, ...) is the per-track filter: every track is one member of a stack, so a scan of
a hundred tracks is a handful of numpy calls (:meth:`MultiTargetTracker.from_registry` builds one by name
like :class:`~zentrack.node.diffusion.tracker.Tracker` does). A filter whose state carries more than a Gaussian (a
particle cloud) runs on its Gaussian summary.

A tracker given scans of sensors of different kinds (a centralized tracker of cameras and radars,
:func:`~zentrack.fusion.multitarget.central.make_central_tracker`) takes a :class:`SensorModel` per sensor in
``sensor_models``: each scan is gated, associated and updated with its own sensor's measurement model (its local
filter's update) and associator (its clutter density and P_D); the prediction is the tracker's ``local_filter``'s,
whose motion every sensor's filter shares. A sensor without an entry uses the tracker's own.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..filters.base import FILTER_REGISTRY, FilterContext, LocalFilter
from ..filters.interval import IntervalPredictor, update_at_times
from ..linalg import GaussianState
from ..measurement import MeasurementModel
from ..scan import Scan
from .base import Associator, Birth, Confirmer, Deleter, Initiator, Track, TrackStatus
from .combine import associated_update
from .gating import gate_gamma, scan_likelihood
from .lifecycle import MOfNConfirmer

Array = np.ndarray


@dataclass(frozen=True)
class SensorModel:
    """How a tracker takes one sensor's scans: the local filter that updates with them (its measurement model),
    that model for the gating, and the associator (P_D, clutter density, gate)."""

    local_filter: LocalFilter
    measurement: MeasurementModel
    associator: Associator


class MultiTargetTracker:
    """Tracks of one node (module docstring); ``tracks`` holds the live ones after each step."""

    def __init__(self, local_filter: LocalFilter, measurement: MeasurementModel, associator: Associator,
                 initiator: Initiator, deleter: Deleter, confirmer: Confirmer | None = None,
                 lumped_var: float = 1.0, sensor_models: Mapping[int, SensorModel] | None = None) -> None:
        if not isinstance(local_filter, LocalFilter):
            raise TypeError(f"the per-track filter must be a batched LocalFilter, got {type(local_filter).__name__}")
        self.local_filter = local_filter
        self.measurement = measurement
        self.associator = associator
        self.initiator = initiator
        self.deleter = deleter
        self.confirmer = confirmer if confirmer is not None else MOfNConfirmer()
        self.lumped_var = float(lumped_var)
        #: a step's hit (what M of N and K misses count) needs returns of this many sensors: 1, or 2 for a camera
        #: node (:func:`~.network.make_gnn_tracker`: two rays cross where one has no range)
        self.min_hit_sensors = 1
        #: per sensor index, how its scans are taken (module docstring); others: the tracker's own models
        self.sensor_models: dict[int, SensorModel] = dict(sensor_models or {})
        self.tracks: list[Track] = []
        #: tracks deleted at the last step
        self.deleted: list[Track] = []
        self.last_step: int | None = None
        self._next_id = 0

    @classmethod
    def from_registry(cls, filter_name: str, context: FilterContext, associator: Associator, initiator: Initiator,
                      deleter: Deleter, confirmer: Confirmer | None = None,
                      filter_params: Mapping[str, Any] | None = None) -> MultiTargetTracker:
        """The registered local filter ``filter_name`` built on ``context`` (its models, P0, lumped variance)."""
        if context.measurement is None:
            raise ValueError("a multi-target tracker needs a measurement model in its FilterContext")
        built = FILTER_REGISTRY.create(filter_name, filter_params, context)
        if not isinstance(built, LocalFilter):
            raise TypeError(f"local filter {filter_name!r} is not a batched LocalFilter; it cannot run per track")
        return cls(built, context.measurement, associator, initiator, deleter, confirmer, context.lumped_var)

    def model_of(self, scan: Scan) -> SensorModel:
        """The filter, measurement model and associator that take ``scan``."""
        own = self.sensor_models.get(scan.sensor)
        return own if own is not None else SensorModel(self.local_filter, self.measurement, self.associator)

    def confirmed(self) -> list[Track]:
        """The confirmed tracks."""
        return [t for t in self.tracks if t.status is TrackStatus.CONFIRMED]

    def kinematic(self, track: Track) -> tuple[Array, Array]:
        """A track's kinematic mean and covariance (what is compared with the truth)."""
        k = self.local_filter.kinematic_dim
        return track.mean[:k], track.cov[:k, :k]

    def add_track(self, birth: Birth, step: int) -> Track:
        """Start a track from ``birth`` as the estimate at ``step`` (the filter adds its augmented blocks)."""
        k = self.local_filter.kinematic_dim
        if birth.mean.shape != (k,):
            raise ValueError(f"birth: expected a kinematic mean of shape ({k},), got {birth.mean.shape}")
        state = self.local_filter.initial_state(birth.mean[None], birth.cov, self.lumped_var)
        track = Track(self._next_id, state.mean[0].copy(), state.cov[0].copy(), step, step, birth.status)
        self._next_id += 1
        self.tracks.append(track)
        return track

    def _stacked(self) -> GaussianState:
        """Every track's estimate as it is, stacked ``(T, n)``."""
        n = self.local_filter.state_dim
        if not self.tracks:
            return GaussianState(np.zeros((0, n)), np.zeros((0, n, n)))
        return GaussianState(np.stack([t.mean for t in self.tracks]), np.stack([t.cov for t in self.tracks]))

    def _predict(self, step: int) -> GaussianState:
        """Every track's estimate predicted to ``step``, stacked ``(T, n)``."""
        state = self._stacked()
        for _ in range(step - self.tracks[0].step if self.tracks else 0):
            state = self.local_filter.predict(state)
        return state

    def _born(self, state: GaussianState, births: Sequence[Birth], step: int) -> GaussianState:
        """``state`` with the tracks started from ``births`` at ``step`` appended (they are estimates of its time:
        they take part in the association of the scans that follow)."""
        born = [self.add_track(b, step) for b in births]
        if not born:
            return state
        return GaussianState(np.concatenate([state.mean, np.stack([t.mean for t in born])]),
                             np.concatenate([state.cov, np.stack([t.cov for t in born])]))

    def _take_scan(self, state: GaussianState, scan: Scan, step: int) -> tuple[GaussianState, Array]:
        """One scan's gating, association and update of every track at ``step`` (the tracks it detected note its
        sensor in their ``detected_by``, and ``detected_alone_by``): the updated stack and the returns inside no
        track's gate (what the initiator may start tracks from)."""
        model = self.model_of(scan)
        lik = scan_likelihood(model.measurement, state, scan, gate_gamma(scan.dim, model.associator.gate_prob))
        assoc = model.associator.associate(lik)
        for i in np.flatnonzero(assoc.detected()):
            self.tracks[i].detected_by[scan.sensor] = step
        for i in np.flatnonzero(assoc.detected_alone()):
            self.tracks[i].detected_alone_by[scan.sensor] = step
        return associated_update(model.local_filter, state, scan, assoc), scan.returns[assoc.unassociated()]

    def _close(self, state: GaussianState, step: int, recorded: Array) -> None:
        """The stack as every track's estimate at ``step``; each ``recorded`` track's hit or miss goes into its
        history (a hit: returns of at least :attr:`min_hit_sensors` sensors at ``step``), and the life cycle decides
        (confirmed, deleted)."""
        self.deleted = []
        for i, track in enumerate(self.tracks):
            track.mean, track.cov, track.step = state.mean[i], state.cov[i], step
            if recorded[i]:
                seen = sum(1 for k in track.detected_by.values() if k == step)
                track.record(seen >= self.min_hit_sensors)
            track.move_to(self.confirmer.decide(track))
            if track.alive and self.deleter.should_delete(track):
                track.move_to(TrackStatus.DELETED)
            if not track.alive:
                self.deleted.append(track)
        self.tracks = [t for t in self.tracks if t.alive]

    def _check_next(self, step: int) -> None:
        if self.last_step is not None and step <= self.last_step:
            raise ValueError(f"step {step} does not follow the last step {self.last_step}")

    def step(self, step: int, scans: Sequence[Scan] | Scan | None = None) -> list[Track]:
        """Advance to ``step`` (an integer after the last one) with its scans; returns the live tracks."""
        self._check_next(step)
        scan_list = [] if scans is None else [scans] if isinstance(scans, Scan) else list(scans)
        for scan in scan_list:
            scan.validate()
        # tracks from priors (a neighbour's) are estimates at this step: they take part in its association
        state = self._born(self._predict(step), self.initiator.take_priors(), step)
        leftovers = []
        for scan in scan_list:
            state, left = self._take_scan(state, scan, step)
            leftovers.append((scan, left))
        self._close(state, step, np.ones(len(self.tracks), dtype=bool))
        births = []
        for scan, returns in leftovers:
            births += self.initiator.births(returns, scan, step)
        for birth in births:
            self.add_track(birth, step)
        self.last_step = step
        return self.tracks

    def step_over(self, step: int, t_from: float, t_to: float, timed: Sequence[tuple[float, Scan]],
                  predictor: IntervalPredictor) -> list[Track]:
        """Sensors of their own (issue 52): advance to ``step``, whose estimates are valid at time ``t_to``, from the
        tracks valid at ``t_from`` (and the queued priors, taken as estimates at ``t_from``) with each scan at its
        own time (``timed``: (time, scan) in time order, ``t_from <= time <= t_to``): every track predicted to each
        scan's time over that interval (``predictor``: the per-track filter over any interval,
        :class:`~zentrack.fusion.filters.interval.IntervalPredictor`), gated, associated and updated with it, the
        returns in no track's gate started as tracks there (:meth:`~.base.Initiator.births_at`, in the stack for
        the scans that follow), then every track predicted to ``t_to``
        (:func:`~zentrack.fusion.filters.interval.update_at_times`). The life cycle counts the window as one step:
        a track that scans of :attr:`min_hit_sensors` sensors detected has a hit, any other a miss, and a window
        without a scan records nothing (no sensor looked); tracks born in it start their history at the next."""
        self._check_next(step)
        for _, scan in timed:
            scan.validate()
        state = self._born(self._stacked(), self.initiator.take_priors(), step)
        before = len(self.tracks)

        def correct(st: GaussianState, scans: list[Scan], t: float) -> GaussianState:
            st, left = self._take_scan(st, scans[0], step)
            return self._born(st, self.initiator.births_at(left, scans[0], step, t), step)

        state = update_at_times(state, t_from, t_to, timed, predictor, correct)
        self._close(state, step, np.arange(len(self.tracks)) < (before if timed else 0))
        self.last_step = step
        return self.tracks
