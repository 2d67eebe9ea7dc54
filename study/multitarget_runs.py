"""zentrack's multi-target trackers run over one simulated many-target run: each node alone, the distributed network
(local trackers and one track-list exchange per step), and a centralized tracker on every scan.

Every method gets the same :class:`TrackerSettings` (:func:`settings_for`): the scenario's plant as the motion model,
its point measurement model and noise, its new-track covariance ``[initial] p0_diag``, its P_D and clutter density
``lambda = clutter_rate / V`` (V the volume of a sensor's field of view), a GNN associator
(:class:`~zentrack.fusion.multitarget.gnn.GlobalNearestNeighbour`), two-point initiation, M-of-N confirmation and
deletion after K misses (no covariance bound: Stone Soup's comparator has none). What differs is which scans a
tracker sees and what it exchanges:

- **alone**: node i's tracker on node i's scans only;
- **distributed** (:func:`run_distributed`): node i's tracker on its own scans; then every node publishes its
  confirmed tracks under network ids (:class:`~zentrack.fusion.track_to_track.TrackId`), and each node fuses its own
  tracks with its graph neighbours' lists (:func:`~zentrack.fusion.track_to_track.fuse_track_lists`, CI with the
  fast weights): the fused estimates replace its tracks' estimates (a diffusion step, as the single-target
  trackers do with their priors), renamed tracks take the network id, and every neighbour's target it does not
  hold starts a confirmed track from its prior (``Initiator.from_prior``) at the next step;
- **centralized**: one tracker on every sensor's scan of each step, in sensor order.

Each run gives, per view (a node, or the one centralized tracker), the confirmed tracks' positions under their
ids at every step, and the seconds spent in the trackers (and, distributed, in the fusion).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from zentrack.config.scenario_config import RunConfig
from zentrack.fusion.filters import FilterContext
from zentrack.fusion.models import make_measurement, make_plant
from zentrack.fusion.motion import MotionModel
from zentrack.fusion.multitarget import TrackStatus, make_associator
from zentrack.fusion.multitarget.initiator import TwoPointInitiator
from zentrack.fusion.multitarget.lifecycle import MissesCovarianceDeleter, MOfNConfirmer
from zentrack.fusion.multitarget.tracker import MultiTargetTracker
from zentrack.fusion.track_to_track import TrackEstimate, TrackId, TrackIdIssuer, fuse_track_lists
from zentrack.truth.simulation.multitarget import MultiTargetData, SensingSpec
from zentrack.truth.simulation.scenario import graph_weights

Array = np.ndarray
#: one step's confirmed tracks: (ids, positions (n, 3))
TrackSet = tuple[list, Array]


@dataclass(frozen=True)
class TrackerSettings:
    """The models and parameters every method's tracker gets (module docstring)."""

    filter_kind: str  #: the per-track filter (zentrack's registry name; Stone Soup uses its Kalman filter)
    motion: MotionModel
    measurement: str  #: "point" (Cartesian position)
    p0: Array  #: (6, 6) covariance of a new track
    ts: float
    detection_prob: float
    clutter_density: float  #: lambda, clutter returns per m^3 and scan
    gate_prob: float = 0.999
    max_speed: float = 30.0  #: m/s, two-point initiation's velocity gate
    confirm_m: int = 3  #: M of N: a track is confirmed at M hits in its first N steps
    confirm_n: int = 4
    max_misses: int = 5  #: K: deleted after K consecutive steps without a return


def view_volume(sensing: SensingSpec) -> float:
    """The volume (m^3) of a point sensor's field of view: range ``R``, azimuth width ``W``, elevations
    ``[lo, hi]``: ``V = W (sin hi - sin lo) R^3 / 3`` (the integral of ``r^2 cos(el)`` over the view)."""
    lo, hi = sensing.fov_elevation
    return float(min(sensing.fov_azimuth, 2 * np.pi) * (np.sin(hi) - np.sin(lo)) * sensing.max_range**3 / 3.0)


