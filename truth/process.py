"""``zentrack truth``: the truth process. Replays a scenario's run step by step over Zenoh.

It waits for the trackers' liveliness tokens, announces the run on ``ctl/start`` (t0, Ts, steps, mode and the
participants), then per step k publishes the true state on ``truth`` and each node's measurement on
``meas/<i>`` (none for the trackers of a run with sensors of their own, ``[sensor_timing]``: the ``zentrack
sensor`` processes measure, :mod:`zentrack.truth.sensor`):

- **realtime**: step k at wall time ``t0 + k Ts``; a tracker that (re)joins later is sent ``ctl/start`` again.
  After a stall (the process was stopped or starved) it does not replay the steps it missed: it resumes at
  the current step, and the trackers coast through the gap.
- **lockstep**: step k+1 only once every live participant has published its estimate for step k.

A restarted truth (realtime) first asks the trackers for the run's ``ctl/start`` (each node answers the
``ctl/start`` query with the start message it received); when one answers, it resumes that run at the
current step instead of starting a new one. Finally it publishes ``ctl/stop``.
"""
from __future__ import annotations

import argparse
import logging
import time

import numpy as np
import zenoh

from zentrack.common.argtypes import float_in, int_in
from zentrack.common.procs import StopFlag, freeze_heap, setup_logging
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.transport.codec import WireError
from zentrack.transport.messages import EstimateMessage, Measurement, Start, Stop
from zentrack.transport.messages import Truth as TruthMessage  # the process below is Truth
from zentrack.transport.track_messages import TargetSet, TrackList
from zentrack.transport.zsession import Inbox, add_zenoh_arguments, data_congestion, open_session, undeclare_all

#: lockstep: how long the truth waits after the last tracker's token before it starts (nothing re-sends a round
#: message, and a prior published before the peers' link to its neighbour exists reaches no one)
LOCKSTEP_SETTLE_S = 0.5

log = logging.getLogger("zentrack.truth")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_arguments(p)
    p.add_argument("--wait-nodes", type=int_in(1, 1000, "count"), help="start once this many trackers are alive (default: all)")
    p.add_argument("--wait-for", action="append", default=[], metavar="NAME",
                   help="also wait for the liveliness token alive/NAME (e.g. recorder, viewer)")
    p.add_argument("--wait-timeout", type=float_in(0.0, 86400.0, "seconds"), default=60.0, help="seconds to wait for them (default 60)")
    p.add_argument("--start-delay", type=float_in(0.0, 3600.0, "seconds"), default=0.5, help="seconds between ctl/start and step 0 (realtime)")
    p.add_argument("--step-timeout", type=float_in(0.1, 86400.0, "seconds"), default=60.0, help="lockstep: seconds to wait for one step's estimates")
    p.add_argument("--grace", type=float_in(0.0, 3600.0, "seconds"), default=1.0, help="realtime: seconds after the last step before ctl/stop")
    p.add_argument("--resume-query-s", type=float_in(0.0, 60.0, "seconds"), default=1.0,
                   help="seconds to ask the trackers for a run already under way before starting a new one")
    add_zenoh_arguments(p)


