"""One node of a multi-target network: its local tracker, the network ids of its tracks, and the fusion of its
neighbours' track lists into them (one exchange per step).

:class:`TrackerSettings` are the models and parameters of a node's :class:`~.tracker.MultiTargetTracker`
(:func:`make_tracker`): the plant as the motion model, the measurement model (point or bearing), the new-track
covariance, P_D and the clutter density ``lambda`` for a GNN associator, the initiation (two-point differencing of
positions; for bearing sensors, triangulation of the own leftover returns with the neighbours' scans of the step,
:class:`~.triangulation.TriangulationInitiator`), M-of-N confirmation and deletion after K misses. Every user builds its tracker here: the tracker process
(``node/track_lists/payload.py``), the bench's in-process network and lone trackers, and the centralized tracker
(:mod:`.central`, from the same parts: :func:`filter_context`, :func:`make_gnn`, :func:`make_initiator`).

:class:`NetworkTracker` is the node. Per step k::

    local_step(k, scans)       the local tracker's step on its own scan (none: every track coasts), or, for
                               bearing sensors, on its neighbours' scans of step k then its own (what a
                               bearing-only track needs to be observable); new tracks get network ids (a
                               takeover keeps the id it came with)
    local_step_over(k, ...)    sensors of their own: the same over the window's scans, each at its own time
                               (a node built with ``over``, the plant over any interval)
    estimates()                its tracks at k as track-list entries under their network ids (published)
    fuse(lists)                its tracks fused with the neighbours' lists of step k
                               (:func:`~zentrack.fusion.track_to_track.fuse_track_lists`): the fused estimates
                               replace its tracks' (a diffusion step, as the single-target trackers do with
                               their priors), renamed tracks take the network id, and every neighbour's target
                               it does not hold is queued as a confirmed track from its prior for step k + 1

A track's miss count (what deletes it after K misses) is the steps since the target was last measured by this
node *or any holder it heard from*: after the fusion it is the least count of the associated tracks (each list
carries its tracks' counts), and a takeover starts from its neighbours' count plus the step it takes. So a
target outside this node's view, or missed by its sensor, stays held while a node within a few hops sees it,
and a track that no node measures any more (a target gone, a track gone astray) dies after K steps everywhere
instead of being passed around the network for ever (each node taking it back, fresh, from the others).

A restarted node holds no track: its first fusion takes over every target its neighbours hold, ids included
(its warm start); a tentative track of its own that a neighbour's confirmed track joins is confirmed at once
(the target is the network's already) and takes the network's id.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..defaults import MULTITARGET_TRACKERS
from ..filters import FILTER_REGISTRY, FilterContext, LocalFilter
from ..filters.interval import IntervalPredictor
from ..linalg import GaussianState, is_spd
from ..models import make_measurement
from ..motion import MotionModel
from ..scan import Scan
from ..track_to_track import DEFAULT_TRACK_RULE, TrackEstimate, TrackId, TrackIdIssuer, fuse_track_lists
from . import Associator, TrackStatus, make_associator
from .initiator import TwoPointInitiator
from .lifecycle import MissesCovarianceDeleter, MOfNConfirmer
from .pmbm import Pmbm, PmbmSettings, Ppp
from .pmbm_tracker import PmbmTracker, undetected
from .tracker import MultiTargetTracker
from .triangulation import TriangulationInitiator

Array = np.ndarray
#: the trackers a node may run (:attr:`TrackerSettings.tracker`)
TRACKERS = MULTITARGET_TRACKERS


@dataclass(frozen=True)
class TrackerSettings:
    """The models and parameters of a node's multi-target tracker (module docstring)."""

    filter_kind: str  #: the per-track filter (a registered batched local filter)
    motion: MotionModel
    measurement: str  #: "point" (Cartesian position) or "bearing" (azimuth, elevation)
    p0: Array  #: (6, 6) covariance of a new track
    ts: float
    detection_prob: float
    clutter_density: float  #: lambda, clutter returns per scan and m^3 (point) or rad^2 (bearing)
    gate_prob: float = 0.999
    max_speed: float = 30.0  #: m/s, two-point initiation's velocity gate
    confirm_m: int = 3  #: M of N: a track is confirmed at M hits in its first N steps
    confirm_n: int = 4
    max_misses: int = 5  #: K: deleted after K consecutive steps without a return
    track_rule: str = DEFAULT_TRACK_RULE  #: the fusion rule of associated tracks
    max_tracks: int = 256  #: no takeover beyond this many tracks held (a track list carries at most 256)
    max_range: float = math.inf  #: m, the sensing range (bearing: where triangulated rays may meet; PMBM: P_D 0 beyond)
    tracker: str = "gnn"  #: the node's tracker: "gnn" (M of N, K misses) or "pmbm" (:mod:`.pmbm_tracker`)
    #: point sensors: a node also steps on its neighbours' scans of the step, before its own (bearing sensors always do)
    share_scans: bool = False

    @property
    def exchanges_scans(self) -> bool:
        """Whether a node steps on its neighbours' scans too: bearing sensors (one sensor sees no range), and point
        sensors that share them (:attr:`share_scans`)."""
        return self.measurement == "bearing" or self.share_scans