def settings_for(cfg: RunConfig, **overrides: object) -> TrackerSettings:
    """The :class:`TrackerSettings` of a many-target scenario with point sensors (ValueError otherwise)."""
    if cfg.multitarget is None:
        raise ValueError(f"{cfg.source}: not a many-target scenario (it has no [targets] section)")
    spec, sensing = cfg.spec, cfg.multitarget.sensing
    if spec.measurement != "point":
        raise ValueError(f"{cfg.source}: {spec.measurement} sensors; the multi-target bench needs point sensors "
                         "(two-point initiation, and Stone Soup's LinearGaussian measurement model)")
    # lambda must be positive for the associators: a scenario without clutter gets one return per 1000 views
    density = max(sensing.clutter_rate, 1e-3) / view_volume(sensing)
    return TrackerSettings(cfg.filter_kind, make_plant(spec.plant, cfg.ts, spec.plant_params), spec.measurement,
                           np.asarray(spec.p0, dtype=float), cfg.ts, sensing.detection_prob, density,
                           **overrides)  # type: ignore[arg-type]


def make_tracker(s: TrackerSettings) -> MultiTargetTracker:
    """A zentrack multi-target tracker with the settings ``s``."""
    context = FilterContext(s.motion, make_measurement(s.measurement), s.p0)
    assoc = make_associator("gnn", {"detection_prob": s.detection_prob, "clutter_density": s.clutter_density,
                                    "gate_prob": s.gate_prob})
    init = TwoPointInitiator(s.ts, s.max_speed, s.p0, gate_prob=s.gate_prob)
    return MultiTargetTracker.from_registry(s.filter_kind, context, assoc, init, MissesCovarianceDeleter(s.max_misses),
                                            MOfNConfirmer(s.confirm_m, s.confirm_n))


@dataclass
class MethodRun:
    """One method over one run: ``views[v][k]`` the confirmed tracks of view v at step k, the seconds spent, the
    scans processed."""

    method: str
    views: list[list[TrackSet]]
    seconds: float
    scans: int


def confirmed_set(tracker: MultiTargetTracker, ids: Callable[[int], object] = lambda i: i) -> TrackSet:
    """The tracker's confirmed tracks: their ids (``ids`` maps a local id) and positions ``(n, 3)``."""
    tracks = tracker.confirmed()
    return [ids(t.id) for t in tracks], np.array([t.mean[:3] for t in tracks]).reshape(-1, 3)


def run_alone(data: MultiTargetData, s: TrackerSettings) -> MethodRun:
    """Each node's tracker on its own scans."""
    views, seconds = [], 0.0
    for node in range(data.sensors.shape[0]):
        tracker, out = make_tracker(s), []
        for k in range(data.steps):
            scan = data.scan(k, node)
            t0 = time.perf_counter()
            tracker.step(k, scan)
            seconds += time.perf_counter() - t0
            out.append(confirmed_set(tracker))
        views.append(out)
    return MethodRun("alone", views, seconds, data.steps * data.sensors.shape[0])


def run_centralized(data: MultiTargetData, s: TrackerSettings) -> MethodRun:
    """One tracker on every sensor's scan of each step."""
    tracker, out, seconds = make_tracker(s), [], 0.0
    nodes = data.sensors.shape[0]
    for k in range(data.steps):
        scans = [data.scan(k, i) for i in range(nodes)]
        t0 = time.perf_counter()
        tracker.step(k, scans)
        seconds += time.perf_counter() - t0
        out.append(confirmed_set(tracker))
    return MethodRun("centralized", [out], seconds, data.steps * nodes)


