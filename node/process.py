"""``zentrack node``: one tracker as its own OS process, moving bytes and time around :class:`NodeSchedule` with
its payload: single-target diffusion (``node/diffusion/``) or many-target track lists (``node/track_lists/``).

The schedule (``node/schedule.py``) decides what to do with every message and when; this module owns the
Zenoh session: subscriptions feed one inbox, the schedule's ``send`` goes to the publishers.

A lost truth is searched for, not given up on: when, during a realtime run, no measurement message has
arrived for ``--reconnect-s`` or the truth's liveliness token has been gone that long (a stalled truth whose
lease check closed its links, a restarted truth, a restarted router), the node closes its session and opens a
new one, re-declaring every subscription, with a doubling back-off; only after ``--truth-timeout`` without the
truth does the node stop (when: ``node/link_watch.py``).
A tracker with sensors of its own (``[sensor_timing]``) does not need the truth to track: while its detections
come, its links work, and the truth's absence is no reason to re-open them (each re-open costs it the detections
of a moment) nor to stop; a run whose truth has gone ends for it at the run's end (``node/run_control.py``).

Time is the run's: every message's receive time and every deadline are on :class:`~zentrack.node.clock_offset.RunClock`,
the local clock corrected by the offset estimated from the truth's measurements (``node/clock_offset.py``).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from zentrack.common.argtypes import float_in
from zentrack.common.atomic import EXIT_WRITE_FAILED, write_text_atomically
from zentrack.common.procs import StopFlag, freeze_heap, release_free_memory, setup_logging, without_openssl
from zentrack.config.node_config import NodeConfig
from zentrack.node.clock_offset import RunClock, StartGate
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.link_watch import LinkWatch, Watch
from zentrack.node.schedule import NodeSchedule
from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import (
    Inbox,
    add_zenoh_arguments,
    data_congestion,
    describe_source,
    open_zenoh,
    undeclare_all,
    zenoh_config,
)

log = logging.getLogger("zentrack.node")

#: how often the loop checks whether the truth has gone missing (``--reconnect-s`` is at least 0.1 s)
WATCH_PERIOD_S = 0.05


def add_arguments(p: argparse.ArgumentParser) -> None:
    """A tracker's own flags (`zentrack node` adds the scenario's before them: :mod:`zentrack.cli.node_command`)."""
    p.add_argument("--id", type=int, required=True, help="node index in the scenario (0-based)")
    p.add_argument("--node-config", metavar="FILE",
                   help="this node's own configuration slice (JSON, as `zentrack run` writes to <out>/config/); "
                        "without it the node slices --scenario/--scenario-file itself")
    p.add_argument("--out", metavar="DIR", help="write node-<id>.json (final counters) here on exit")
    p.add_argument("--reconnect-s", type=float_in(0.1, 3600.0, "seconds"), default=2.0,
                   help="re-open the Zenoh session when the truth has been gone this long (default 2)")
    p.add_argument("--truth-timeout", type=float_in(0.2, 86400.0, "seconds"), default=30.0,
                   help="stop when the truth has been gone this long after the start (default 30)")
    add_zenoh_arguments(p, lease_default=1000)


class NodeProcess:
    """The session side of one tracker: (re)opens Zenoh, feeds the schedule, publishes what it sends."""

    def __init__(self, args: argparse.Namespace, schedule: NodeSchedule[Any], keys: Keys, stop: StopFlag,
                 clock: RunClock | None = None) -> None:
        self.args, self.schedule, self.keys, self.stop = args, schedule, keys, stop
        # the schedule's clock too (by default the schedule's own, uncorrected): every time here is the run's
        self.clock = clock if clock is not None else RunClock(schedule.id, schedule.clock)
        self.dropped: dict[str, int] = {}  # messages the inboxes' flood guard dropped, over every session
        self._drops_seen = 0
        self._drops_changed: float | None = None  # when the drop count last changed (None: settled)
        schedule.ctx.dropped = self.dropped
        self.inbox = self.new_inbox()
        self.session: zenoh.Session | None = None
        self.reconnects = 0
        self._last_open = 0.0
        self.watch = LinkWatch(args.reconnect_s, args.truth_timeout)
        self.last_meas = self.clock()  # the truth sends every node a measurement message every step
        self.last_det = self.clock()  # sensors of their own: when the last detection came
        self.closers: list[threading.Thread] = []
        self.start_gate = StartGate(self.clock)
        self._next_watch = 0.0  # when the loop next checks for a missing truth
        self._congestion = data_congestion(schedule.mode)  # realtime DROP: a cut link holds up nothing

    def open(self, connect_timeout_ms: int | None = None) -> None:
        conf = zenoh_config(self.args, f"node-{self.schedule.id}")
        if connect_timeout_ms is not None and self.args.connect:
            conf.insert_json5("connect/timeout_ms", str(connect_timeout_ms))
        session = open_zenoh(conf, describe_source(self.args.zenoh_config, self.args.listen, self.args.connect))
        self.session, self.inbox = session, self.new_inbox()  # a fresh inbox: nothing of an old session leaks into it
        s, keys, node = session, self.keys, self.schedule.id
        self.pubs = {channel: s.declare_publisher(key, congestion_control=self._congestion, express=express)
                     for channel, (key, express) in self.schedule.publications().items()}
        self.subs = [
            *[s.declare_subscriber(key, self.inbox.callback(tag)) for key, tag in self.schedule.subscriptions()],
            s.declare_subscriber(keys.start, self.inbox.callback("start")),
            s.declare_subscriber(keys.stop, self.inbox.callback("stop")),
            s.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(), history=True),
        ]
        self.queryable = s.declare_queryable(keys.start, self._answer_start)
        self.token = s.liveliness().declare_token(keys.alive(node))
        self._last_open = self.clock()
        if self.schedule.t0 is None:  # joined late: ask the truth for the start instead of waiting for a re-send
            s.get(keys.start, self.inbox.reply_callback("start"), timeout=2.0)

    def after_flood(self, now: float) -> None:
        """Once the flood guard has dropped nothing for a second after dropping something, give the memory
        the flood's buffers took back to the system."""
        if not self.dropped:  # nothing ever dropped (every wake-up of a healthy run)
            return
        total = sum(self.dropped.values())
        if total != self._drops_seen:
            self._drops_seen, self._drops_changed = total, now
        elif self._drops_changed is not None and now - self._drops_changed > 1.0:
            self._drops_changed = None
            released = release_free_memory()
            log.warning("node %d: the flood guard dropped %d message(s) so far (%s); free memory released: %s",
                        self.schedule.id, total, self.dropped, released)

    def new_inbox(self) -> Inbox:
        """An inbox whose flood guard lets through 4x the most a neighbour sends per key (a prior per round
        and step, at the run's wall-clock period once the start is known), plus 20 messages per second."""
        if self.schedule.mode == "lockstep":  # steps as fast as the slowest node: no rate to hold it to, and a
            return Inbox(rate_per_key=1e9, max_queued=100_000, dropped=self.dropped)  # dropped message would stall
        return Inbox(rate_per_key=self.schedule.flood_rate(), dropped=self.dropped)  # the run

    def close_in_background(self) -> None:
        """Close the session on another thread: closing waits on every link, and a cut one (the very reason
        we re-open) holds it until the link is back; a reconnect must not wait for that."""
        if self.session is None:
            return
        closer = threading.Thread(target=self.close_quietly, args=(self.session, self.subs, self.queryable,
                                                                   self.token, list(self.pubs.values())), daemon=True)
        self.session = None
        closer.start()
        self.closers.append(closer)

    @staticmethod
    def close_quietly(session: zenoh.Session, *entities) -> None:
        try:
            undeclare_all(*entities)
        except Exception as exc:  # noqa: BLE001 - a session torn down under a cut link may refuse; it is closing
            log.debug("undeclare on a closing session: %s", exc)
        finally:
            session.close()

    def join_closers(self, timeout: float) -> bool:
        """Wait up to ``timeout`` for sessions closing in the background; False if one is still closing."""
        end = time.time() + timeout
        for closer in self.closers:
            closer.join(max(0.0, end - time.time()))
        return not any(c.is_alive() for c in self.closers)

    def _answer_start(self, query: zenoh.Query) -> None:
        """A restarted truth asks for the run's start: answer with truth's own ctl/start as we received it."""
        payload = self.schedule.start_payload
        if payload is not None:
            query.reply(self.keys.start, payload)

    def send(self, channel: str, payload: bytes) -> None:
        if self.session is not None:
            self.pubs[channel].put(payload)

    def reopen(self, why: str) -> None:
        """A new session: every link, subscription and token anew (the live set is rebuilt from history)."""
        self.reconnects += 1
        log.warning("node %d: %s; re-opening the Zenoh session (#%d)", self.schedule.id, why, self.reconnects)
        self.close_in_background()
        self.schedule.live.clear()
        self.try_open()

    def try_open(self) -> bool:
        """One attempt at a new session that gives up after 0.5 s when its router is still down (a restarting
        router): the loop keeps the schedule going meanwhile and tries again."""
        self._last_open = self.clock()
        try:
            self.open(connect_timeout_ms=500)
            return True
        except ValueError as exc:
            log.warning("node %d: %s; trying again", self.schedule.id, exc)
            self.session = None
            return False

    def truth_silence(self, now: float) -> tuple[float, str] | None:
        """How long the truth has been missing, and how we know; None while it is there (or not expected)."""
        sched = self.schedule
        if sched.t0 is None:
            return None
        period = sched.payload.detection_period_s()  # sensors of their own (None: the truth's measurements)
        if sched.truth_gone_since is not None:
            gone = now - sched.truth_gone_since
            if period is None:
                return gone, "the truth's liveliness token is gone"
            # sensors of their own: while detections come the links work (the truth is not needed to track); past
            # the fastest sensor's period without one, they may be lost too (a router restarted, a cut link)
            quiet = now - self.last_det - period
            return (min(gone, quiet), "the truth's liveliness token is gone and no detection came") if quiet > 0 else None
        running = sched.mode == "realtime" and sched.t0 + sched.ts < now < sched.t0 + (sched.steps or 0) * sched.ts
        # (sensors of their own send when they send, and a dead one is no missing truth: its liveliness only)
        if running and period is None:
            # a measurement message comes every period: only the time past the expected one is silence (with
            # a 10 s period, 2 s without one is normal)
            overdue = now - self.last_meas - sched.ts
            return (overdue, "no measurement message from the truth") if overdue > 0 else None
        return None

    def deliver(self, msg: Message) -> None:
        """One received message to the schedule, on the run's time (a measurement is a clock sample first); a start
        of a run under way waits for the clock (:class:`~zentrack.node.clock_offset.StartGate`)."""
        sched = self.schedule
        self.clock.receive(msg, sched.measurement_dim, sched.t0, sched.ts)
        if msg.tag == "start" and self.start_gate.hold(msg, sched.t0 is not None, sched.mode == "realtime"):
            return
        for held in self.start_gate.due():
            self.hand_over(held)
        self.hand_over(msg)

    def hand_over(self, msg: Message) -> None:
        if msg.tag == "meas":
            self.last_meas = msg.t_recv
        elif msg.tag == "det":
            self.last_det = msg.t_recv
        self.schedule.handle(msg)
        if msg.tag == "start":  # the run's wall-clock period is known now
            self.inbox.set_rate(self.new_inbox().rate_per_key)

    def run(self) -> None:
        sched, clock = self.schedule, self.clock
        while not self.stop:
            msg = self.inbox.get(sched.timeout())
            if msg is not None:
                self.deliver(msg)
            for held in self.start_gate.due():  # held for the clock's first sample long enough
                self.hand_over(held)
            sched.advance()
            if sched.done():
                return
            now = clock()  # the schedule's clock: liveliness times are taken with it too
            self.after_flood(now)
            if self.session is None:
                if now - self._last_open > 0.5:
                    self.try_open()
                continue
            if now < self._next_watch:  # the truth watch works in tenths of seconds: not at every wake-up
                continue
            self._next_watch = now + WATCH_PERIOD_S
            silence = self.truth_silence(now)
            action = self.watch.decide(now, None if silence is None else silence[0], self._last_open)
            if action is Watch.STOP and silence is not None:
                log.warning("node %d: %s for %.0f s; stopping", sched.id, silence[1], silence[0])
                return
            if action is Watch.REOPEN and silence is not None:
                self.reopen(f"{silence[1]} for {silence[0]:.1f} s")