def filter_context(s: TrackerSettings) -> FilterContext:
    """The motion and measurement models and new-track covariance of the settings ``s``."""
    return FilterContext(s.motion, make_measurement(s.measurement), s.p0)


def make_gnn(s: TrackerSettings) -> Associator:
    """The GNN associator of the settings ``s`` (P_D, clutter density, gate)."""
    return make_associator("gnn", {"detection_prob": s.detection_prob, "clutter_density": s.clutter_density,
                                   "gate_prob": s.gate_prob})


def make_initiator(s: TrackerSettings, sensor: int | None = 0) -> TwoPointInitiator | TriangulationInitiator:
    """The initiator of the settings ``s``: two-point differencing for point sensors (its candidates per sensor),
    triangulation for bearing sensors (``sensor``: the own sensor, None for a tracker of every sensor's scans)."""
    if s.measurement == "bearing":  # only points a third ray confirms start tracks (ghosts of two rays are many)
        return TriangulationInitiator(sensor, s.p0, s.max_range, s.gate_prob, require_confirmation=True)
    return TwoPointInitiator(s.ts, s.max_speed, s.p0, gate_prob=s.gate_prob)


def make_tracker(s: TrackerSettings, sensor: int = 0) -> MultiTargetTracker | PmbmTracker:
    """A multi-target tracker with the settings ``s`` (``sensor``: the own sensor's index, whose leftover
    bearings a bearing tracker triangulates with the other scans of the step): ``s.tracker``'s."""
    if s.tracker not in TRACKERS:
        raise ValueError(f"tracker {s.tracker!r}: not one of {', '.join(TRACKERS)}")
    return make_gnn_tracker(s, sensor) if s.tracker == "gnn" else make_pmbm_tracker(s)


def make_gnn_tracker(s: TrackerSettings, sensor: int = 0) -> MultiTargetTracker:
    """The GNN tracker (two-point or triangulated births, M of N, K misses) of the settings ``s``, whatever
    ``s.tracker`` names (a centralized tracker's base; the filter a PMBM tracker runs on). A camera's (bearing
    sensors) counts a step a hit only where two cameras' returns took the track (``min_hit_sensors``): one ray
    has no range, and a track that lone rays of other targets kept "hit" lived on as a ghost."""
    tracker = MultiTargetTracker.from_registry(s.filter_kind, filter_context(s), make_gnn(s), make_initiator(s, sensor),
                                               MissesCovarianceDeleter(s.max_misses),
                                               MOfNConfirmer(s.confirm_m, s.confirm_n))
    tracker.min_hit_sensors = 2 if s.measurement == "bearing" else 1
    return tracker


