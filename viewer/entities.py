"""The viewer's subscriber: every message of a run drawn as Rerun entities (timelines ``step`` and ``time``).

- ``world/target`` a ``Transform3D`` (translation: the true position) per step: the frame the target view
  is drawn in (:mod:`zentrack.viewer.layout`);
- ``world/truth/position`` the truth (white, labelled ``truth``), ``world/truth/path`` one segment per step;
- ``world/sensors`` (static, labelled ``s<i>``), ``world/nodes/<i>/estimate`` point, ``.../trail`` one segment
  per step, ``.../ellipsoid`` the 3-σ position covariance ellipsoid (half sizes 3·sqrt(eig), principal axes),
  ``.../ray`` the current bearing line of sight (bearing scenarios; satellites also ``.../ray_near``, its part
  near the target) or ``.../measurement`` (point scenarios);
- with clutter (paper 1): ``world/nodes/<i>/clutter`` the clutter returns' rays (grey; the target's return,
  known from the replayed scenario, is ``.../ray``), ``.../particles`` a subsample of the node's particle cloud;
- with moving sensors (paper 2 UAVs, paper 3 satellites): ``world/platforms/<i>/{position,trail}`` from the
  pose each scan carries, and ``world/graph`` the communication links between the current positions;
- with an extended object (paper 4): outlines, scan points, sensor and relay nodes (:mod:`.extent_view`);
- ``key`` (static): what the views show for the scenario's family, as a text document;
- ``events``: liveliness joins and departures and newly rejected messages, as a text log;
- ``metrics/...`` and ``world/fused``: :mod:`zentrack.viewer.metrics`.

Markers and lines are sized in UI points (a fixed size on screen), so the target view, a few metres across,
and the sensor layout, up to hundreds of km, both show them.
"""
from __future__ import annotations

import logging
import time

import numpy as np
import rerun as rr

from zentrack.common.procs import StopFlag
from zentrack.transport.codec import MAX_ROUNDS, Message, WireError
from zentrack.transport.keys import node_id
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Stop, Truth
from zentrack.transport.zsession import Inbox
from zentrack.viewer.columns import ColumnBuffer
from zentrack.viewer.extent_view import ExtentView
from zentrack.viewer.geometry import bearing_direction
from zentrack.viewer.layout import CLUTTER_RGB, TARGET_FRAME, TRUTH_RGB, Scene, node_color
from zentrack.viewer.metrics import Metrics, ellipsoid_of, round_message_dims

log = logging.getLogger("zentrack.viewer")