class Truth:
    def __init__(self, session: zenoh.Session, keys, setup, args, stop: StopFlag) -> None:
        self.session, self.keys, self.setup, self.args, self.stop = session, keys, setup, args, stop
        self.scn = setup.run_data
        #: a many-target run: its targets and scans (None: one target, ``scn``)
        self.mt = setup.multitarget_data if setup.multitarget is not None else None
        self.inbox = Inbox(rate_per_key=1e9, max_queued=1_000_000)  # lockstep estimates come as fast as nodes step
        self.live: set[int] = set()
        self.strangers: set[int] = set()  # tokens alive/<n> of nodes the run does not have
        self.observers: set[str] = set()
        self.ests: dict[int, set[int]] = {}
        self.start_payload: bytes | None = None
        self.skipped = 0
        # realtime: DROP, so that a cut or full link towards one subscriber (a host behind a partition) never
        # holds up the truth nor, in a router, the same messages to everyone else (data_congestion)
        congestion = data_congestion(setup.mode)
        self.pub_truth = session.declare_publisher(keys.truth, congestion_control=congestion)
        # trackers that take sensors of their own (``[sensor_timing]``: ``zentrack sensor``) get no ``meas/<i>``
        own = setup.own_sensors()
        self.pub_meas = {i: session.declare_publisher(keys.meas(i), congestion_control=congestion, express=False)
                         for i in range(self.scn.nodes) if i not in own}
        self.subs = [
            session.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(), history=True),
        ]
        if setup.mode == "lockstep":  # the barrier needs the estimates; in realtime the truth only publishes
            self.subs.append(session.declare_subscriber(keys.est("*"), self.inbox.callback("est")))
            if self.mt is not None:  # a many-target node's step ends with its track list
                self.subs.append(session.declare_subscriber(keys.tracks("*"), self.inbox.callback("tracks")))
        # the control channel blocks (it is rare): ctl/start goes once and again when a tracker (re)joins, ctl/stop
        # once after the last step. A DROP ctl/start made trackers behind a restarted router go unheard by the
        # recorder for 75-227 steps (tests/test_multihost.py, 4 of 5 runs; BLOCK: 5-6 steps)
        self.pub_start = session.declare_publisher(keys.start, congestion_control=zenoh.CongestionControl.BLOCK)
        self.pub_stop = session.declare_publisher(keys.stop, congestion_control=zenoh.CongestionControl.BLOCK)
        self.queryable = session.declare_queryable(keys.start, self._answer_start)
        self.token = session.liveliness().declare_token(keys.alive("truth"))

    def _answer_start(self, query: zenoh.Query) -> None:
        """A tracker that joined late (or re-opened its session) asks for the run's start."""
        payload = self.start_payload
        if payload is not None:
            query.reply(self.keys.start, payload)

    def drain(self, until: float, first_only: bool = False) -> None:
        """Handle messages until wall time ``until``, or (``first_only``) until one has been handled."""
        while not self.stop:
            msg = self.inbox.get(min(until - time.time(), 0.2))
            if msg is None:
                if time.time() >= until:
                    return
                continue
            self.handle(msg)
            if first_only or time.time() >= until:
                return

    def handle(self, msg) -> None:
        name = self.keys.last_segment(msg.key)
        if msg.tag == "alive":
            node = self.keys.node_of(msg.key)
            if node is None:
                (self.observers.add if msg.payload == b"put" else self.observers.discard)(name)
                return
            if node >= self.scn.nodes:  # not a configured tracker: a token cannot make itself a participant
                if node not in self.strangers:
                    self.strangers.add(node)
                    log.warning("truth: liveliness token alive/%d is not one of the run's %d trackers; ignored",
                                node, self.scn.nodes)
                return
            if msg.payload == b"put":
                if node not in self.live and self.start_payload is not None:
                    log.info("truth: node %d joined; sending ctl/start again", node)
                    self.pub_start.put(self.start_payload)
                self.live.add(node)
            else:
                log.info("truth: node %d left", node)
                self.live.discard(node)
        elif msg.tag in ("est", "tracks"):
            sender = self.keys.node_of(msg.key)
            if sender is None:
                return
            try:
                k = (EstimateMessage.decode(msg.payload, sender) if msg.tag == "est"
                     else TrackList.decode(msg.payload, sender, 6)).k
            except WireError:
                return
            if k < self.scn.steps:  # a forged step far ahead would only grow the map
                self.ests.setdefault(k, set()).add(sender)

    def wait_for_nodes(self) -> list[int]:
        want = self.args.wait_nodes or self.scn.nodes
        deadline = time.time() + self.args.wait_timeout
        observers = set(self.args.wait_for)
        while (len(self.live) < want or not observers <= self.observers) and time.time() < deadline and not self.stop:
            self.drain(min(deadline, time.time() + 0.1))
        if not observers <= self.observers:
            log.warning("truth: %s not seen after %.0f s; starting anyway", sorted(observers - self.observers),
                        self.args.wait_timeout)
        if len(self.live) < want:
            log.warning("truth: only %d of %d trackers alive after %.0f s; starting anyway",
                        len(self.live), want, self.args.wait_timeout)
        return sorted(self.live)

    def publish_step(self, k: int, t0: float) -> None:
        t = k * self.scn.ts
        now = time.time()
        if self.mt is not None:
            self.publish_targets(k, t, now)
            return
        self.pub_truth.put(TruthMessage(k, t, self.scn.truth[0, k], now).encode())
        for i, pub in self.pub_meas.items():
            # (J, m) returns (with clutter, J varies and may be 0), or None: no scan. A relay has no sensor: it
            # still hears "no scan" every step, which tells it the truth is alive
            returns = self.scn.scan(0, k, i)
            pub.put(Measurement(k, t, i, returns, self.scn.sensor_pose(k, i), time.time()).encode())

    def publish_targets(self, k: int, t: float, now: float) -> None:
        """A many-target step: the targets present on ``truth``, each sensor's scan on ``meas/<i>``."""
        mt = self.mt
        assert mt is not None
        ids, states = mt.truth_at(k)
        self.pub_truth.put(TargetSet(k, t, ids, states, now).encode())
        for i, pub in self.pub_meas.items():
            pub.put(Measurement(k, t, i, mt.scan(k, i).returns, None, time.time()).encode())

    def run_under_way(self) -> tuple[Start, bytes] | None:
        """Ask the trackers for the ctl/start of a run already under way (we are a restarted truth): the start
        and its bytes."""
        if self.setup.mode != "realtime" or self.args.resume_query_s <= 0:
            return None
        try:
            replies = self.session.get(self.keys.start, timeout=self.args.resume_query_s)
            for reply in replies:
                if reply.ok is None:
                    continue
                payload = reply.ok.payload.to_bytes()
                try:
                    start = Start.decode(payload)
                except WireError:
                    continue
                if start.mode == "realtime" and start.ts == self.setup.wall_period and start.steps == self.scn.steps:
                    return start, payload
        except zenoh.ZError as exc:
            log.warning("truth: could not ask for a run under way (%s)", exc)
        return None

    def run(self) -> int:
        # ts here is the wall-clock period (``--period``; the scenario's ts by default): what ctl/start announces
        mode, ts, steps = self.setup.mode, self.setup.wall_period, self.scn.steps
        under_way = self.run_under_way()
        if under_way is not None:
            start, self.start_payload = under_way
            t0, first = start.t0, max(0, int((time.time() - start.t0) / ts) + 1)
            self.drain(time.time() + 0.05)
            log.warning("truth: resuming the run under way (t0 %.3f) at step %d", t0, first)
        else:
            participants = self.wait_for_nodes()
            if mode == "lockstep":  # every token is in; let the peers' gossip finish linking them to each other
                self.drain(time.time() + LOCKSTEP_SETTLE_S)  # (a prior sent before its link exists is lost)
            t0, first = time.time() + (self.args.start_delay if mode == "realtime" else 0.0), 0
            x0 = self.scn.x0_estimate[0] if self.mt is None else np.zeros(6)  # many targets: no one initial state
            self.start_payload = Start(t0, ts, steps, mode, tuple(participants), self.setup.deadline_frac,
                                       x0).encode()
            self.pub_start.put(self.start_payload)
            log.info("truth: %s run of %d steps, Ts %.3f s, participants %s", mode, steps, ts, participants)
        for k in range(first, steps):
            if self.stop:
                break
            if mode == "realtime":
                self.drain(t0 + k * ts)
                if time.time() > t0 + (k + 1) * ts:  # stalled past this step's period: do not replay it
                    self.skipped += 1
                    if self.skipped == 1 or self.skipped % 100 == 0:
                        log.warning("truth: behind schedule at step %d; skipping missed steps (%d so far)", k,
                                    self.skipped)
                    continue
                self.publish_step(k, t0)
            else:
                self.publish_step(k, t0)
                deadline = time.time() + self.args.step_timeout
                while not self.stop:
                    waiting = (set(participants) & self.live) - self.ests.get(k, set())
                    if not waiting:
                        break
                    if time.time() > deadline:
                        log.error("truth: step %d: no estimate from %s after %.0f s; aborting", k, sorted(waiting),
                                  self.args.step_timeout)
                        self.pub_stop.put(Stop(k).encode())
                        return 1
                    self.drain(min(deadline, time.time() + 0.5), first_only=True)
                self.ests.pop(k - 1, None)
        if mode == "realtime" and not self.stop:
            self.drain(t0 + steps * ts + self.args.grace)
        self.pub_stop.put(Stop(steps).encode())
        log.info("truth: done")
        time.sleep(0.2)  # let ctl/stop leave before the session closes
        return 0

    def close(self) -> None:
        undeclare_all(self.subs, self.queryable, self.pub_start, self.pub_stop, self.token)


def run(args: argparse.Namespace) -> int:
    setup_logging()
    setup = resolve_setup(args)
    stop = StopFlag()
    with open_session(args, "truth") as (session, keys):
        truth = Truth(session, keys, setup, args, stop)
        freeze_heap()
        try:
            return truth.run()
        finally:
            truth.close()