def node_config(args: argparse.Namespace) -> NodeConfig:
    """This node's slice: the ``--node-config`` file the orchestrator wrote. A tracker reads nothing else: the
    command line (:mod:`zentrack.cli.node_command`) cuts a slice from ``--scenario``/``--scenario-file`` itself
    and hands it to :func:`run`, so no scenario module is imported from this package."""
    if not args.node_config:
        raise ValueError("a tracker needs its slice: --node-config FILE (or --scenario through `zentrack node`)")
    cfg = NodeConfig.load(args.node_config)
    if cfg.node != args.id:
        raise ValueError(f"{args.node_config}: is node {cfg.node}'s configuration, not node {args.id}'s")
    return cfg


def run(args: argparse.Namespace, slice_of: Callable[[argparse.Namespace], NodeConfig] = node_config) -> int:
    """Run one tracker until the run stops; ``slice_of(args)`` gives its slice (by default the --node-config
    file), called after logging is set up and OpenSSL kept out."""
    setup_logging()
    without_openssl()  # before the tracker's filter imports numpy.random
    if args.truth_timeout <= args.reconnect_s:
        raise ValueError(f"--truth-timeout ({args.truth_timeout:g} s) must exceed --reconnect-s ({args.reconnect_s:g} s)")
    cfg = slice_of(args)
    stop = StopFlag()
    keys = Keys(args.run)
    clock = RunClock(args.id, sampling=cfg.mode == "realtime")
    # a single-target tracker never loads the multi-target modules (SciPy's assignment solver): each payload is
    # imported by its constructor
    schedule: NodeSchedule[Any]
    if cfg.multitarget is not None:  # a many-target run: a multi-target tracker and track lists
        schedule = NodeSchedule.track_lists(keys, cfg, clock=clock, send=lambda ch, data: None, incarnation=os.getpid())
    else:
        schedule = NodeSchedule.diffusion(keys, cfg, Tracker(cfg), clock=clock, send=lambda ch, data: None,
                                          incarnation=os.getpid())
    proc = NodeProcess(args, schedule, keys, stop, clock)
    schedule.ctx.send = proc.send  # the schedule publishes through the session side
    # the wire's and the gate's checks use numpy's LAPACK (loaded with numpy) and the gate's chi-square bounds
    # come with the slice (NodeConfig.gate_thresholds): no SciPy module is loaded at the first step
    proc.open()
    log.info("node %d up: run %s, %s %s, filter %s, fusion %s, neighbours %s", args.id, keys.run, cfg.mode, cfg.role,
             cfg.filter, cfg.fusion, sorted(cfg.neighbours))
    freeze_heap()
    status = 0
    try:
        proc.run()
    finally:
        # closing waits on every link, and at the end of a killed cluster (the orchestrator gone, its router and
        # peers going at the same moment) one may hold it: on another thread, waited for below at most 3 s
        proc.close_in_background()
        if args.out:
            path = Path(args.out) / f"node-{args.id}.json"
            report = {**schedule.report(), "reconnects": proc.reconnects, **clock.report(), "final": True}
            try:
                write_text_atomically(path, json.dumps(report, indent=2) + "\n")
            except OSError as exc:  # the steps ran, only the report is lost: say which file, and exit 74
                log.error("node %d: ran its steps but could not write its report %s (%s)", args.id, path,
                          exc.strerror or exc)
                status = EXIT_WRITE_FAILED
        if not proc.join_closers(3.0):
            # an old session still waits on a dead link; its report is written: leave without the interpreter's
            # exit, which would wait for that session too
            logging.shutdown()
            os._exit(status)
    return status
