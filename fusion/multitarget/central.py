"""One tracker of every sensor's scans: the centralized many-target tracker of any network, point, bearing-only or
mixed (cameras and radars).

It is a :class:`~.tracker.MultiTargetTracker` built from the nodes' own :class:`~.network.TrackerSettings`
(:func:`make_central_tracker`), stepped on every sensor's scan of a step in sensor order:

- **update**: each scan with its own sensor's measurement model, local filter and GNN associator (its kind's
  clutter density and P_D: :class:`~.tracker.SensorModel`); every track is predicted once per step by the shared
  motion model;
- **initiation**: by each kind's own initiator, built as a node builds it (:func:`~.network.make_initiator`) but
  with every sensor as its own: point sensors by two-point differencing of each sensor's consecutive leftovers
  (:class:`~.initiator.TwoPointInitiator` keeps its candidates per sensor), bearing sensors by triangulating
  each scan's leftover rays with those of the step's scans before it
  (:class:`~.triangulation.TriangulationInitiator` with ``sensor=None``: a node does the same with its
  neighbours' scans; the centre has all of them, so its "neighbours" are all sensors);
- **one target, one birth**: a target that six cameras see gives two triangles of three fresh rays in one
  step, and in a mixed network a camera triangle and a radar pair can start the same target in one step:
  :class:`SensorInitiator` drops a birth whose position lies within the gate (``chi2_3(P_G)`` on the sum of
  the position covariances, :func:`~.initiator.started_already`, the test by which two radars' pairs already
  start a target once) of one started at this step (for point sensors alone it drops nothing the two-point
  initiator has not dropped already: the same test on the same points);
- M-of-N confirmation over steps and deletion after K steps without a return, as the nodes'; where there are
  cameras, also a track that over its last K steps no radar and fewer than three cameras detected
  (:class:`~.lifecycle.RayConfirmationDeleter`: a triangulation ghost is two cameras' rays of two targets).

A network of point sensors gets the tracker it had before: ``make_gnn_tracker`` of the settings with its two-point
initiator.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..filters.base import FILTER_REGISTRY, LocalFilter
from ..scan import Scan
from .base import Birth, Initiator
from .gating import gate_gamma
from .initiator import started_already
from .lifecycle import RayConfirmationDeleter
from .network import TrackerSettings, filter_context, make_gnn, make_gnn_tracker, make_initiator
from .tracker import MultiTargetTracker, SensorModel

Array = np.ndarray


class SensorInitiator(Initiator):
    """Each scan's leftovers to its sensor's initiator (``by_sensor``); a birth within the gate of one started
    at the same step is dropped (module docstring)."""

    def __init__(self, by_sensor: Mapping[int, Initiator], gate_prob: float = 0.999) -> None:
        super().__init__()
        self.by_sensor = dict(by_sensor)
        self.gamma = gate_gamma(3, gate_prob)
        #: the step of the last births and their positions and position covariances
        self.started: tuple[int, list[tuple[Array, Array]]] = (-1, [])

    def births_from_returns(self, returns: Array, scan: Scan, step: int) -> list[Birth]:
        if scan.sensor not in self.by_sensor:
            raise ValueError(f"a scan of sensor {scan.sensor}, which this tracker has no initiator for")
        if self.started[0] != step:
            self.started = (step, [])
        out = []
        for birth in self.by_sensor[scan.sensor].births_from_returns(returns, scan, step):
            z, cov = birth.mean[:3], birth.cov[:3, :3]
            if not started_already(z, cov, self.started[1], self.gamma):
                out.append(birth)
                self.started[1].append((z, cov))
        return out


def sensor_model(s: TrackerSettings) -> SensorModel:
    """The local filter, measurement model and associator of a sensor with the settings ``s``."""
    context = filter_context(s)
    built = FILTER_REGISTRY.create(s.filter_kind, None, context)
    if not isinstance(built, LocalFilter) or context.measurement is None:
        raise TypeError(f"local filter {s.filter_kind!r} is not a batched LocalFilter; it cannot run per track")
    return SensorModel(built, context.measurement, make_gnn(s))


def make_central_tracker(settings: Sequence[TrackerSettings]) -> MultiTargetTracker:
    """One tracker of the scans of sensors ``0 .. M-1`` whose nodes have the settings ``settings[i]`` (module
    docstring). The sensors of one kind share one settings object (as ``node_settings`` gives); the confirmation and deletion are the first
    sensor's (ValueError if the kinds' differ)."""
    if not settings:
        raise ValueError("a centralized tracker needs at least one sensor")
    by_kind: dict[str, TrackerSettings] = {}
    for s in settings:
        if by_kind.setdefault(s.measurement, s) is not s:
            raise ValueError(f"the {s.measurement} sensors have settings of their own: one tracker takes one "
                             "TrackerSettings per kind")
    first = settings[0]
    for s in by_kind.values():
        if (s.confirm_m, s.confirm_n, s.max_misses, s.filter_kind) != (first.confirm_m, first.confirm_n,
                                                                       first.max_misses, first.filter_kind):
            raise ValueError("the kinds' filter, confirmation or deletion differ: one tracker has one of each")
    tracker = make_gnn_tracker(first)
    tracker.min_hit_sensors = 1  # a radar's return is a hit; the cameras' ghosts go by the third-ray rule below
    if len(by_kind) > 1:
        models = {kind: sensor_model(s) for kind, s in by_kind.items()}
        tracker.sensor_models = {i: models[s.measurement] for i, s in enumerate(settings)}
    initiators = {kind: make_initiator(s, None) for kind, s in by_kind.items()}
    bearing = [i for i, s in enumerate(settings) if s.measurement == "bearing"]
    if bearing:
        tracker.deleter = RayConfirmationDeleter(tracker.deleter, bearing, window=first.max_misses)
    tracker.initiator = SensorInitiator({i: initiators[s.measurement] for i, s in enumerate(settings)},
                                        first.gate_prob)
    return tracker
