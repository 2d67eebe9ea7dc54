"""zentrack's multi-target trackers run over one simulated many-target run: each node alone, the distributed network
(local trackers and one track-list exchange per step), and a centralized tracker on every scan.

Every method gets the same :class:`TrackerSettings` (:func:`settings_for`; a mixed network's nodes each get their
own sensor kind's, :func:`node_settings`): the scenario's plant as the motion model,
its measurement model and noise, its new-track covariance ``[initial] p0_diag``, its P_D and clutter density
``lambda = clutter_rate / V`` (V the volume of a point sensor's field of view, or the solid angle box of a bearing
sensor's), a GNN associator (:class:`~zentrack.fusion.multitarget.gnn.GlobalNearestNeighbour`), two-point
initiation (bearing sensors: triangulation with the neighbours' scans), M-of-N confirmation and
deletion after K misses (no covariance bound: Stone Soup's comparator has none). What differs is which scans a
tracker sees and what it exchanges:

- **alone**: node i's tracker on node i's scans only;
- **distributed** (:func:`run_distributed`): node i's tracker on its own scans (bearing sensors: its graph
  neighbours' scans of the step, then its own, as a live node that exchanges scans; its confirmed tracks then are
  what it is judged by: what a live node publishes on ``tracks/<i>``); then every node publishes its
  confirmed tracks under network ids (:class:`~zentrack.fusion.track_to_track.TrackId`), and each node fuses its own
  tracks with its graph neighbours' lists (:func:`~zentrack.fusion.track_to_track.fuse_track_lists`, CI with the
  fast weights): the fused estimates replace its tracks' estimates (a diffusion step, as the single-target
  trackers do with their priors), renamed tracks take the network id, and every neighbour's target it does not
  hold starts a confirmed track from its prior (``Initiator.from_prior``) at the next step;
- **centralized**: one tracker on every sensor's scan of each step, in sensor order, each scan with its own
  sensor's measurement model and associator; it starts tracks by each kind's initiator with every sensor as
  its own (bearing sensors: each scan's leftover rays triangulated with those of the scans before it; a node
  does the same with its neighbours'), :mod:`zentrack.fusion.multitarget.central`.

Each run gives, per view (a node, or the one centralized tracker), the confirmed tracks' positions under their
ids at every step, and the seconds spent in the trackers (and, distributed, in the fusion).
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from zentrack.config.scenario_config import RunConfig
from zentrack.config.scenario_multitarget import tracking_params
from zentrack.fusion.models import make_plant
from zentrack.fusion.multitarget.central import make_central_tracker
from zentrack.fusion.multitarget.network import NetworkTracker, TrackerSettings, make_tracker
from zentrack.fusion.multitarget.pmbm_tracker import PmbmTracker
from zentrack.fusion.multitarget.tracker import MultiTargetTracker
from zentrack.truth.simulation.multitarget import MultiTargetData
from zentrack.truth.simulation.scenario_spec import graph_weights

Array = np.ndarray
#: one step's confirmed tracks: (ids, positions (n, 3))
TrackSet = tuple[list, Array]


def settings_for(cfg: RunConfig, kind: str | None = None, **overrides: object) -> TrackerSettings:
    """The :class:`TrackerSettings` of a many-target scenario's sensors of measurement kind ``kind`` (None: the
    scenario's ``[measurement] kind``); ValueError for a single-target scenario."""
    if cfg.multitarget is None:
        raise ValueError(f"{cfg.source}: not a many-target scenario (it has no [targets] section)")
    spec = cfg.spec
    kind = spec.measurement if kind is None else kind
    params = tracking_params(cfg.multitarget, kind, cfg.source)
    return TrackerSettings(cfg.filter_kind, make_plant(spec.plant, cfg.ts, spec.plant_params), kind,
                           np.asarray(spec.p0, dtype=float), cfg.ts, **{**params, **overrides})  # type: ignore[arg-type]


def node_settings(cfg: RunConfig) -> list[TrackerSettings]:
    """Every node's :class:`TrackerSettings`, by its sensor's kind (a mixed network's cameras and radars)."""
    first = settings_for(cfg)  # refuses a single-target scenario
    assert cfg.multitarget is not None
    kinds = cfg.multitarget.sensor_kinds(first.measurement, cfg.spec.nodes)
    by_kind = {kind: settings_for(cfg, kind) for kind in dict.fromkeys(kinds)}
    return [by_kind[kind] for kind in kinds]