class NetworkNode:
    """One node of the distributed network: its local tracker and the network ids of its tracks."""

    def __init__(self, node: int, s: TrackerSettings) -> None:
        self.node = node
        self.tracker = make_tracker(s)
        self.issuer = TrackIdIssuer(node)
        self.ids: dict[int, TrackId] = {}  # local track id -> network id
        self._pending: list[TrackId] = []  # ids of the takeovers queued for the next step, in order

    def local_step(self, k: int, scan) -> None:
        """The local tracker's step; new tracks get their network ids (takeovers first: they are born first)."""
        self.tracker.step(k, scan)
        pending, self._pending = self._pending, []
        for track in self.tracker.tracks:
            if track.id not in self.ids:
                self.ids[track.id] = pending.pop(0) if pending else self.issuer.issue(track.birth_step)
        live = {t.id for t in self.tracker.tracks}
        self.ids = {i: net for i, net in self.ids.items() if i in live}

    def estimates(self, confirmed_only: bool) -> list[TrackEstimate]:
        """Its tracks as track-list entries (kinematic part) under their network ids."""
        k = self.tracker.local_filter.kinematic_dim
        return [TrackEstimate(self.ids[t.id], t.mean[:k], t.cov[:k, :k], t.status.value, t.step)
                for t in self.tracker.tracks if not confirmed_only or t.status is TrackStatus.CONFIRMED]

    def predicted(self, estimate: TrackEstimate) -> tuple[Array, Array]:
        """A track-list entry's kinematic estimate predicted one step by the local filter."""
        f, k = self.tracker.local_filter, self.tracker.local_filter.kinematic_dim
        state = f.predict(f.initial_state(estimate.mean[None], estimate.cov, self.tracker.lumped_var))
        return state.mean[0, :k], state.cov[0, :k, :k]

    def fuse(self, published: dict[int, list[TrackEstimate]], neighbours: Array) -> TrackSet:
        """Fuse its tracks with its neighbours' published lists, feed the result back into its tracker, queue
        the takeovers; its confirmed tracks after the fusion."""
        own = self.estimates(confirmed_only=False)
        result = fuse_track_lists(own, {int(j): published[int(j)] for j in neighbours}, issuer=self.issuer)
        assert len(result.tracks) == len(own), "every own track keeps a network id"
        k = self.tracker.local_filter.kinematic_dim
        for track, fused in zip(self.tracker.tracks, result.tracks):
            track.mean = track.mean.copy()
            track.mean[:k] = fused.mean
            cov = np.zeros_like(track.cov)  # cross terms with augmented blocks dropped: stays block SPD
            cov[:k, :k], cov[k:, k:] = fused.cov, track.cov[k:, k:]
            track.cov = cov
            self.ids[track.id] = fused.id
        for prior in result.takeovers:  # at step k; from_prior takes the estimate at the next step
            mean, cov = self.predicted(prior)
            self.tracker.initiator.from_prior(mean, cov, TrackStatus.CONFIRMED)
            self._pending.append(prior.id)
        return confirmed_set(self.tracker, self.ids.__getitem__)


def run_distributed(data: MultiTargetData, s: TrackerSettings, cfg: RunConfig) -> MethodRun:
    """Every node's tracker on its own scans, then one exchange of confirmed track lists per step over the
    scenario's graph (module docstring)."""
    adjacency, _ = graph_weights(cfg.spec)
    nodes = [NetworkNode(i, s) for i in range(data.sensors.shape[0])]
    views: list[list[TrackSet]] = [[] for _ in nodes]
    seconds = 0.0
    for k in range(data.steps):
        scans = [data.scan(k, n.node) for n in nodes]
        t0 = time.perf_counter()
        for node, scan in zip(nodes, scans):
            node.local_step(k, scan)
        published = {n.node: n.estimates(confirmed_only=True) for n in nodes}
        for node in nodes:
            views[node.node].append(node.fuse(published, np.flatnonzero(adjacency[node.node])))
        seconds += time.perf_counter() - t0
    return MethodRun("distributed", views, seconds, data.steps * len(nodes))
