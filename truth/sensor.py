"""``zentrack sensor --id S``: one sensor of its own (issue 52) as its own process.

It derives the run from the same scenario flags as the truth (``[sensor_timing]`` gives its rate, phase, clock
and latency), declares its liveliness token ``alive/sensor-<S>`` (a name, not a node id: nobody takes it for a
tracker), and waits for the run's ``ctl/start``, subscribing to it and asking for it (the truth and every tracker
answer the query, so a sensor restarted mid-run finds the run under way). Then it publishes each of its
simulated detections (:func:`~zentrack.truth.simulation.sensor_stream.sensor_stream`, or
:func:`~zentrack.truth.simulation.sensor_stream.multitarget_stream` of a many-target scenario: every target in
its view, P_D, noise and clutter) as a
:class:`~zentrack.transport.detection_messages.Detection` on ``det/<S>`` at wall time ``t0 + t_publish``, stamped
``t0 + stamp`` (the measurement time on its own clock) and ``t_pub`` read from that clock, until ``ctl/stop`` or
the run's end. A sensor that (re)starts after t0 skips what is past and resumes at the current time.

A clock jump (the soak's ``--clock-jump-every``): each SIGUSR1 steps the sensor's clock back
``--clock-jump-s``, as NTP, a GPS receiver or an operator stepping its host's clock would; the process runs on
and the clock stays back (nothing steps it forward again). Every detection measured from then on is stamped on
the stepped clock, and so is ``t_pub``; one measured before and published after keeps the stamp it was measured
with. A sensor (re)started on a host whose clock was stepped keeps the steps: ``--clock-back-s`` (the cluster
passes the sum of the steps it made to a restarted sensor).

The pure part is :class:`DetectionPlan` (which detection is due when) and :class:`SensorClock` (its own
clock, its steps included): both unit tested without Zenoh; :class:`ClockSteps` notes each SIGUSR1 for the loop.
Exit status: 0 at a stop or the run's end, 1 when no start came within ``--start-timeout``, 2 with one line for
a bad flag or a scenario without ``[sensor_timing]``.
"""
from __future__ import annotations

import argparse
import logging
import math
import signal
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import zenoh

from zentrack.common.argtypes import float_in, int_in
from zentrack.common.procs import StopFlag, freeze_heap, setup_logging
from zentrack.config.run_setup import RunSetup, resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.fusion.models import make_measurement
from zentrack.transport.codec import Message, WireError
from zentrack.transport.detection_messages import MAX_SENSORS, Detection
from zentrack.transport.keys import Keys, sensor_name
from zentrack.transport.messages import Start, Stop
from zentrack.transport.zsession import Inbox, add_zenoh_arguments, data_congestion, open_session, undeclare_all
from zentrack.truth.simulation.sensor_stream import (
    SensorStreamSpec,
    SimulatedDetection,
    multitarget_stream,
    sensor_stream,
)

log = logging.getLogger("zentrack.sensor")

#: the longest the loop waits for a message before it looks at the time again (s)
MAX_WAIT_S = 0.2
#: how far back one SIGUSR1 steps the sensor's clock by default (s): beyond a tracker's ``STALE_S`` (10 s) and
#: any latency, so that a tracker refuses every detection of the stepped clock as stale until it follows
CLOCK_JUMP_S = 30.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", type=int_in(0, MAX_SENSORS - 1, "sensor id"), required=True,
                   help="sensor index in the scenario (0-based; [sensor_timing] gives its timing)")
    add_scenario_arguments(p)
    p.add_argument("--start-timeout", type=float_in(0.1, 86400.0, "seconds"), default=120.0,
                   help="give up (exit 1) when no ctl/start came within this many seconds (default 120)")
    p.add_argument("--grace", type=float_in(0.0, 3600.0, "seconds"), default=5.0,
                   help="seconds after the run's last step to wait for ctl/stop before leaving (default 5)")
    p.add_argument("--clock-jump-s", type=float_in(0.0, 3600.0, "seconds"), default=CLOCK_JUMP_S,
                   help=f"each SIGUSR1 steps this sensor's clock back this far, and it stays back (a clock jump; "
                        f"default {CLOCK_JUMP_S:g})")
    p.add_argument("--clock-back-s", type=float_in(0.0, 86400.0, "seconds"), default=0.0,
                   help="start with the clock this far back already: the steps its host's clock took before a "
                        "restart (default 0)")
    add_zenoh_arguments(p, lease_default=1000)


@dataclass(frozen=True)
class SensorClock:
    """The sensor's own clock: ``t0 + offset_s`` at the run's start, drifting ``drift_ppm`` (``reading`` of a
    wall-clock time), less each step back it took: ``steps``, ``(wall time, seconds back)``, a step at ``-inf``
    taken before the process started (``--clock-back-s``)."""

    t0: float
    offset_s: float = 0.0
    drift_ppm: float = 0.0
    steps: tuple[tuple[float, float], ...] = ()

    def back_at(self, wall: float) -> float:
        """How far back the clock has stepped by wall time ``wall`` (s)."""
        return sum(by for at, by in self.steps if wall >= at)

    def reading(self, wall: float) -> float:
        return wall + self.offset_s + self.drift_ppm * 1e-6 * (wall - self.t0) - self.back_at(wall)

    def stepped_back(self, by: float, at: float = -math.inf) -> SensorClock:
        """This clock stepped back ``by`` seconds at wall time ``at`` (it stays back)."""
        if not (by >= 0 and math.isfinite(by)):
            raise ValueError(f"a clock steps back by a finite number of seconds >= 0, not {by!r}")
        return replace(self, steps=(*self.steps, (at, by)))


