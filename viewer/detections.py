"""Sensors of their own (issue 52) in the viewer: each sensor's detections (``det/<s>``) drawn at their own
measurement time, and each sensor's latency. The single-target and many-target parts
(:class:`~zentrack.viewer.single_target.SingleTarget`, :class:`~zentrack.viewer.multi_target.MultiTarget`) hold one
:class:`SensorDetections` when the run has a ``[sensor_timing]`` section and hand it the ``det`` and ``start``
messages.

A detection's stamp ``t`` is its measurement time on the **sensor's own clock**. The viewer is an evaluator (it
reads the truth), so it maps the stamp to the run's clock with the sensor's *simulated* offset and drift
(``stamp = t0 + τ + offset_s + drift_ppm·1e-6·τ``, :mod:`zentrack.truth.simulation.sensor_stream`), τ the run
time: seconds after ``t0``, the run's start (``ctl/start``). Each detection is logged

- on the ``time`` timeline at τ, its own time (not a step's sample time), and on ``step`` at the step whose window
  takes it (a tracker's step k takes the detections measured in ``[t0 + (k-1)·ts, t0 + k·ts)``: k = ⌊τ/ts⌋ + 1);
- as ``world/sensors/<s>/ray``, the bearing line of sight from the sensor's pose (or ``.../measurement``, a
  point), in the colour of the tracker that takes sensor s (by default tracker s), so that several sensors
  feeding one tracker are told apart by their entities; with many targets (``every_return``) every return of the
  scan, targets' and clutter alike, as ``world/sensors/<s>/returns`` (points, or ``.../rays`` of
  :data:`RAY_M`), an empty scan drawn empty (it clears the sensor's last one);
- with ``metrics/sensor_latency_ms/<s>``: arrival at the viewer less the measurement time on the run's clock, in
  ms: the sensor's own latency plus the network path to the viewer (like the trackers' step latency);
- and ``metrics/out_of_order/<s>``: the share of sensor s's detections so far that arrived after one it measured
  later.

Refused (:class:`~zentrack.transport.codec.WireError`, counted by the core under ``bad``): a detection that does
not decode (``Detection.decode`` checks every field: a forged sender, a NaN time, a bad covariance ...), one on
the key of no sensor of the run, one measured outside the run; a ``ctl/start`` of another run (period or steps).
Detections that come before the run's start (no t0 yet) are held, up to :data:`HELD`, and drawn once it comes.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np
import rerun as rr

from zentrack.transport.codec import Message, WireError
from zentrack.transport.detection_messages import Detection
from zentrack.transport.keys import Keys, node_id
from zentrack.transport.messages import Start
from zentrack.viewer.geometry import bearing_direction
from zentrack.viewer.payload import Canvas

#: detections held until the run's start gives t0 (the oldest are dropped beyond)
HELD = 10_000
#: the length of a bearing return's ray with many targets (no one target whose range to reach past)
RAY_M = 2000.0
#: a many-target scan's returns: points' size and rays' width (UI points)
RETURN_R, RETURN_RAY_R = -2.0, -0.5


class SensorDetections:
    """Draws the detections of a run's sensors of their own (module docstring) on ``canvas`` and counts them
    (``det``). ``ts``, ``steps``: the run's; ``kinds``, ``dims``: each sensor's measurement kind and dimension;
    ``timing``: the run's :class:`~zentrack.config.scenario_sensor_timing.SensorTiming`; ``target``: the latest
    true position (None before the first), which a bearing ray reaches past; ``every_return``: draw every return
    of a scan (many targets), not its first."""

    def __init__(self, ts: float, steps: int, kinds: Sequence[str], dims: Sequence[int], timing, canvas: Canvas,
                 target: Callable[[], np.ndarray | None], every_return: bool = False) -> None:
        self.timing, self.canvas, self.buf, self.target = timing, canvas, canvas.buf, target
        self.kinds, self.dims, self.every_return = list(kinds), list(dims), every_return
        colors = canvas.colors
        self.ts, self.steps = float(ts), int(steps)
        #: each sensor's colour: its first tracker's (a sensor no tracker takes: the node of its number's)
        self.colors = [next((colors[i] for i, row in enumerate(timing.takes) if s in row), colors[s % len(colors)])
                       for s in range(timing.sensors)]
        self.t0: float | None = None
        self.held: deque[tuple[Detection, float]] = deque(maxlen=HELD)
        self.latest: dict[int, float] = {}  # each sensor's latest measurement time so far (run time)
        self.count: dict[int, int] = {}
        self.late: dict[int, int] = {}  # ... and how many of its detections came after one measured later

    def log_static(self, rec: rr.RecordingStream) -> None:
        """Each sensor's series named ``sensor <s>`` in its colour."""
        for s, color in enumerate(self.colors):
            for name in ("sensor_latency_ms", "out_of_order"):
                rec.log(f"metrics/{name}/{s}", rr.SeriesLines(colors=[color], names=[f"sensor {s}"]), static=True)

    @staticmethod
    def topics(keys: Keys) -> dict[str, str]:
        return {"det": keys.det("*"), "start": keys.start}

    def handle(self, msg: Message) -> bool:
        """Draw a ``det`` message or take the run's start from a ``start`` one (True: it was one of these).
        WireError for one refused."""
        if msg.tag == "start":
            self.on_start(Start.decode(msg.payload))
        elif msg.tag == "det":
            sensor = node_id(msg.key.rsplit("/", 1)[-1])
            if sensor is None or sensor >= self.timing.sensors:
                raise WireError("sender_mismatch", f"{msg.key}: not the key of one of the run's "
                                                   f"{self.timing.sensors} sensors")
            det = Detection.decode(msg.payload, sensor, self.dims[sensor])
            if self.t0 is None:
                self.held.append((det, msg.t_recv))
            else:
                self.draw(det, msg.t_recv)
        else:
            return False
        return True

    def on_start(self, start: Start) -> None:
        """The run's start: t0 (the first start taken; the truth sends it again when a tracker joins)."""
        if abs(start.ts - self.ts) > 1e-9 or start.steps != self.steps:
            raise WireError("schema", f"a start of another run (ts {start.ts:g} s, {start.steps} steps; this run's "
                                      f"{self.ts:g} s, {self.steps})")
        if self.t0 is None:
            self.t0 = start.t0
            while self.held:  # (one of them refused is counted as the core counts a message refused)
                try:
                    self.draw(*self.held.popleft())
                except WireError:
                    self.canvas.logged["bad"] += 1

    def run_time(self, det: Detection) -> float:
        """The detection's measurement time on the run's clock, seconds after t0 (its sensor's simulated clock
        taken off), to the microsecond (an epoch stamp in a double is good to a quarter of one)."""
        assert self.t0 is not None
        spec = self.timing.stream(det.sensor)
        return round((det.t_meas - self.t0 - spec.offset_s) / (1.0 + spec.drift_ppm * 1e-6), 6)

    def step_of(self, tau: float) -> int:
        """The step whose window ``[(k-1)·ts, k·ts)`` holds run time ``tau`` (within the run's steps; a time on a
        window's edge, to a millionth of a step, starts the next window: 0.3 / 0.1 is 2.9999999999999996)."""
        return min(max(math.floor(round(tau / self.ts, 6)) + 1, 0), self.steps - 1)

    def draw(self, det: Detection, t_recv: float) -> None:
        """One detection at its own time (module docstring); WireError for one measured outside the run."""
        tau = self.run_time(det)
        if not -self.ts <= tau <= self.steps * self.ts:
            raise WireError("range", f"sensor {det.sensor}: measured {tau:.3f} s after the start, outside the run "
                                     f"(0 to {self.steps * self.ts:g} s)")
        s, k, buf, color = det.sensor, self.step_of(tau), self.buf, self.colors[det.sensor]
        assert self.t0 is not None
        buf.add(f"metrics/sensor_latency_ms/{s}", "scalar", k, (t_recv - (self.t0 + tau)) * 1e3, at=tau)
        late = tau < self.latest.get(s, -math.inf)
        self.latest[s] = max(tau, self.latest.get(s, -math.inf))
        self.count[s] = self.count.get(s, 0) + 1
        self.late[s] = self.late.get(s, 0) + late
        buf.add(f"metrics/out_of_order/{s}", "scalar", k, self.late[s] / self.count[s], at=tau)
        self.canvas.logged["det"] += 1
        if self.every_return:
            self.draw_scan(det, k, tau, color)
            return
        if len(det.returns) == 0:  # looked, saw nothing
            return
        pose, z = det.pose, det.returns[0]
        if self.kinds[s] == "bearing":
            target = self.target()
            length = 1.2 * float(np.linalg.norm(target - pose)) if target is not None else 1000.0
            buf.add(f"world/sensors/{s}/ray", "segment", k, [pose, pose + length * bearing_direction(*z)], color,
                    -0.75, at=tau)
        elif self.kinds[s] == "point":
            buf.add(f"world/sensors/{s}/measurement", "point", k, z, color, -2.5, at=tau)

    def draw_scan(self, det: Detection, k: int, tau: float, color) -> None:
        """Every return of a many-target scan at its time: points, or bearing rays of :data:`RAY_M`."""
        s, n, buf = det.sensor, len(det.returns), self.buf
        colors = np.tile(np.asarray(color, dtype=np.uint8), (n, 1))
        if self.kinds[s] == "bearing":
            rays = [[det.pose, det.pose + RAY_M * bearing_direction(*z)] for z in det.returns]
            buf.add(f"world/sensors/{s}/rays", "segments", k, rays, colors.reshape(-1, 3), np.full(n, RETURN_RAY_R),
                    at=tau)
        elif self.kinds[s] == "point":
            buf.add(f"world/sensors/{s}/returns", "cloud", k, np.reshape(det.returns, (-1, 3)), colors.reshape(-1, 3),
                    np.full(n, RETURN_R), at=tau)