class Viewer:
    def __init__(self, session, keys, setup, rec: rr.RecordingStream, scene: Scene, flush_s: float = 1.0) -> None:
        self.keys, self.rec, self.flush_s, self.scene = keys, rec, flush_s, scene
        self.scn = setup.scenario
        self.m = self.scn.nodes
        self.inbox = Inbox(rate_per_key=1e9, max_queued=100_000)  # every round of every node, faster in lockstep
        self.last_est: dict[int, np.ndarray] = {}
        self.last_truth: np.ndarray | None = None
        self.rejected: dict[int, dict] = {}
        self.logged = {"est": 0, "truth": 0, "meas": 0, "bad": 0}
        self.stopped = False
        self.current_step = 0
        self.colors = [node_color(i, self.m) for i in range(self.m)]
        self.moving = self.scn.sensor_track is not None
        self.far = scene.family == "satellites"
        self.poses: dict[int, np.ndarray] = {}  # the latest pose of each moving sensor
        self.edges = [(i, int(j)) for i in range(self.m) for j in np.flatnonzero(self.scn.adjacency[i]) if j > i]
        info = round_message_dims(setup)  # None: one round per step, no disagreement to draw
        self.round_dims: dict[str, int] | None = None if info is None else info[0]
        self.subs = [
            session.declare_subscriber(keys.truth, self.inbox.callback("truth")),
            session.declare_subscriber(keys.est("*"), self.inbox.callback("est")),
            session.declare_subscriber(keys.meas("*"), self.inbox.callback("meas")),
            session.declare_subscriber(keys.stop, self.inbox.callback("stop")),
            session.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(), history=True),
        ]
        if self.round_dims is not None:
            self.subs.append(session.declare_subscriber(keys.prior("*"), self.inbox.callback("prior")))
        self.token = session.liveliness().declare_token(keys.alive("viewer"))
        self.buf = ColumnBuffer(rec, self.scn.ts)
        self.extent = ExtentView(self.scn, self.buf, self.colors) if self.scn.plant == "eot" else None
        #: the state components drawn as a position (an extended object's centre is 2-D, on the surface)
        self.pos_dims = 2 if self.extent is not None else min(3, self.scn.truth.shape[-1])
        self.metrics = Metrics(self.scn, self.buf, self.colors, self.pos_dims, None if info is None else info[1],
                               self.extent)
        self._log_static()

    def _log_static(self) -> None:
        rec, scn = self.rec, self.scn
        if self.extent is not None:
            self.extent.log_static(rec)
        elif scn.truth.shape[-1] >= 3 and scn.sensor_track is None:
            rec.log("world/sensors", rr.Points3D(scn.sensors, colors=self.colors, radii=-5.0,
                                                 labels=[f"s{i}" for i in range(self.m)]), static=True)
        rec.log("key", rr.TextDocument(self.scene.key, media_type="text/markdown"), static=True)
        self.metrics.log_static(rec)

    def _time(self, k: int) -> None:
        self.current_step = max(self.current_step, k)
        self.rec.set_time("step", sequence=k)
        self.rec.set_time("time", duration=k * self.scn.ts)

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
        try:
            last = self.scn.steps - 1  # a step beyond the run would stretch the timeline (or break Rerun's)
            if msg.tag == "truth":
                truth = Truth.decode(msg.payload)
                self._check_state(truth.k, truth.x)
                self._on_truth(truth)
            elif msg.tag == "est":
                i = self.keys.node_of(msg.key)
                if i is not None and i < self.m:
                    est = EstimateMessage.decode(msg.payload, i)
                    self._check_state(est.k, est.x)
                    self._on_est(i, est)
            elif msg.tag == "meas":
                i = self.keys.node_of(msg.key)
                if i is not None and i < self.m:
                    self._on_meas(i, Measurement.decode(msg.payload, i, self.scn.measurements.shape[-1], 0, last))
            elif msg.tag == "prior":
                i = self.keys.node_of(msg.key)
                if i is not None and i < self.m and self.round_dims is not None:  # the last is for step `steps`
                    self.metrics.on_round(i, RoundMessage.decode(msg.payload, i, self.round_dims, 0, last + 1, MAX_ROUNDS))
            elif msg.tag == "alive":
                who = self.keys.last_segment(msg.key)
                joined = msg.payload == b"put"
                self._time(self.current_step)
                self.rec.log("events", rr.TextLog(f"{'node ' if node_id(who) is not None else ''}{who} {'joined' if joined else 'left'}",
                                                  level="INFO" if joined else "WARN"))
            elif msg.tag == "stop":
                Stop.decode(msg.payload)  # the truth's (anything else on ctl/stop is counted and ignored)
                self.stopped = True
        except WireError as err:
            self.logged["bad"] += 1
            if self.logged["bad"] <= 3:
                log.warning("viewer: dropped a %s message (%s)", msg.tag, err)

    def _check_state(self, k: int, x: np.ndarray) -> None:
        """A true state or estimate is drawn and scored against the scenario's: one of its steps, its dimension."""
        if k >= self.scn.steps:
            raise WireError("future", f"step {k} beyond the run's {self.scn.steps}")
        if x.shape[0] != self.scn.truth.shape[-1]:
            raise WireError("shape", f"x: dimension {x.shape[0]}, the scenario's is {self.scn.truth.shape[-1]}")

    def _on_truth(self, t: Truth) -> None:
        k, x = t.k, t.x
        self.current_step = max(self.current_step, k)
        p = self.metrics.pos(x)
        self.buf.add(TARGET_FRAME, "translation", k, p)
        self.buf.add("world/truth/position", "labelled", k, p, TRUTH_RGB, -7.0, "truth")
        if self.last_truth is not None:
            self.buf.add("world/truth/path", "segment", k, [self.last_truth, p], TRUTH_RGB, -1.5)
        self.last_truth = p
        if self.extent is not None:
            self.extent.truth(k, x)
        self.metrics.on_truth(k, x)
        if self.moving and len(self.poses) >= 2:
            links = [[self.poses[i], self.poses[j]] for i, j in self.edges if i in self.poses and j in self.poses]
            if links:
                self.buf.add("world/graph", "segments", k, links, np.tile([90, 90, 140], (len(links), 1)),
                             np.full(len(links), -0.75))
        self.logged["truth"] += 1

    def _on_est(self, i: int, e: EstimateMessage) -> None:
        k, x, cov = e.k, e.x, e.P
        self.current_step = max(self.current_step, k)
        base = f"world/nodes/{i}"
        p = self.metrics.pos(x)
        color = self.colors[i]
        self.buf.add(f"{base}/estimate", "point", k, p, color, -4.0)
        if i in self.last_est:
            self.buf.add(f"{base}/trail", "segment", k, [self.last_est[i], p], color, -0.75)
        self.last_est[i] = p
        if self.extent is not None:
            self.extent.estimate(i, k, x)
        half, quat = ellipsoid_of(cov, self.pos_dims)
        self.buf.add(f"{base}/ellipsoid", "ellipsoid", k, p, half, quat, color, -1.0)
        self.metrics.on_estimate(i, e)
        clutter = self.scn.has_scans and self.extent is None
        if clutter:
            self._on_diagnostics(i, k, e)
        if clutter or (self.far and self.m > 1):
            self.metrics.fuse_centre(k, i, x, cov)
        if e.counters is None:  # counters ride on every tenth estimate only
            self.logged["est"] += 1
            return
        rejected = e.counters.get("rejected") or {}
        before = self.rejected.get(i, {})
        new = {r: n - before.get(r, 0) for r, n in rejected.items() if n > before.get(r, 0)}
        if new:
            self._time(k)
            self.rec.log("events", rr.TextLog(f"node {i} rejected " + ", ".join(f"{n} {r}" for r, n in sorted(new.items())),
                                              level="WARN"))
        self.rejected[i] = dict(rejected)
        self.logged["est"] += 1

    def _on_meas(self, i: int, m: Measurement) -> None:
        """Draw a scan: a ray per bearing return, a point per Cartesian return (none for an empty scan). In
        clutter, the target's return (known from the replayed scenario) is drawn in the node's colour and the
        clutter rays in grey under ``.../clutter``."""
        if m.returns is None or len(m.returns) == 0:
            return
        k = m.k
        if self.extent is not None:
            self.extent.scan(i, k, m.returns)
            self.logged["meas"] += 1
            return
        base = f"world/nodes/{i}"
        s = self.scn.sensors[i] if m.pose is None else m.pose
        if self.moving:
            if i in self.poses:
                self.buf.add(f"world/platforms/{i}/trail", "segment", k, [self.poses[i], s], self.colors[i], -1.0)
            self.buf.add(f"world/platforms/{i}/position", "labelled", k, s, self.colors[i], -6.0, f"s{i}")
            self.poses[i] = s
        target = self._target_index(k, i)
        z = m.returns[0 if target is None else target]  # point-target scans have one return
        if self.scn.measurement == "bearing":
            ref = self.last_est.get(i)
            length = float(np.linalg.norm(ref - s)) * 1.2 if ref is not None else 1000.0
            if target is None or target >= 0:
                direction = bearing_direction(*z)
                self.buf.add(f"{base}/ray", "segment", k, [s, s + length * direction], self.colors[i], -0.75)
                if self.far and self.last_truth is not None:  # the part through the target, for the target view
                    centre = s + float(np.dot(self.last_truth - s, direction)) * direction
                    half = 2.0 * self.scene.scale * direction
                    self.buf.add(f"{base}/ray_near", "segment", k, [centre - half, centre + half], self.colors[i], -0.75)
            if self.scn.has_scans:
                clutter = [r for j, r in enumerate(m.returns) if j != target]
                strips = [[s, s + length * bearing_direction(*r)] for r in clutter]
                self.buf.add(f"{base}/clutter", "segments", k, strips, np.tile(CLUTTER_RGB, (len(strips), 1)),
                             np.full(len(strips), -0.5))
        elif self.scn.measurement == "point":
            self.buf.add(f"{base}/measurement", "point", k, z, self.colors[i], -2.5)
        self.logged["meas"] += 1

    def _target_index(self, k: int, i: int) -> int | None:
        """Where the target's return sits in node i's scan of step k (-1: missed); None without clutter."""
        if self.scn.scan_target is None or not 0 <= k < self.scn.steps:
            return None
        return int(self.scn.scan_target[0, k, i])

    def _on_diagnostics(self, i: int, k: int, e: EstimateMessage) -> None:
        """A particle filter's cloud (subsample) and the association probability of the target's return."""
        if e.samples is not None and len(e.samples):
            pts = np.stack([self.metrics.pos(x) for x in e.samples])
            faint = np.tile(np.asarray(self.colors[i]) // 2 + 60, (len(pts), 1))
            self.buf.add(f"world/nodes/{i}/particles", "cloud", k, pts, faint, np.full(len(pts), -1.5))
        self.metrics.beta(i, k, e.beta, self._target_index(k, i))

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.token.undeclare()