class ClockSteps:
    """The SIGUSR1s the process received, each a step of its clock back (module docstring): the handler notes
    the wall time only (no logging in a handler); the loop :meth:`take` s them and steps its clock."""

    def __init__(self, clock: Callable[[], float] = time.time) -> None:
        self.clock = clock
        self._at: deque[float] = deque()

    def install(self, sig: int = signal.SIGUSR1) -> None:
        signal.signal(sig, self.note)

    def note(self, signum: int = signal.SIGUSR1, frame: object = None) -> None:
        self._at.append(self.clock())

    def take(self) -> list[float]:
        """The wall times of the steps noted since the last call, oldest first."""
        out = []
        while self._at:
            out.append(self._at.popleft())
        return out


class DetectionPlan:
    """The detections of one sensor in the order they are published (by ``t_publish``, run time: seconds after
    t0): :meth:`skip_past` the ones already past (a restart), :meth:`due` the ones whose time has come."""

    def __init__(self, stream: list[SimulatedDetection]) -> None:
        self.pending = sorted(stream, key=lambda d: (d.t_publish, d.seq))
        self.pos = 0
        self.skipped = 0

    def skip_past(self, now: float) -> int:
        """Leave out every detection due before run time ``now`` (a sensor (re)started after t0); how many."""
        start = self.pos
        while self.pos < len(self.pending) and self.pending[self.pos].t_publish < now:
            self.pos += 1
        self.skipped += self.pos - start
        return self.pos - start

    def due(self, now: float) -> list[SimulatedDetection]:
        """The detections due by run time ``now`` not handed out yet, in publication order."""
        start = self.pos
        while self.pos < len(self.pending) and self.pending[self.pos].t_publish <= now:
            self.pos += 1
        return self.pending[start:self.pos]

    def next_time(self) -> float | None:
        """The run time the next detection is due (None: every one handed out)."""
        return self.pending[self.pos].t_publish if self.pos < len(self.pending) else None

    @property
    def done(self) -> bool:
        return self.pos >= len(self.pending)


def detection(d: SimulatedDetection, sensor: int, t0: float, pose: np.ndarray, noise_cov: np.ndarray,
              t_pub: float, back_s: float = 0.0) -> Detection:
    """``d`` on the wire: measured at ``t0 + stamp`` on the sensor's clock (less ``back_s``, how far the clock had
    stepped back when it measured), put on the wire at ``t_pub`` (same clock)."""
    return Detection(d.seq, t0 + d.stamp - back_s, sensor, d.returns, pose, noise_cov, t_pub)


def accepts(start: Start, setup: RunSetup, steps: int) -> bool:
    """Whether ``start`` is this run's: realtime, at the scenario's period, with its steps."""
    return start.mode == "realtime" and start.ts == setup.wall_period and start.steps == steps


