"""The many-target payload part of the viewer (:class:`~zentrack.viewer.payload.Payload`): the truth's target sets
and every node's track lists as Rerun entities (the core, timelines and events: :mod:`zentrack.viewer.core`).

Markers and lines sized in UI points. Entities:

- ``world/truth/targets``: the targets present at each step (white, labelled ``t<id>``, or a recorded target's
  name or call sign: :meth:`~zentrack.truth.simulation.multitarget.MultiTargetData.target_label`), ``world/truth/paths``
  one thin segment per target and step (the views keep the whole path:
  :func:`~zentrack.viewer.multi_target_layout.multitarget_blueprint`);
- ``world/sensors`` (static, in their node's colour, labelled ``s<i>``);
- per node i, one subtree to toggle, ``world/nodes/<i>/``: ``confirmed`` (the confirmed tracks' positions, full
  colour, labelled ``born/node/serial``), ``tentative`` (smaller, dim; labelled too, the blueprint hides
  those labels), ``trails`` (a segment per track and step from its id's previous position; the views keep the
  last :data:`~zentrack.viewer.multi_target_layout.TRACK_TRAIL_STEPS` steps);
- ``metrics/gospa/<i>`` GOSPA of node i's confirmed tracks against the targets present at the list's step (the
  run's truth, as the recorder scores it: the scenario's cut-off ``data.gospa_cutoff``),
  ``metrics/gospa_{localisation,missed,false}/<i>`` its parts (m²), ``metrics/confirmed/<i>`` the number of
  confirmed tracks and ``metrics/confirmed/targets`` the targets present (wide, translucent grey);
- with sensors of their own (``[sensor_timing]``): every return of each sensor's scans at its own measurement
  time, ``world/sensors/<s>/returns``, and each sensor's latency and share out of order
  (:mod:`zentrack.viewer.detections`);
- ``key`` (static) what the views show;
- a recorded truth (``data.geodetic_origin`` set) only: the same truth, sensors and confirmed tracks in latitude and
  longitude under ``map/`` (:mod:`~zentrack.viewer.map_view`).
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.fusion.models import make_measurement
from zentrack.fusion.multitarget.metrics import gospa
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.track_messages import TargetSet, TrackList
from zentrack.truth.simulation.multitarget import MultiTargetData
from zentrack.viewer.detections import SensorDetections
from zentrack.viewer.layout import TRUTH_RGB, log_node_series
from zentrack.viewer.map_view import GEO_KINDS, MapLayer, region_name_height, region_zoom
from zentrack.viewer.multi_target_layout import multitarget_blueprint, multitarget_key, targets_region
from zentrack.viewer.payload import Canvas

#: the truth's paths (thin, light grey); the targets-present series (a wide translucent grey: the plots' background
#: follows the UI theme, white or dark, and the nodes' lines show through it where they hold as many tracks)
TRUTH_PATH_RGB = [200, 200, 200]
TARGETS_SERIES_RGBA = [140, 140, 140, 150]
GOSPA_PARTS = ("localisation", "missed", "false")
#: a track's trail joins its positions at most this many steps apart (a list lost in between)
TRAIL_GAP_STEPS = 3
#: sizes in UI points: confirmed, tentative, truth marker; trail widths
CONFIRMED_R, TENTATIVE_R, TARGET_R = -5.0, -2.5, -3.5
CONFIRMED_TRAIL_R, TENTATIVE_TRAIL_R, TRUTH_PATH_R = -1.0, -0.5, -0.6


def track_label(track_id) -> str:
    """A track's network identity as drawn: ``born/node/serial``."""
    return f"{track_id.born}/{track_id.node}/{track_id.serial}"


def dim(color: list[int]) -> list[int]:
    """A node's colour dimmed towards the dark background (tentative tracks)."""
    return [int(0.45 * c + 20) for c in color]


