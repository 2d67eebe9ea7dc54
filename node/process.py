"""``zentrack node``: one tracker as its own OS process, moving bytes and time around :class:`Tracker`.

Each step k: take ``meas/<id>`` (or coast without it), publish the posterior on ``est/<id>``, publish the
predicted information pair for k+1 on ``prior/<id>``, then fuse the neighbours' pairs for k+1 by CI:

- **realtime**: fuse at ``t0 + k Ts + deadline_frac Ts`` (earlier once every live neighbour's pair is in);
  pairs that come later are dropped and counted as late. No measurement by the deadline: predict only.
- **lockstep**: fuse once every participating live neighbour's pair is in (membership fixed at start).

A node that starts after the run began, or whose prior is too old (a long freeze), warm-starts: its first
prior is the CI fusion of its neighbours' pairs. Every message is validated (``zentrack.wire``); a bad one
is dropped and counted under its reason, and logging of rejections is rate-limited.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import time
from collections import defaultdict
from pathlib import Path

import zenoh

from zentrack import wire
from zentrack.runcfg import RunSetup, add_scenario_arguments, resolve_setup
from zentrack.zsession import Inbox, StopFlag, add_zenoh_arguments, freeze_heap, open_session, setup_logging, undeclare_all

from .tracker import MAX_COAST_STEPS, Pair, Tracker

log = logging.getLogger("zentrack.node")

REALTIME_FUTURE_STEPS = 2
TRUTH_GONE_EXIT_S = 10.0
COAST_MARGIN_S = 0.02


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", type=int, required=True, help="node index in the scenario (0-based)")
    add_scenario_arguments(p)
    p.add_argument("--out", metavar="DIR", help="write node-<id>.json (final counters) here on exit")
    add_zenoh_arguments(p, lease_default=1000)


class RejectLog:
    """Counts rejections per reason; logs the first of each reason, then a summary at most every 5 s."""

    def __init__(self, node: int) -> None:
        self.node = node
        self.counts: dict[str, int] = defaultdict(int)
        self._since: dict[str, int] = defaultdict(int)
        self._last = 0.0

    def add(self, where: str, err: wire.WireError) -> None:
        first = self.counts[err.reason] == 0
        self.counts[err.reason] += 1
        self._since[err.reason] += 1
        now = time.monotonic()
        if first:
            log.warning("node %d: rejected %s message (%s); further rejections are summarised", self.node, where, err)
            self._since.clear()
        elif now - self._last > 5.0 and self._since:
            log.warning("node %d: rejected in the last 5 s: %s", self.node, dict(self._since))
            self._since.clear()
            self._last = now


class NodeLoop:
    def __init__(self, session: zenoh.Session, keys, setup: RunSetup, tracker: Tracker, stop: StopFlag) -> None:
        self.session, self.keys, self.tracker, self.stop = session, keys, tracker, stop
        self.id = tracker.id
        self.mode = setup.mode
        self.frac = setup.deadline_frac
        self.ts = setup.scenario.ts
        self.t0: float | None = None
        self.steps: int | None = None
        self.participants: set[int] | None = None
        self.live: set[int] = set()
        self.truth_gone_since: float | None = None
        self.coast_run = 0  # consecutive steps without a measurement
        self.stale = False  # realtime: coasted too long, so the next measurement triggers a warm start
        self.phase = "idle"  # idle -> await_meas <-> fusing; warming when it has no prior
        self.step = 0  # the step being processed (await_meas) or whose measurement produced own_pair
        self.fuse_step: int | None = None
        self.own_pair: Pair | None = None
        self.meas: dict[int, dict] = {}
        self.priors: dict[int, dict[int, Pair]] = defaultdict(dict)
        self.warm_next = False
        self.fused_upto = 0  # the last step whose prior has been fused (the cold prior is step 0)
        self.counters = {"meas_rx": 0, "prior_rx": 0, "late": 0, "coasted": 0, "misses": 0, "steps": 0, "warm_starts": 0}
        self.rejects = RejectLog(self.id)
        self.inbox = Inbox()
        congestion = zenoh.CongestionControl.BLOCK if self.mode == "lockstep" else zenoh.CongestionControl.DROP
        self.pub_prior = session.declare_publisher(keys.prior(self.id), congestion_control=congestion, express=True)
        self.pub_est = session.declare_publisher(keys.est(self.id), congestion_control=congestion, express=True)
        self.subs = [
            session.declare_subscriber(keys.meas(self.id), self.inbox.callback("meas")),
            *[session.declare_subscriber(keys.prior(j), self.inbox.callback("prior")) for j in tracker.neighbours],
            session.declare_subscriber(keys.start, self.inbox.callback("start")),
            session.declare_subscriber(keys.stop, self.inbox.callback("stop")),
            session.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(), history=True),
        ]
        self.token = session.liveliness().declare_token(keys.alive(self.id))

    # ------------------------------------------------------------------ main loop
    def run(self) -> None:
        while not self.stop:
            msg = self.inbox.get(self._timeout())
            if msg is not None:
                if msg.tag == "stop" and self._valid_stop(msg.payload):
                    log.info("node %d: stop received", self.id)
                    return
                self._dispatch(msg)
            self._advance(time.time())
            if self.mode == "lockstep" and self.steps is not None and self.step >= self.steps:
                return
            if self.truth_gone_since is not None and self.t0 is not None \
                    and time.monotonic() - self.truth_gone_since > TRUTH_GONE_EXIT_S:
                log.warning("node %d: the truth process has been gone for %.0f s; stopping", self.id, TRUTH_GONE_EXIT_S)
                return

    def _timeout(self) -> float:
        """How long to wait for a message before the next timed action (at most 0.2 s, at least 1 ms)."""
        if self.mode != "realtime" or self.t0 is None or (self.steps is not None and self.step >= self.steps):
            return 0.2
        now = time.time()
        if self.phase == "fusing":
            wait = self._deadline(self.step) - now
        elif self.phase == "await_meas":
            wait = self._deadline(self.step) - COAST_MARGIN_S - now
        else:
            wait = 0.05
        return min(0.2, max(0.001, wait))

    def _valid_stop(self, payload: bytes) -> bool:
        try:
            msg = wire.unpack(payload)
            if msg["kind"] != "stop" or msg.get("sender") != "truth":
                raise wire.WireError("kind", "ctl/stop that is not a stop message from truth")
        except wire.WireError as err:
            self.rejects.add("stop", err)
            return False
        return True

    def _deadline(self, k: int) -> float:
        return self.t0 + (k + self.frac) * self.ts

    def _k_now(self, now: float) -> int:
        return int(math.floor((now - self.t0) / self.ts + 1e-9))

    # ------------------------------------------------------------------ messages
    def _dispatch(self, msg) -> None:
        try:
            if msg.tag == "alive":
                self._on_alive(msg.key, msg.payload == b"put")
            elif msg.tag == "start":
                self._on_start(wire.decode_start(msg.payload))
            elif msg.tag == "meas":
                self._on_meas(msg)
            elif msg.tag == "prior":
                self._on_prior(msg)
            elif msg.tag == "stop":
                pass  # an invalid ctl/stop, already counted
        except wire.WireError as err:
            self.rejects.add(msg.tag, err)

    def _on_alive(self, key: str, present: bool) -> None:
        name = self.keys.last_segment(key)
        if name.isdigit():
            (self.live.add if present else self.live.discard)(int(name))
        elif name == "truth":
            # after a freeze or a cut link every token looks gone for a moment: only a lasting absence stops us
            self.truth_gone_since = None if present else time.monotonic()

    def _on_start(self, start: dict) -> None:
        if start["mode"] != self.mode:
            raise wire.WireError("schema", f"run mode {start['mode']} differs from this node's {self.mode}")
        first = self.t0 is None
        self.t0, self.steps, self.ts = start["t0"], start["steps"], start["ts"]
        self.participants = set(start["participants"])
        if not first:
            return
        now = time.time()
        fresh = self.mode == "lockstep" or now < self._deadline(0) - COAST_MARGIN_S
        if fresh and self.id in self.participants:
            self.tracker.cold_start(0)
            self.phase, self.step = "await_meas", 0
            log.info("node %d: cold start, %d participants", self.id, len(self.participants))
        else:
            self._start_warming(now)

    def _meas_window(self, now: float) -> tuple[int | None, int | None]:
        if self.t0 is None:
            raise wire.WireError("unexpected", "measurement before the run's start message")
        lo = self.step + (1 if self.phase == "fusing" else 0)
        if self.mode == "lockstep":
            return lo, lo + 1
        k_now = self._k_now(now)
        return max(lo, k_now - 1), k_now + REALTIME_FUTURE_STEPS

    def _on_meas(self, msg) -> None:
        lo, hi = self._meas_window(msg.t_recv)
        m = wire.decode_meas(msg.payload, self.id, self.tracker.measurement_dim, lo, hi)
        if m["k"] in self.meas:
            raise wire.WireError("duplicate", f"second measurement for step {m['k']}")
        m["t_recv"] = msg.t_recv
        self.meas[m["k"]] = m
        self.counters["meas_rx"] += 1

    def _on_prior(self, msg) -> None:
        name = self.keys.last_segment(msg.key)
        if not name.isdigit():
            raise wire.WireError("sender_mismatch", f"prior on key {msg.key!r}")
        sender = int(name)
        if self.t0 is None:
            raise wire.WireError("unexpected", "prior before the run's start message")
        if self.mode == "lockstep":
            lo = self.fused_upto + 1
            hi = lo + 1
        else:
            k_now = self._k_now(msg.t_recv)
            lo, hi = k_now - 1, k_now + REALTIME_FUTURE_STEPS + 1
        p = wire.decode_prior(msg.payload, sender, self.tracker.state_dim, lo, hi)
        if p["k"] <= self.fused_upto:
            self.counters["late"] += 1  # a genuine pair that came after we fused that step
            return
        box = self.priors[p["k"]]
        if sender in box:
            raise wire.WireError("duplicate", f"second prior from node {sender} for step {p['k']}")
        box[sender] = Pair(p["k"], p["Y"], p["y"])
        self.counters["prior_rx"] += 1

    # ------------------------------------------------------------------ stepping
    def _advance(self, now: float) -> None:
        for _ in range(4):  # a few transitions per wake-up (e.g. fuse then a buffered measurement)
            before = (self.phase, self.step)
            if self.phase == "await_meas":
                self._try_step(now)
            elif self.phase == "fusing":
                self._try_fuse(now)
            elif self.phase == "warming":
                self._try_warm(now)
            if (self.phase, self.step) == before:
                return
            now = time.time()

    def _expected_neighbours(self) -> set[int]:
        nbrs = set(self.tracker.neighbours) & self.live
        if self.mode == "lockstep" and self.participants is not None:
            nbrs &= self.participants
        return nbrs

    def _try_step(self, now: float) -> None:
        k = self.step
        if self.steps is not None and k >= self.steps:
            return  # the run is over; wait for ctl/stop
        if self.mode == "realtime":
            k_now = self._k_now(now)
            if now > self._deadline(k):  # we fell behind (frozen, overloaded): skip to a step we can still make
                target = k_now if now < self._deadline(k_now) - COAST_MARGIN_S else k_now + 1
                self.counters["misses"] += target - k  # every skipped step is a missed deadline
                log.warning("node %d: behind by %d step(s); skipping to step %d", self.id, target - k, target)
                self._drop_buffers_before(target)
                if self.tracker.catch_up(target):
                    self.step = target
                    return
                self._start_warming(now)
                return
        m = self.meas.pop(k, None)
        if m is None:
            if self.mode == "realtime" and now >= self._deadline(k) - COAST_MARGIN_S:
                self._local_step(k, None, now)  # coast: predict only
            return
        self._local_step(k, m, now)

    def _local_step(self, k: int, m: dict | None, now: float) -> None:
        if self.stale and m is not None:
            # measurements are back after a long gap (a cut link): our prior is stale, so rejoin like a
            # restarted node (warm start from the neighbours) instead of publishing one very wrong posterior
            self.stale, self.coast_run = False, 0
            self.counters["warm_starts"] += 1
            self._start_warming(now)
            return
        t_start = time.perf_counter()
        z = None if m is None else m["z"]
        post = self.tracker.update(z)
        update_us = (time.perf_counter() - t_start) * 1e6
        kin = self.tracker.kinematic(post)
        coasted = z is None
        self.counters["coasted"] += coasted
        self.coast_run = self.coast_run + 1 if coasted else 0
        self.stale = self.stale or (self.mode == "realtime" and self.coast_run > MAX_COAST_STEPS)
        self.counters["steps"] += 1
        t_pub = time.time()
        miss = self.mode == "realtime" and t_pub > self._deadline(k)
        self.counters["misses"] += miss
        self.pub_est.put(wire.encode_est(
            k, k * self.ts, self.id, kin.mean[0], kin.cov[0],
            t_meas_pub=None if m is None else m["t_pub"], t_recv=None if m is None else m["t_recv"],
            t_pub=t_pub, update_us=update_us, fused=self.last_fused, coasted=coasted, warm=self.warm_next,
            miss=bool(miss), neighbours=sorted(self._expected_neighbours()), counters=self._counter_snapshot(),
        ))
        self.warm_next = False
        self.own_pair = self.tracker.predict_pair(post, k + 1)
        self.pub_prior.put(wire.encode_prior(k + 1, (k + 1) * self.ts, self.id, self.own_pair.matrix, self.own_pair.vector, time.time()))
        self.phase, self.fuse_step = "fusing", k + 1

    last_fused = 0

    def _try_fuse(self, now: float) -> None:
        s = self.fuse_step
        got = self.priors.get(s, {})
        complete = self._expected_neighbours() <= set(got)
        if not complete and not (self.mode == "realtime" and now >= self._deadline(s - 1)):
            return
        own = self.own_pair
        self.last_fused = self.tracker.fuse(s, own, got)
        self.fused_upto = s
        if self.mode == "realtime" and time.time() > self.t0 + s * self.ts:
            self.counters["misses"] += 1  # the step overran into the next sample period
        self._drop_buffers_before(s + 1, priors_only=True)
        self._drop_buffers_before(s)
        self.own_pair = None
        if self.tracker.prior is None:
            self._start_warming(now)
            return
        self.phase, self.step, self.fuse_step = "await_meas", s, None

    def _start_warming(self, now: float) -> None:
        """No usable prior: fuse the neighbours' pairs of the next step (realtime) as our prior."""
        self.tracker.prior, self.tracker.prior_step = None, None
        self.phase = "warming"
        self.own_pair = None
        if self.t0 is not None:
            k_now = self._k_now(now)
            self.step = k_now if now < self._deadline(k_now) else k_now + 1
            self.fuse_step = self.step + 1

    def _try_warm(self, now: float) -> None:
        if self.t0 is None:
            return
        if self.fuse_step is None:
            self._start_warming(now)
        s = self.fuse_step
        got = self.priors.get(s, {})
        deadline_passed = self.mode == "realtime" and now >= self._deadline(s - 1)
        if not deadline_passed and not (got and self._expected_neighbours() <= set(got)):
            return
        if got:
            self.last_fused = self.tracker.fuse(s, None, got)
            self.fused_upto = s
            if self.tracker.prior is not None:
                self.counters["warm_starts"] += 1
                self.warm_next = True
                log.info("node %d: warm start at step %d from %d neighbour(s)", self.id, s, len(got))
                self._drop_buffers_before(s + 1, priors_only=True)
                self._drop_buffers_before(s)
                self.phase, self.step, self.fuse_step = "await_meas", s, None
                return
        if deadline_passed:
            self._drop_buffers_before(s + 1, priors_only=True)
            self.fused_upto = s
            self.step, self.fuse_step = s, s + 1  # try the next step

    def _drop_buffers_before(self, step: int, priors_only: bool = False) -> None:
        for s in [s for s in self.priors if s < step]:
            del self.priors[s]
        if not priors_only:
            for k in [k for k in self.meas if k < step]:
                del self.meas[k]

    def _counter_snapshot(self) -> dict:
        return {**self.counters, "rejected": dict(self.rejects.counts)}

    def close(self) -> None:
        undeclare_all(self.subs, self.token)


def run(args: argparse.Namespace) -> int:
    setup_logging()
    setup = resolve_setup(args)
    tracker = Tracker(setup.scenario, args.id, setup.filter_kind, setup.qbar, setup.theta)
    stop = StopFlag()
    with open_session(args) as (session, keys):
        loop = NodeLoop(session, keys, setup, tracker, stop)
        log.info("node %d up: run %s, %s, filter %s, neighbours %s", args.id, keys.run, setup.mode,
                 setup.filter_kind, tracker.neighbours)
        freeze_heap()
        try:
            loop.run()
        finally:
            loop.close()
            if args.out:
                path = Path(args.out) / f"node-{args.id}.json"
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(json.dumps(loop._counter_snapshot(), indent=2) + "\n")
    return 0
