"""The viewer of a many-target run: the truth's target sets and every node's track lists as Rerun entities.

Timelines ``step`` and ``time`` as for one target (:mod:`zentrack.viewer.entities`); markers and lines sized
in UI points. Entities:

- ``world/truth/targets``: the targets present at each step (white, labelled ``t<id>``, or a recorded target's
  name or call sign: :meth:`~zentrack.truth.simulation.multitarget.MultiTargetData.target_label`), ``world/truth/paths``
  one thin segment per target and step (the views keep the whole path: :func:`~zentrack.viewer.layout.multitarget_blueprint`);
- ``world/sensors`` (static, in their node's colour, labelled ``s<i>``);
- per node i, one subtree to toggle, ``world/nodes/<i>/``: ``confirmed`` (the confirmed tracks' positions, full
  colour, labelled ``born/node/serial``), ``tentative`` (smaller, dim; labelled too, the blueprint hides
  those labels), ``trails`` (a segment per track and step from its id's previous position; the views keep the
  last :data:`~zentrack.viewer.layout.TRACK_TRAIL_STEPS` steps);
- ``metrics/gospa/<i>`` GOSPA of node i's confirmed tracks against the targets present at the list's step (the
  run's truth, as the recorder scores it: the scenario's cut-off ``data.gospa_cutoff``),
  ``metrics/gospa_{localisation,missed,false}/<i>`` its parts (m²), ``metrics/confirmed/<i>`` the number of
  confirmed tracks and ``metrics/confirmed/targets`` the targets present (wide, translucent grey);
- ``key`` (static) what the views show, ``events`` nodes joining and leaving;
- a recorded truth (``data.geodetic_origin`` set) only: the same truth, sensors and confirmed tracks in latitude and
  longitude under ``map/`` (:mod:`~zentrack.viewer.map_view`).

A message that does not decode (:class:`~zentrack.transport.codec.WireError`) is counted in
``logged["bad"]`` and skipped.
"""
from __future__ import annotations

import logging
import time

import numpy as np
import rerun as rr

from zentrack.common.procs import StopFlag
from zentrack.fusion.multitarget.metrics import gospa
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import node_id
from zentrack.transport.messages import Stop
from zentrack.transport.track_messages import TargetSet, TrackList
from zentrack.transport.zsession import Inbox
from zentrack.truth.simulation.multitarget import MultiTargetData
from zentrack.viewer.columns import ColumnBuffer
from zentrack.viewer.layout import TRUTH_RGB, multitarget_key, node_color
from zentrack.viewer.map_view import GEO_KINDS, MapLayer, region_name_height

log = logging.getLogger("zentrack.viewer")

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


def _cloud(rows: list):
    """Rows of (positions (n, 3), colours (n, 3), radii (n,), labels (n,)), any n per row (0 included)."""
    return rr.Points3D.columns(
        positions=np.concatenate([np.reshape(r[0], (-1, 3)) for r in rows]),
        colors=np.concatenate([np.reshape(r[1], (-1, 3)) for r in rows]).astype(np.uint8),
        radii=np.concatenate([np.reshape(r[2], -1) for r in rows]),
        labels=[label for r in rows for label in r[3]]).partition([len(r[0]) for r in rows])


def _segments(rows: list):
    """Rows of (segments [[a, b], ...], colours (n, 3), radii (n,)), any n per row (0 included)."""
    return rr.LineStrips3D.columns(
        strips=[s for r in rows for s in r[0]],
        colors=np.concatenate([np.reshape(r[1], (-1, 3)) for r in rows]).astype(np.uint8),
        radii=np.concatenate([np.reshape(r[2], -1) for r in rows])).partition([len(r[0]) for r in rows])


class TrackColumns(ColumnBuffer):
    """:class:`ColumnBuffer` with point sets and segment sets of any size per step, empty ones included (an
    empty row clears what the step before drew: a node without tracks shows none)."""

    KINDS = {**ColumnBuffer.KINDS, "set": _cloud, "segset": _segments, **GEO_KINDS}