def _per_node(s: TrackerSettings | Sequence[TrackerSettings], nodes: int) -> list[TrackerSettings]:
    return [s] * nodes if isinstance(s, TrackerSettings) else list(s)


@dataclass
class MethodRun:
    """One method over one run: ``views[v][k]`` the confirmed tracks of view v at step k, the seconds spent, the
    scans processed."""

    method: str
    views: list[list[TrackSet]]
    seconds: float
    scans: int


def confirmed_set(tracker: MultiTargetTracker | PmbmTracker, ids: Callable[[int], object] = lambda i: i) -> TrackSet:
    """The tracker's confirmed tracks: their ids (``ids`` maps a local id) and positions ``(n, 3)``."""
    tracks = tracker.confirmed()
    return [ids(t.id) for t in tracks], np.array([t.mean[:3] for t in tracks]).reshape(-1, 3)


def run_alone(data: MultiTargetData, s: TrackerSettings | Sequence[TrackerSettings]) -> MethodRun:
    """Each node's tracker on its own scans (``s``: every node's settings, or one for all)."""
    views, seconds = [], 0.0
    settings = _per_node(s, data.nodes)
    for node in range(data.sensors.shape[0]):
        tracker, out = make_tracker(settings[node]), []
        for k in range(data.steps):
            scan = data.scan(k, node)
            t0 = time.perf_counter()
            tracker.step(k, scan)
            seconds += time.perf_counter() - t0
            out.append(confirmed_set(tracker))
        views.append(out)
    return MethodRun("alone", views, seconds, data.steps * data.sensors.shape[0])


def run_centralized(data: MultiTargetData, s: TrackerSettings | Sequence[TrackerSettings]) -> MethodRun:
    """One tracker on every sensor's scan of each step (``s``: every node's settings, or one for all), each scan
    taken by its sensor's models (:func:`~zentrack.fusion.multitarget.central.make_central_tracker`)."""
    tracker, out, seconds = make_central_tracker(_per_node(s, data.nodes)), [], 0.0
    nodes = data.sensors.shape[0]
    for k in range(data.steps):
        scans = [data.scan(k, i) for i in range(nodes)]
        t0 = time.perf_counter()
        tracker.step(k, scans)
        seconds += time.perf_counter() - t0
        out.append(confirmed_set(tracker))
    return MethodRun("centralized", [out], seconds, data.steps * nodes)


def run_distributed(data: MultiTargetData, s: TrackerSettings | Sequence[TrackerSettings], cfg: RunConfig) -> MethodRun:
    """Every node's tracker on its own scans, then one exchange of confirmed track lists per step over the
    scenario's graph (module docstring; ``s``: every node's settings, or one for all). A node that exchanges
    scans takes those of its neighbours of its own kind (a mixed network's cameras do not take the radars')."""
    adjacency, _ = graph_weights(cfg.spec)
    nodes = [NetworkTracker(i, si) for i, si in enumerate(_per_node(s, data.nodes))]
    views: list[list[TrackSet]] = [[] for _ in nodes]
    seconds = 0.0
    for k in range(data.steps):
        scans = [data.scan(k, n.node) for n in nodes]
        t0 = time.perf_counter()
        for node, scan in zip(nodes, scans):
            if node.settings.exchanges_scans:  # bearing sensors: the neighbours' scans of the step, then the own
                node.local_step(k, [scans[int(j)] for j in np.flatnonzero(adjacency[node.node])  # (as live)
                                    if j != node.node and data.kind(int(j)) == data.kind(node.node)] + [scan])
            else:
                node.local_step(k, scan)
        published = {n.node: n.estimates(confirmed_only=True) for n in nodes}
        for node in nodes:  # what it publishes at k is what it is judged by, as a live node (tracks/<i>)
            views[node.node].append(node.confirmed())
            node.fuse({int(j): published[int(j)] for j in np.flatnonzero(adjacency[node.node]) if j != node.node})
        seconds += time.perf_counter() - t0
    return MethodRun("distributed", views, seconds, data.steps * len(nodes))
