"""The single-target payload part of the viewer (:class:`~zentrack.viewer.payload.Payload`): the truth, every
node's estimate and scan of one target drawn as Rerun entities (the core, timelines and events:
:mod:`zentrack.viewer.core`).

- ``world/target`` a ``Transform3D`` (translation: the true position) per step: the frame the target view
  is drawn in (:mod:`zentrack.viewer.single_target_layout`);
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
- ``events``: newly rejected messages, besides the core's joins and departures;
- ``metrics/...`` and ``world/fused``: :mod:`zentrack.viewer.metrics`;
- with sensors of their own (``[sensor_timing]``: ``det/<s>`` instead of ``meas/<i>``): each detection at its own
  measurement time, ``world/sensors/<s>/ray``, and each sensor's latency (:mod:`zentrack.viewer.detections`).

Markers and lines are sized in UI points (a fixed size on screen), so the target view, a few metres across,
and the sensor layout, up to hundreds of km, both show them.
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.config.run_setup import RunSetup
from zentrack.transport.codec import MAX_ROUNDS, Message, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Truth
from zentrack.viewer.detections import SensorDetections
from zentrack.viewer.extent_view import ExtentView
from zentrack.viewer.geometry import bearing_direction
from zentrack.viewer.layout import TRUTH_RGB
from zentrack.viewer.metrics import Metrics, ellipsoid_of, round_message_dims
from zentrack.viewer.payload import Canvas
from zentrack.viewer.single_target_layout import CLUTTER_RGB, TARGET_FRAME, blueprint, describe


def single_target(setup: RunSetup, rec: rr.RecordingStream) -> tuple[Canvas, SingleTarget]:
    """The canvas and the part of a single-target run (``setup`` a ``RunSetup``) recording to ``rec``."""
    canvas = Canvas(rec, setup.scenario.ts, setup.scenario.nodes,
                    SingleTarget.COUNTS + (("det",) if setup.sensor_timing is not None else ()))
    return canvas, SingleTarget(setup, canvas)


class SingleTarget:
    """Draws a single-target run (module docstring) on ``canvas``."""

    #: what :attr:`Canvas.logged` counts
    COUNTS = ("est", "truth", "meas")

    def __init__(self, setup: RunSetup, canvas: Canvas) -> None:
        self.canvas = canvas
        self.scn = setup.scenario
        info = round_message_dims(setup)  # None: one round per step, no disagreement to draw
        timing = setup.sensor_timing
        self.scene = describe(self.scn, rounds=info is not None, sensors=0 if timing is None else timing.sensors)
        self.round_dims: dict[str, int] | None = None if info is None else info[0]
        self.last_est: dict[int, np.ndarray] = {}
        self.last_truth: np.ndarray | None = None
        self.rejected: dict[int, dict] = {}
        self.moving = self.scn.sensor_track is not None
        self.far = self.scene.family == "satellites"
        self.poses: dict[int, np.ndarray] = {}  # the latest pose of each moving sensor
        m = self.scn.nodes
        self.edges = [(i, int(j)) for i in range(m) for j in np.flatnonzero(self.scn.adjacency[i]) if j > i]
        self.extent = ExtentView(self.scn, canvas.buf, canvas.colors) if self.scn.plant == "eot" else None
        #: the state components drawn as a position (an extended object's centre is 2-D, on the surface)
        self.pos_dims = 2 if self.extent is not None else min(3, self.scn.truth.shape[-1])
        self.metrics = Metrics(self.scn, canvas.buf, canvas.colors, self.pos_dims, None if info is None else info[1],
                               self.extent)
        #: sensors of their own: their detections, each at its own time (None: the truth measures, ``meas/<i>``)
        dims = [int(self.scn.measurements.shape[-1])] * (0 if timing is None else timing.sensors)
        self.detections = None if timing is None else SensorDetections(
            self.scn.ts, self.scn.steps, [self.scn.measurement] * len(dims), dims, timing, canvas,
            lambda: self.last_truth)

    def topics(self, keys: Keys) -> dict[str, str]:
        rounds = {} if self.round_dims is None else {"prior": keys.prior("*")}
        scans = {"meas": keys.meas("*")} if self.detections is None else self.detections.topics(keys)
        return {"est": keys.est("*"), **scans, **rounds}

    def blueprint(self) -> rrb.Blueprint:
        return blueprint(self.scene)

    def summary(self) -> str:
        return f"{self.scn.nodes} nodes, {self.scene.family} scenario (target view {2 * self.scene.scale:.0f} m across)"

    def log_static(self) -> None:
        scn = self.scn
        if self.extent is not None:
            self.extent.log_static(self.canvas.rec)
        elif scn.truth.shape[-1] >= 3 and scn.sensor_track is None:
            self.canvas.log_sensors(scn.sensors)
        self.canvas.log_key(self.scene.key)
        self.metrics.log_static(self.canvas.rec)
        if self.detections is not None:
            self.detections.log_static(self.canvas.rec)

    def handle(self, msg: Message, node: int | None) -> None:
        last = self.scn.steps - 1  # a step beyond the run would stretch the timeline (or break Rerun's)
        if msg.tag == "truth":
            truth = Truth.decode(msg.payload)
            self._check_state(truth.k, truth.x)
            self._on_truth(truth)
        elif self.detections is not None and self.detections.handle(msg):  # det/<s> (any key: checked), start
            return
        elif node is None:  # not one of the run's nodes: not drawn
            return
        elif msg.tag == "est":
            est = EstimateMessage.decode(msg.payload, node)
            self._check_state(est.k, est.x)
            self._on_est(node, est)
        elif msg.tag == "meas":
            self._on_meas(node, Measurement.decode(msg.payload, node, self.scn.measurements.shape[-1], 0, last))
        elif msg.tag == "prior" and self.round_dims is not None:  # the last is for step `steps`
            self.metrics.on_round(node, RoundMessage.decode(msg.payload, node, self.round_dims, 0, last + 1, MAX_ROUNDS))

    def _check_state(self, k: int, x: np.ndarray) -> None:
        """A true state or estimate is drawn and scored against the scenario's: one of its steps, its dimension."""
        if k >= self.scn.steps:
            raise WireError("future", f"step {k} beyond the run's {self.scn.steps}")
        if x.shape[0] != self.scn.truth.shape[-1]:
            raise WireError("shape", f"x: dimension {x.shape[0]}, the scenario's is {self.scn.truth.shape[-1]}")

    def _on_truth(self, t: Truth) -> None:
        k, x, buf = t.k, t.x, self.canvas.buf
        self.canvas.reached(k)
        p = self.metrics.pos(x)
        buf.add(TARGET_FRAME, "translation", k, p)
        buf.add("world/truth/position", "labelled", k, p, TRUTH_RGB, -7.0, "truth")
        if self.last_truth is not None:
            buf.add("world/truth/path", "segment", k, [self.last_truth, p], TRUTH_RGB, -1.5)
        self.last_truth = p
        if self.extent is not None:
            self.extent.truth(k, x)
        self.metrics.on_truth(k, x)
        if self.moving and len(self.poses) >= 2:
            links = [[self.poses[i], self.poses[j]] for i, j in self.edges if i in self.poses and j in self.poses]
            if links:
                buf.add("world/graph", "segments", k, links, np.tile([90, 90, 140], (len(links), 1)),
                        np.full(len(links), -0.75))
        self.canvas.logged["truth"] += 1

    def _on_est(self, i: int, e: EstimateMessage) -> None:
        k, x, cov, buf = e.k, e.x, e.P, self.canvas.buf
        self.canvas.reached(k)
        base = f"world/nodes/{i}"
        p = self.metrics.pos(x)
        color = self.canvas.colors[i]
        buf.add(f"{base}/estimate", "point", k, p, color, -4.0)
        if i in self.last_est:
            buf.add(f"{base}/trail", "segment", k, [self.last_est[i], p], color, -0.75)
        self.last_est[i] = p
        if self.extent is not None:
            self.extent.estimate(i, k, x)
        half, quat = ellipsoid_of(cov, self.pos_dims)
        buf.add(f"{base}/ellipsoid", "ellipsoid", k, p, half, quat, color, -1.0)
        self.metrics.on_estimate(i, e)
        clutter = self.scn.has_scans and self.extent is None
        if clutter:
            self._on_diagnostics(i, k, e)
        if clutter or (self.far and self.scn.nodes > 1):
            self.metrics.fuse_centre(k, i, x, cov)
        if e.counters is not None:  # counters ride on every tenth estimate only
            self._rejections(i, k, e.counters.get("rejected") or {})
        self.canvas.logged["est"] += 1

    def _rejections(self, i: int, k: int, rejected: dict) -> None:
        """An event for the messages node i rejected since its last counters, by reason."""
        before = self.rejected.get(i, {})
        new = {r: n - before.get(r, 0) for r, n in rejected.items() if n > before.get(r, 0)}
        if new:
            self.canvas.event(k, f"node {i} rejected " + ", ".join(f"{n} {r}" for r, n in sorted(new.items())), "WARN")
        self.rejected[i] = dict(rejected)

    def _on_meas(self, i: int, m: Measurement) -> None:
        """Draw a scan: a ray per bearing return, a point per Cartesian return (none for an empty scan). In
        clutter, the target's return (known from the replayed scenario) is drawn in the node's colour and the
        clutter rays in grey under ``.../clutter``."""
        if m.returns is None or len(m.returns) == 0:
            return
        k, buf, color = m.k, self.canvas.buf, self.canvas.colors[i]
        if self.extent is not None:
            self.extent.scan(i, k, m.returns)
            self.canvas.logged["meas"] += 1
            return
        base = f"world/nodes/{i}"
        s = self.scn.sensors[i] if m.pose is None else m.pose
        if self.moving:
            if i in self.poses:
                buf.add(f"world/platforms/{i}/trail", "segment", k, [self.poses[i], s], color, -1.0)
            buf.add(f"world/platforms/{i}/position", "labelled", k, s, color, -6.0, f"s{i}")
            self.poses[i] = s
        target = self._target_index(k, i)
        z = m.returns[0 if target is None else target]  # point-target scans have one return
        if self.scn.measurement == "bearing":
            ref = self.last_est.get(i)
            length = float(np.linalg.norm(ref - s)) * 1.2 if ref is not None else 1000.0
            if target is None or target >= 0:
                direction = bearing_direction(*z)
                buf.add(f"{base}/ray", "segment", k, [s, s + length * direction], color, -0.75)
                if self.far and self.last_truth is not None:  # the part through the target, for the target view
                    centre = s + float(np.dot(self.last_truth - s, direction)) * direction
                    half = 2.0 * self.scene.scale * direction
                    buf.add(f"{base}/ray_near", "segment", k, [centre - half, centre + half], color, -0.75)
            if self.scn.has_scans:
                clutter = [r for j, r in enumerate(m.returns) if j != target]
                strips = [[s, s + length * bearing_direction(*r)] for r in clutter]
                buf.add(f"{base}/clutter", "segments", k, strips, np.tile(CLUTTER_RGB, (len(strips), 1)),
                        np.full(len(strips), -0.5))
        elif self.scn.measurement == "point":
            buf.add(f"{base}/measurement", "point", k, z, color, -2.5)
        self.canvas.logged["meas"] += 1

    def _target_index(self, k: int, i: int) -> int | None:
        """Where the target's return sits in node i's scan of step k (-1: missed); None without clutter."""
        if self.scn.scan_target is None or not 0 <= k < self.scn.steps:
            return None
        return int(self.scn.scan_target[0, k, i])

    def _on_diagnostics(self, i: int, k: int, e: EstimateMessage) -> None:
        """A particle filter's cloud (subsample) and the association probability of the target's return."""
        if e.samples is not None and len(e.samples):
            pts = np.stack([self.metrics.pos(x) for x in e.samples])
            faint = np.tile(np.asarray(self.canvas.colors[i]) // 2 + 60, (len(pts), 1))
            self.canvas.buf.add(f"world/nodes/{i}/particles", "cloud", k, pts, faint, np.full(len(pts), -1.5))
        self.metrics.beta(i, k, e.beta, self._target_index(k, i))