class MultiTargetViewer:
    """Logs a many-target run (module docstring). ``session`` None: no subscriptions, messages come through
    :meth:`handle` (tests)."""

    def __init__(self, session, keys, data: MultiTargetData, rec: rr.RecordingStream, flush_s: float = 1.0) -> None:
        self.keys, self.data, self.rec, self.flush_s = keys, data, rec, flush_s
        self.m = data.nodes
        self.colors = [node_color(i, self.m) for i in range(self.m)]
        self.inbox = Inbox(rate_per_key=1e9, max_queued=100_000)
        self.buf = TrackColumns(rec, data.ts)
        #: the map's rows (a recorded truth only)
        height = region_name_height(data)
        self.map = None if data.geodetic_origin is None or height is None else MapLayer(
            self.buf, data.geodetic_origin, self.colors, height)
        self.logged = {"truth": 0, "tracks": 0, "bad": 0}
        self.stopped = False
        self.current_step = 0
        #: the last position of each target: id -> (step, position)
        self.last_target: dict[int, tuple[int, np.ndarray]] = {}
        #: per node, the last position of each track id: id -> (step, position)
        self.last_track: list[dict] = [dict() for _ in range(self.m)]
        self.subs: list = []
        self.token = None
        if session is not None:
            self.subs = [
                session.declare_subscriber(keys.truth, self.inbox.callback("truth")),
                session.declare_subscriber(keys.tracks("*"), self.inbox.callback("tracks")),
                session.declare_subscriber(keys.stop, self.inbox.callback("stop")),
                session.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(), history=True),
            ]
            self.token = session.liveliness().declare_token(keys.alive("viewer"))
        self._log_static()

    def _log_static(self) -> None:
        rec = self.rec
        rec.log("world/sensors", rr.Points3D(self.data.sensors, colors=self.colors, radii=-5.0,
                                             labels=[f"s{i}" for i in range(self.m)]), static=True)
        rec.log("key", rr.TextDocument(multitarget_key(self.map is not None, self.data.gospa_cutoff), media_type="text/markdown"),
                static=True)
        if self.map is not None:
            self.map.log_sensors(rec, self.data.sensors)
        for i, color in enumerate(self.colors):
            for name in ("gospa", "confirmed", *(f"gospa_{p}" for p in GOSPA_PARTS)):
                rec.log(f"metrics/{name}/{i}", rr.SeriesLines(colors=[color], names=[f"node {i}"]), static=True)
        rec.log("metrics/confirmed/targets", rr.SeriesLines(colors=[TARGETS_SERIES_RGBA], names=["targets present"],
                                                            widths=[5.0]), static=True)

    def run(self, stop: StopFlag, duration: float | None, stop_grace: float = 1.0) -> None:
        """Log until ctl/stop (then ``stop_grace`` seconds more for stragglers), a signal, or ``duration``."""
        end = None if duration is None else time.time() + duration
        next_flush = time.time() + self.flush_s
        while not stop and (end is None or time.time() < end):
            msg = self.inbox.get(0.2)
            while msg is not None:
                was_stopped = self.stopped
                self.handle(msg)
                if self.stopped and not was_stopped:
                    end = time.time() + stop_grace if end is None else min(end, time.time() + stop_grace)
                msg = self.inbox.get(0.0) if time.time() < next_flush else None
            if time.time() >= next_flush:
                self.buf.flush()
                next_flush = time.time() + self.flush_s
        self.buf.flush()

    def handle(self, msg: Message) -> None:
        """Draw one message; one that does not decode is counted and skipped."""
        try:
            if msg.tag == "truth":
                self._on_targets(TargetSet.decode(msg.payload))
            elif msg.tag == "tracks":
                i = self.keys.node_of(msg.key)
                if i is None or i >= self.m:
                    raise WireError("sender_mismatch", f"tracks on {msg.key!r}: not one of the run's {self.m} nodes")
                self._on_tracks(i, TrackList.decode(msg.payload, i, 6, 0, self.data.steps - 1))
            elif msg.tag == "alive":
                who = self.keys.last_segment(msg.key)
                joined = msg.payload == b"put"
                self.rec.set_time("step", sequence=self.current_step)
                self.rec.set_time("time", duration=self.current_step * self.data.ts)
                self.rec.log("events", rr.TextLog(f"{'node ' if node_id(who) is not None else ''}{who} "
                                                  f"{'joined' if joined else 'left'}", level="INFO" if joined else "WARN"))
            elif msg.tag == "stop":
                Stop.decode(msg.payload)
                self.stopped = True
        except WireError as err:
            self.logged["bad"] += 1
            if self.logged["bad"] <= 3:
                log.warning("viewer: dropped a %s message (%s)", msg.tag, err)

    def _on_targets(self, targets: TargetSet) -> None:
        k = targets.k
        if k >= self.data.steps:  # a step beyond the run would stretch the timeline
            raise WireError("future", f"targets of step {k} beyond the run's {self.data.steps}")
        self.current_step = max(self.current_step, k)
        pos = targets.states[:, :3]
        n = len(pos)
        names = [self.data.target_label(i) for i in targets.ids.tolist()]
        self.buf.add("world/truth/targets", "set", k, pos, np.tile(TRUTH_RGB, (n, 1)), np.full(n, TARGET_R), names)
        strips = []
        for tid, p in zip(targets.ids.tolist(), pos):
            last = self.last_target.get(tid)
            if last is not None and last[0] < k:
                if k - last[0] <= TRAIL_GAP_STEPS:
                    strips.append([last[1], p])
            if last is None or last[0] < k:
                self.last_target[tid] = (k, p)
        if strips:
            self.buf.add("world/truth/paths", "segset", k, strips, np.tile(TRUTH_PATH_RGB, (len(strips), 1)),
                         np.full(len(strips), TRUTH_PATH_R))
        if self.map is not None:
            self.map.targets(k, pos, names)
            self.map.names(k, targets.ids.tolist(), pos, [self.data.target_name(i) for i in targets.ids.tolist()])
            self.map.paths(k, strips)
        self.buf.add("metrics/confirmed/targets", "scalar", k, float(n))
        self.logged["truth"] += 1

    def _on_tracks(self, i: int, lst: TrackList) -> None:
        k = lst.k
        self.current_step = max(self.current_step, k)
        base, color = f"world/nodes/{i}", self.colors[i]
        drawn = {}
        for status, rgb, radius in (("confirmed", color, CONFIRMED_R), ("tentative", dim(color), TENTATIVE_R)):
            tracks = [e for e in lst.tracks if e.status == status]
            pos = np.array([e.mean[:3] for e in tracks]).reshape(-1, 3)
            drawn[status] = pos, [track_label(e.id) for e in tracks]
            self.buf.add(f"{base}/{status}", "set", k, pos, np.tile(rgb, (len(tracks), 1)),
                         np.full(len(tracks), radius), drawn[status][1])
        self._trails(i, lst)
        confirmed = drawn["confirmed"][0]
        if self.map is not None:
            self.map.confirmed(i, k, *drawn["confirmed"])
        score = gospa(confirmed, self.data.truth_at(k)[1][:, :3], self.data.gospa_cutoff)
        self.buf.add(f"metrics/gospa/{i}", "scalar", k, score.total)
        for part in GOSPA_PARTS:
            self.buf.add(f"metrics/gospa_{part}/{i}", "scalar", k, float(getattr(score, part)))
        self.buf.add(f"metrics/confirmed/{i}", "scalar", k, float(len(confirmed)))
        self.logged["tracks"] += 1

    def _trails(self, i: int, lst: TrackList) -> None:
        """A segment from each track's previous position (its id, at most TRAIL_GAP_STEPS before) to this one."""
        k, last = lst.k, self.last_track[i]
        strips, colors, radii = [], [], []
        for e in lst.tracks:
            p = e.mean[:3]
            before = last.get(e.id)
            if before is not None and before[0] >= k:  # a list older than one already drawn
                continue
            if before is not None and k - before[0] <= TRAIL_GAP_STEPS:
                confirmed = e.status == "confirmed"
                strips.append([before[1], p])
                colors.append(self.colors[i] if confirmed else dim(self.colors[i]))
                radii.append(CONFIRMED_TRAIL_R if confirmed else TENTATIVE_TRAIL_R)
            last[e.id] = (k, p)
        for old in [tid for tid, (step, _) in last.items() if step < k - TRAIL_GAP_STEPS]:
            del last[old]
        self.buf.add(f"world/nodes/{i}/trails", "segset", k, strips, np.array(colors, dtype=np.uint8).reshape(-1, 3),
                     np.array(radii, dtype=float))

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        if self.token is not None:
            self.token.undeclare()