class Trails:
    """The last position of each id (a target's, a track's) and the step it was at: each new position joins the
    id's previous one when they are at most :data:`TRAIL_GAP_STEPS` steps apart."""

    def __init__(self) -> None:
        #: id -> (step, position)
        self.last: dict = {}

    def extend(self, k: int, ids: list, positions) -> list[tuple[int, list]]:
        """The segments ``(index, [previous, position])`` of step k's positions (``ids[index]``'s); a position no
        later than its id's last is not drawn."""
        segments = []
        for index, (key, p) in enumerate(zip(ids, positions)):
            before = self.last.get(key)
            if before is not None and before[0] >= k:  # a set older than one already drawn
                continue
            if before is not None and k - before[0] <= TRAIL_GAP_STEPS:
                segments.append((index, [before[1], p]))
            self.last[key] = (k, p)
        return segments

    def forget(self, k: int) -> None:
        """Drop the ids not seen within :data:`TRAIL_GAP_STEPS` steps before step k."""
        for old in [key for key, (step, _) in self.last.items() if step < k - TRAIL_GAP_STEPS]:
            del self.last[old]


def multi_target(data: MultiTargetData, rec: rr.RecordingStream, timing=None) -> tuple[Canvas, MultiTarget]:
    """The canvas and the part of a many-target run (``data`` its truth and sensors; ``timing`` its
    ``[sensor_timing]``, None when the truth measures) recording to ``rec``."""
    canvas = Canvas(rec, data.ts, data.nodes, MultiTarget.COUNTS + (("det",) if timing is not None else ()), GEO_KINDS)
    return canvas, MultiTarget(data, canvas, timing)