def make_pmbm_tracker(s: TrackerSettings) -> PmbmTracker:
    """The PMBM tracker of the settings ``s``, whatever ``s.tracker`` names, on the filter and measurement model a
    GNN tracker of them has: point sensors only (ValueError otherwise), its undetected targets spread evenly over
    what the sensors see (:func:`.pmbm_tracker.undetected`), nothing beyond ``s.max_range``."""
    if s.measurement != "point":
        raise ValueError(f"tracker 'pmbm' takes point sensors, not {s.measurement} (bearing-only births are not built)")
    base = make_gnn_tracker(s)
    local_filter, measurement = base.local_filter, base.measurement
    n = local_filter.state_dim
    nothing = Ppp(np.zeros(0), GaussianState(np.zeros((0, n)), np.zeros((0, n, n))))
    pmbm = Pmbm(local_filter, measurement, PmbmSettings(s.detection_prob, s.clutter_density, gate_prob=s.gate_prob,
                                                        max_range=s.max_range),
                nothing, nothing, undetected(s.max_speed))
    return PmbmTracker(pmbm, measurement, base.lumped_var, s.max_misses)


def interval_filters(s: TrackerSettings, base: LocalFilter, over: Callable[[float], MotionModel]) -> IntervalPredictor:
    """The per-track filter over any interval (sensors of their own): ``base``, built for the sample period
    ``s.ts``, and for another interval dt the same filter on the plant over dt (``over(dt)``, e.g.
    :func:`~zentrack.fusion.models.plant_over`)."""
    def build(dt: float) -> LocalFilter:
        built = FILTER_REGISTRY.create(s.filter_kind, None, filter_context(replace(s, motion=over(dt))))
        assert isinstance(built, LocalFilter)  # (the same filter as ``base``, which is one)
        return built

    return IntervalPredictor(base, s.ts, build)