class Sensor:
    """The session side of sensor ``sensor`` (module docstring)."""

    def __init__(self, session: zenoh.Session, keys: Keys, setup: RunSetup, spec: SensorStreamSpec, args,
                 stop: StopFlag, steps: ClockSteps | None = None) -> None:
        self.session, self.keys, self.setup, self.spec, self.args, self.stop = session, keys, setup, spec, args, stop
        self.clock_steps = steps or ClockSteps()
        self.steps = setup.run_data.steps
        stream, self.pose, self.noise_cov = simulated(setup, spec)
        self.plan = DetectionPlan(stream)
        self.inbox = Inbox(rate_per_key=50.0)
        self.pub = session.declare_publisher(keys.det(spec.sensor), congestion_control=data_congestion("realtime"),
                                             express=True)
        self.subs = [session.declare_subscriber(keys.start, self.inbox.callback("start")),
                     session.declare_subscriber(keys.stop, self.inbox.callback("stop"))]
        self.token = session.liveliness().declare_token(keys.alive(sensor_name(spec.sensor)))
        self.start: Start | None = None
        self.stopped = False
        self.published = 0

    def handle(self, msg: Message) -> None:
        try:
            if msg.tag == "start" and self.start is None:
                start = Start.decode(msg.payload)
                if accepts(start, self.setup, self.steps):
                    self.start = start
                else:
                    log.warning("sensor %d: a start of another run (%s, ts %g s, %d steps); ignored", self.spec.sensor,
                                start.mode, start.ts, start.steps)
            elif msg.tag == "stop" and self.start is not None:
                Stop.decode(msg.payload)
                self.stopped = True
        except WireError as err:
            log.warning("sensor %d: refused a %s message (%s)", self.spec.sensor, msg.tag, err)

    def wait_for_start(self) -> bool:
        """Until the run's start (asking for it too, as a sensor restarted mid-run must); False at the timeout."""
        self.session.get(self.keys.start, self.inbox.reply_callback("start"), timeout=2.0)
        end = time.time() + self.args.start_timeout
        while self.start is None and not self.stop and time.time() < end:
            msg = self.inbox.get(min(MAX_WAIT_S, max(0.0, end - time.time())))
            if msg is not None:
                self.handle(msg)
        return self.start is not None

    def run(self) -> int:
        sensor = self.spec.sensor
        if not self.wait_for_start():
            if self.stop:
                return 0
            log.error("sensor %d: no ctl/start within %.0f s", sensor, self.args.start_timeout)
            return 1
        start = self.start
        assert start is not None
        t0 = start.t0
        clock = SensorClock(t0, self.spec.offset_s, self.spec.drift_ppm)
        back = float(getattr(self.args, "clock_back_s", 0.0) or 0.0)
        if back:
            clock = clock.stepped_back(back)
            log.warning("sensor %d: its clock is %g s back already (its host's clock was stepped before this start)",
                        sensor, back)
        jump = float(getattr(self.args, "clock_jump_s", CLOCK_JUMP_S))
        skipped = self.plan.skip_past(time.time() - t0)
        if skipped:
            log.warning("sensor %d: joined the run under way; %d detection(s) already past skipped", sensor, skipped)
        log.info("sensor %d: %g Hz, phase %g s, clock offset %+g s, %d detection(s) to publish", sensor,
                 self.spec.rate_hz, self.spec.phase_s, self.spec.offset_s, len(self.plan.pending) - self.plan.pos)
        end = t0 + self.steps * start.ts + self.args.grace
        while not self.stop and not self.stopped:
            for at in self.clock_steps.take():  # SIGUSR1: the clock steps back and stays
                clock = clock.stepped_back(jump, at)
                log.warning("sensor %d: clock stepped back %g s at %.3f (%g s back in all); it stays back", sensor,
                            jump, at, clock.back_at(at))
            now = time.time()
            for d in self.plan.due(now - t0):
                wire = detection(d, sensor, t0, self.pose, self.noise_cov, clock.reading(time.time()),
                                 clock.back_at(t0 + d.t))
                self.pub.put(wire.encode())
                self.published += 1
            nxt = self.plan.next_time()
            if nxt is None and now >= end:
                log.info("sensor %d: the run is over (no ctl/stop)", sensor)
                break
            wake = end if nxt is None else t0 + nxt
            msg = self.inbox.get(min(MAX_WAIT_S, max(0.0, wake - time.time())))
            if msg is not None:
                self.handle(msg)
        log.info("sensor %d: done, %d detection(s) published, %d skipped; its clock %g s back", sensor, self.published,
                 self.plan.skipped, clock.back_at(time.time()))
        return 0

    def close(self) -> None:
        undeclare_all(self.subs, self.pub, self.token)


def simulated(setup: RunSetup, spec: SensorStreamSpec) -> tuple[list[SimulatedDetection], np.ndarray, np.ndarray]:
    """Sensor ``spec.sensor``'s scans of the run (``sensor_stream.py``: one target, in clutter if the scenario
    has it, or many), its position and the noise covariance of one of its returns."""
    s = spec.sensor
    if setup.multitarget is not None:
        data = setup.multitarget_data
        assert setup.spec is not None  # (a many-target run comes from its scenario file)
        m = make_measurement(data.kind(s)).dim
        stream = multitarget_stream(data, setup.multitarget, float(setup.spec.noise_levels()[s]), spec, setup.seed)
        return stream, np.asarray(data.sensors[s], dtype=float), np.asarray(data.noise_cov[s, :m, :m], dtype=float)
    scn = setup.scenario
    stream = sensor_stream(scn, spec, setup.seed, 0, None if setup.spec is None else setup.spec.clutter)
    return stream, np.asarray(scn.sensors[s], dtype=float), np.asarray(scn.noise_cov[s], dtype=float)


def stream_spec(setup: RunSetup, sensor: int) -> SensorStreamSpec:
    """Sensor ``sensor``'s timing; ValueError (one line) for a scenario without ``[sensor_timing]`` or an id
    outside its sensors."""
    streams = setup.sensor_streams()
    if not streams:
        raise ValueError(f"{setup.source}: no [sensor_timing] section: its truth measures every step, so it has no "
                         "sensors of their own to run")
    if not 0 <= sensor < len(streams):
        raise ValueError(f"sensor id {sensor} is outside the scenario's sensors 0..{len(streams) - 1}")
    return streams[sensor]


def run(args: argparse.Namespace) -> int:
    steps = ClockSteps()
    steps.install()  # first: a SIGUSR1 during the start-up steps the clock, never ends the process
    setup_logging()
    setup = resolve_setup(args)
    spec = stream_spec(setup, args.id)
    stop = StopFlag()
    with open_session(args, sensor_name(args.id)) as (session, keys):
        sensor = Sensor(session, keys, setup, spec, args, stop, steps)
        freeze_heap()
        try:
            return sensor.run()
        finally:
            sensor.close()
            time.sleep(0.05)  # let the last detection leave before the session closes