class MultiTarget:
    """Draws a many-target run (module docstring) on ``canvas``."""

    #: what :attr:`Canvas.logged` counts
    COUNTS = ("truth", "tracks")

    def __init__(self, data: MultiTargetData, canvas: Canvas, timing=None) -> None:
        self.data, self.canvas = data, canvas
        #: sensors of their own: every return of their scans, each scan at its own time (None: the truth measures)
        self.detections = None
        if timing is not None:
            kinds = [data.kind(s) if s < len(data.sensors) else data.measurement for s in range(timing.sensors)]
            self.detections = SensorDetections(data.ts, data.steps, kinds, [make_measurement(k).dim for k in kinds],
                                               timing, canvas, lambda: None, every_return=True)
        #: the map's rows (a recorded truth only)
        height = region_name_height(data)
        self.map = None if data.geodetic_origin is None or height is None else MapLayer(
            canvas.buf, data.geodetic_origin, canvas.colors, height)
        self.target_trails = Trails()
        self.track_trails = [Trails() for _ in range(data.nodes)]

    def topics(self, keys: Keys) -> dict[str, str]:
        return {"tracks": keys.tracks("*"), **({} if self.detections is None else self.detections.topics(keys))}

    def blueprint(self) -> rrb.Blueprint:
        data = self.data
        return multitarget_blueprint(data.nodes, targets_region(data.truth), int(data.alive.sum(axis=1).max()),
                                     region_zoom(data), own_sensors=self.detections is not None)

    def summary(self) -> str:
        return f"{self.data.nodes} nodes, many-target scenario ({int(self.data.alive.any(axis=0).sum())} targets over the run)"

    def log_static(self) -> None:
        rec = self.canvas.rec
        self.canvas.log_sensors(self.data.sensors)
        self.canvas.log_key(multitarget_key(self.map is not None, self.data.gospa_cutoff, self.detections is not None))
        if self.detections is not None:
            self.detections.log_static(rec)
        if self.map is not None:
            self.map.log_sensors(rec, self.data.sensors)
        log_node_series(rec, self.canvas.colors, ["gospa", "confirmed", *(f"gospa_{p}" for p in GOSPA_PARTS)])
        rec.log("metrics/confirmed/targets", rr.SeriesLines(colors=[TARGETS_SERIES_RGBA], names=["targets present"],
                                                            widths=[5.0]), static=True)

    def handle(self, msg: Message, node: int | None) -> None:
        if self.detections is not None and self.detections.handle(msg):
            return
        if msg.tag == "truth":
            self._on_targets(TargetSet.decode(msg.payload))
        elif msg.tag == "tracks":
            if node is None:
                raise WireError("sender_mismatch", f"tracks on {msg.key!r}: not one of the run's {self.data.nodes} nodes")
            self._on_tracks(node, TrackList.decode(msg.payload, node, 6, 0, self.data.steps - 1))

    def _on_targets(self, targets: TargetSet) -> None:
        k, buf = targets.k, self.canvas.buf
        if k >= self.data.steps:  # a step beyond the run would stretch the timeline
            raise WireError("future", f"targets of step {k} beyond the run's {self.data.steps}")
        self.canvas.reached(k)
        pos = targets.states[:, :3]
        n, ids = len(pos), targets.ids.tolist()
        names = [self.data.target_label(i) for i in ids]
        buf.add("world/truth/targets", "set", k, pos, np.tile(TRUTH_RGB, (n, 1)), np.full(n, TARGET_R), names)
        strips = [strip for _, strip in self.target_trails.extend(k, ids, pos)]
        if strips:
            buf.add("world/truth/paths", "segset", k, strips, np.tile(TRUTH_PATH_RGB, (len(strips), 1)),
                    np.full(len(strips), TRUTH_PATH_R))
        if self.map is not None:
            self.map.targets(k, pos, names)
            self.map.names(k, ids, pos, [self.data.target_name(i) for i in ids])
            self.map.paths(k, strips)
        buf.add("metrics/confirmed/targets", "scalar", k, float(n))
        self.canvas.logged["truth"] += 1

    def _on_tracks(self, i: int, lst: TrackList) -> None:
        k, buf, color = lst.k, self.canvas.buf, self.canvas.colors[i]
        self.canvas.reached(k)
        base = f"world/nodes/{i}"
        drawn = {}
        for status, rgb, radius in (("confirmed", color, CONFIRMED_R), ("tentative", dim(color), TENTATIVE_R)):
            tracks = [e for e in lst.tracks if e.status == status]
            pos = np.array([e.mean[:3] for e in tracks]).reshape(-1, 3)
            drawn[status] = pos, [track_label(e.id) for e in tracks]
            buf.add(f"{base}/{status}", "set", k, pos, np.tile(rgb, (len(tracks), 1)), np.full(len(tracks), radius),
                    drawn[status][1])
        self._trails(i, lst)
        confirmed = drawn["confirmed"][0]
        if self.map is not None:
            self.map.confirmed(i, k, *drawn["confirmed"])
        score = gospa(confirmed, self.data.truth_at(k)[1][:, :3], self.data.gospa_cutoff)
        buf.add(f"metrics/gospa/{i}", "scalar", k, score.total)
        for part in GOSPA_PARTS:
            buf.add(f"metrics/gospa_{part}/{i}", "scalar", k, float(getattr(score, part)))
        buf.add(f"metrics/confirmed/{i}", "scalar", k, float(len(confirmed)))
        self.canvas.logged["tracks"] += 1

    def _trails(self, i: int, lst: TrackList) -> None:
        """A segment from each track's previous position (its id, at most TRAIL_GAP_STEPS before) to this one."""
        k, trails, color = lst.k, self.track_trails[i], self.canvas.colors[i]
        segments = trails.extend(k, [e.id for e in lst.tracks], [e.mean[:3] for e in lst.tracks])
        trails.forget(k)
        confirmed = [lst.tracks[index].status == "confirmed" for index, _ in segments]
        colors = [color if c else dim(color) for c in confirmed]
        radii = [CONFIRMED_TRAIL_R if c else TENTATIVE_TRAIL_R for c in confirmed]
        self.canvas.buf.add(f"world/nodes/{i}/trails", "segset", k, [strip for _, strip in segments],
                            np.array(colors, dtype=np.uint8).reshape(-1, 3), np.array(radii, dtype=float))