class NetworkTracker:
    """Node ``node``'s tracks under network ids (module docstring). ``first_serial``: where its id counter
    starts (a restart within the step of an earlier run's last id passes one past that run's)."""

    def __init__(self, node: int, s: TrackerSettings, first_serial: int = 0,
                 over: Callable[[float], MotionModel] | None = None) -> None:
        self.node, self.settings = node, s
        self.tracker = make_tracker(s, node)
        #: sensors of their own: the per-track filter over any interval (``over(dt)``: the plant over dt); None: a
        #: node on the run's grid, whose takeovers are predicted one step (its scans are of the next step)
        self.interval = None if over is None else interval_filters(s, self.tracker.local_filter, over)
        self.issuer = TrackIdIssuer(node, first_serial)
        self.ids: dict[int, TrackId] = {}  # local track id -> network id
        #: the takeovers queued for the next step, in order: their ids and their misses at the neighbours
        self._pending: list[tuple[TrackId, int]] = []
        self.takeovers = 0  # tracks started from neighbours' priors, over the run

    @property
    def step(self) -> int | None:
        """The last step the local tracker took (None before the first)."""
        return self.tracker.last_step

    def local_step(self, k: int, scans: Scan | Sequence[Scan] | None) -> None:
        """The local tracker's step on the step's scans (the own one last); new tracks get their network ids
        (takeovers first: they are born first)."""
        self.tracker.step(k, scans)
        self._name_new_tracks()

    def local_step_over(self, k: int, t_from: float, t_to: float, timed: Sequence[tuple[float, Scan]]) -> None:
        """Sensors of their own: the local tracker's step k from its tracks valid at ``t_from`` over the scans
        ``timed`` ((time, scan) in time order), each at its own time, to estimates valid at ``t_to``
        (:meth:`~.tracker.MultiTargetTracker.step_over`); new tracks get their network ids as in
        :meth:`local_step`. Only for a node built with ``over`` (ValueError otherwise)."""
        if self.interval is None:
            raise ValueError(f"node {self.node}: built for the run's grid; steps over times need the plant over any "
                             "interval (over=)")
        self.tracker.step_over(k, t_from, t_to, timed, self.interval)
        self._name_new_tracks()

    def _name_new_tracks(self) -> None:
        """Network ids for the tracks the last step started (module docstring)."""
        self.drop_broken()
        pending, self._pending = self._pending, []
        for track in self.tracker.tracks:
            if track.id not in self.ids:
                if pending:  # a takeover: unless this node measured it now, one step more since the network did
                    self.ids[track.id], misses = pending.pop(0)
                    measured = track.misses == 0 and len(track.hits) > 1  # (a window no sensor looked in: not)
                    track.misses = 0 if measured else misses + 1
                else:
                    self.ids[track.id] = self.issuer.issue(track.birth_step)
        live = {t.id for t in self.tracker.tracks}
        self.ids = {i: net for i, net in self.ids.items() if i in live}

    def drop_broken(self) -> int:
        """Delete every track whose estimate is not finite or whose covariance is not symmetric positive definite
        (a filter's numerical failure, or a fusion gone wrong): its receivers would refuse the whole list for it.
        Checked for all tracks in one batch; returns how many were dropped."""
        tracks = self.tracker.tracks
        if not tracks:
            return 0
        k = self.tracker.local_filter.kinematic_dim
        covs = np.stack([t.cov[:k, :k] for t in tracks])
        good = is_spd(0.5 * (covs + np.swapaxes(covs, 1, 2))) & np.isfinite(np.stack([t.mean for t in tracks])).all(axis=1)
        if good.all():
            return 0
        self.tracker.tracks = [t for t, ok in zip(tracks, good) if ok]
        self.ids = {i: net for i, net in self.ids.items() if i in {t.id for t in self.tracker.tracks}}
        return int((~good).sum())

    def estimates(self, confirmed_only: bool = False, limit: int | None = None) -> list[TrackEstimate]:
        """Its tracks as track-list entries (kinematic part) under their network ids (call :meth:`drop_broken`
        first); at most ``limit``: confirmed tracks first, then the most recently measured."""
        k = self.tracker.local_filter.kinematic_dim
        tracks = [t for t in self.tracker.tracks if not confirmed_only or t.status is TrackStatus.CONFIRMED]
        if limit is not None and len(tracks) > limit:
            tracks = sorted(tracks, key=lambda t: (t.status is not TrackStatus.CONFIRMED, t.misses))[:limit]
        return [TrackEstimate.checked_before(self.ids[t.id], t.mean[:k], 0.5 * (t.cov[:k, :k] + t.cov[:k, :k].T),
                                             t.status.value, t.step, t.misses, t.existence) for t in tracks]

    def confirmed(self) -> tuple[list[TrackId], Array]:
        """Its confirmed tracks: their network ids and positions ``(n, 3)``."""
        tracks = self.tracker.confirmed()
        return [self.ids[t.id] for t in tracks], np.array([t.mean[:3] for t in tracks]).reshape(-1, 3)

    def _predicted_kinematics(self, estimates: Sequence[TrackEstimate],
                              predict: Callable[[GaussianState], GaussianState]) -> tuple[Array, Array]:
        """Track-list entries' kinematic estimates as one stack of the local filter's states, ``predict``-ed."""
        f, k = self.tracker.local_filter, self.tracker.local_filter.kinematic_dim
        state = predict(f.initial_state(np.stack([e.mean for e in estimates]), np.stack([e.cov for e in estimates]),
                                        self.tracker.lumped_var))
        return state.mean[:, :k], state.cov[:, :k, :k]

    def predicted(self, estimate: TrackEstimate) -> tuple[Array, Array]:
        """A track-list entry's kinematic estimate predicted one step by the local filter."""
        mean, cov = self._predicted_kinematics([estimate], self.tracker.local_filter.predict)
        return mean[0], cov[0]

    def predicted_over(self, estimates: Sequence[TrackEstimate], dt: float, step: int) -> list[TrackEstimate]:
        """A neighbour's track-list entries predicted ``dt`` seconds (back when negative) by the per-track filter
        over that interval, as entries of ``step``: a list valid at another time on this node's clock (its sender's
        clock is off this one's, ``node/track_lists/admission.py``). Only for a node built with ``over``."""
        interval = self.interval
        if interval is None:
            raise ValueError(f"node {self.node}: built for the run's grid; predicting over an interval needs over=")
        if not estimates:
            return []
        mean, cov = self._predicted_kinematics(estimates, lambda state: interval.predict(state, dt))
        return [TrackEstimate.checked_before(e.id, mean[n], 0.5 * (cov[n] + cov[n].T), e.status, step, e.misses,
                                             e.existence) for n, e in enumerate(estimates)]

    def fuse(self, lists: Mapping[int, Sequence[TrackEstimate]]) -> None:
        """Fuse its tracks with the neighbours' lists of its current step (sender -> tracks), feed the result back
        into its tracker and queue the takeovers. A list of another step is a caller's error (ValueError)."""
        self.drop_broken()
        own = self.estimates()  # one per track, in the tracker's order
        step = self.tracker.last_step
        for sender, tracks in lists.items():
            if any(t.step != step for t in tracks):
                raise ValueError(f"node {sender}'s list is not at step {step}")
        result = fuse_track_lists(own, lists, rule=self.settings.track_rule, issuer=self.issuer)
        assert len(result.tracks) == len(own), "every own track keeps a network id"
        k = self.tracker.local_filter.kinematic_dim
        usable = _finite_and_spd(result.tracks)  # (one batched check: a check per track was most of this call)
        for track, fused, support, ok in zip(self.tracker.tracks, result.tracks, result.support, usable):
            track.support = support
            track.existence = fused.existence  # (arithmetic average over the cluster: a PMBM tracker takes it)
            if support and track.status is TrackStatus.TENTATIVE:  # a neighbour's confirmed track: the network's
                track.move_to(TrackStatus.CONFIRMED)  # (a restarted node's new tracks of targets others hold)
            if not ok:
                continue  # a fusion that lost its digits: the track keeps its own estimate
            track.mean = track.mean.copy()
            track.mean[:k] = fused.mean
            cov = np.zeros_like(track.cov)  # cross terms with augmented blocks dropped: stays block SPD
            cov[:k, :k], cov[k:, k:] = fused.cov, track.cov[k:, k:]
            track.cov = cov
            self.ids[track.id] = fused.id
            track.misses = fused.misses  # the steps since any holder it heard from measured the target
        room = self.settings.max_tracks - len(self.tracker.tracks)
        takeovers = sorted(result.takeovers, key=lambda p: p.misses)  # the most recently measured first
        for prior, ok in zip(takeovers, _finite_and_spd(takeovers)):
            # at step k; from_prior takes the estimate at the next step. Not a track that would be deleted at once,
            # nor more than the tracker holds (a list of hundreds of forged targets takes what room is left)
            if prior.misses + 1 >= self.settings.max_misses or room <= 0:
                continue
            if not ok:
                continue
            room -= 1  # (a node of timed scans takes them at its next window's start: the fused lists' time)
            mean, cov = (prior.mean, prior.cov) if self.interval is not None else self.predicted(prior)
            self.tracker.initiator.from_prior(mean, cov, TrackStatus.CONFIRMED, prior.existence)
            self._pending.append((prior.id, prior.misses))
            self.takeovers += 1


def _finite_and_spd(estimates: Sequence[TrackEstimate]) -> Array:
    """Per estimate: its mean finite and its covariance symmetric positive definite (one batched check)."""
    if not estimates:
        return np.zeros(0, dtype=bool)
    means = np.stack([e.mean for e in estimates])
    return np.isfinite(means).all(axis=1) & is_spd(np.stack([e.cov for e in estimates]))
