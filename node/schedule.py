"""A tracker's schedule as a state machine free of I/O: what to do with each message and when to act.

:class:`NodeSchedule` is fed messages (:meth:`handle`) and wake-ups (:meth:`advance`); the time comes from an
injected clock and every publication goes through an injected ``send(channel, payload)``, so the whole
schedule runs in unit tests without Zenoh (``node/process.py`` only moves bytes). Phases:

- ``idle``: before ``ctl/start``;
- ``await_meas`` (step k): wait for the measurement of step k, or coast (predict only) at the deadline;
  publish the posterior on ``est`` and the predicted pair for k+1 on ``prior`` (at once, or held until the
  deadline: see ``fusing``);
- ``await_scans`` (step k, rules that exchange scans, e.g. seed 002): the node has forwarded its own scan (or
  "no scan") on ``scan/<i>``; it waits for every live neighbour's scan of step k, or until
  ``t0 + (k + frac / (2 L)) Ts`` (realtime), then updates with its own and the neighbours' scans;
- ``await_relays`` (step k, rules with ``relay_scans``): after its estimate the node has relayed the
  neighbours' scans of step k (one ``relay`` message on ``scan/<i>``); it waits for every live neighbour's
  relay, or until step k's deadline (when fusion follows the deadline; else halfway there from the scan
  deadline), then updates its prior with the own, the neighbours' and the relayed two-hop scans, and that
  posterior's prediction is its round-1 message (the estimate it published keeps the one-hop update);
- ``fusing`` (step k+1, round l of the rule's L): fuse the neighbours' round-l messages for k+1 once every
  live neighbour's is in, or at the round's deadline (realtime; a round fused without every live neighbour's
  message counts as ``partial_rounds``). The fusion window: in realtime, when the period leaves room for it
  (:meth:`NodeSchedule.fusion_after_deadline`), fusion waits for step k's deadline: the node holds its round-1
  message until ``t0 + (k + frac) Ts`` and the window runs from there to ``FUSION_MARGIN_S`` before the next
  sample, so the deadline-critical work of every node (measurement, update, estimate) never competes for
  the CPU with the fusion for the next step (64 trackers on 2 cores: every node wakes at the same sample
  time); otherwise (lockstep, or a deadline late in the period) the round-1 message goes out at once and the
  window ends at ``t0 + (k + frac) Ts``. Each round's deadline is set when the round starts: the end of the
  fusion window less a reserve of ``frac Ts / (4 L)`` for each round still to go
  (but never less than an equal share of what is left), so a round can ride out a stall of a neighbour while
  the later rounds, which take a few ms each, still fit, and the last round ends by the window's end; after round l < L publish the
  rule's next message as round l + 1 and go on, after round L the result is the prior for k+1. Each
  round's duration (own message sent to fused) goes out with the next estimate (``round_ms``);
- ``warming``: no usable prior (a restart) or a stale one (more than ``MAX_COAST_STEPS`` without a
  measurement: a freeze, a cut link, a truth or router stall). A warming node that still has its own
  (stale) prediction publishes it every step flagged ``warm``. At each deadline it takes, in this order:
  the neighbours' fresh pairs (a warm start); else its own prediction fused with the warm pairs that
  arrived; else (no state of its own) the warm pairs; else nothing, and after ``cold_after`` empty
  steps the configured initial prior. So a network in which every node warms at once recovers at the
  first deadline: every node that has a state fuses at least its own pair.

Neighbours' messages are checked before they are fused. Each (step, round, sender) keeps up to
``MAX_COPIES`` distinct messages; an exact replay of one is refused as a duplicate, more copies as a flood.
When a round is fused, each copy goes through the tracker's gate against the node's own message of that
round (a chi-square test with the covariance-intersection bound, ``fusion/gate.py``), and per sender:

- exactly one copy passes: it is fused;
- none passes: the sender is left out of the round (counted ``gated``);
- two or more distinct copies pass: the sender is left out of the round (counted ``equivocations``).

The gate trusts the node's own message, so a node whose own estimate has gone wrong (inconsistent after a
freeze or an overloaded stretch) would refuse every honest neighbour from then on and never come back. So a
node that the gate shows to be the odd one out is ``outvoted``: it fuses the refused neighbours' messages
without its own message in that round (counted ``outvoted``) when either

- at least two senders, more than half of those heard in the round, had every copy refused, each sent one
  copy, and those copies pass the gate against each other (they agree with each other, not with us); or
- every sender heard was refused in ``OUTVOTED_STREAK`` consecutive rounds: with a single neighbour nobody can
  tell which of the two is wrong (both see the same refusals), so the node lifts its gate for that round and
  fuses the refused messages with its own (counted ``gate_lifted``); CI keeps the result consistent if
  either was, and the two estimates meet.

In realtime a forger cannot trigger this: a sender is "refused" only when none of its copies passes, and the
real copy of a node that is right passes; only a node's own wrong estimate, or an adversary who can also
suppress the real messages, makes every copy fail. Lockstep fuses once every neighbour has sent any copy, so
forged copies that arrive before most neighbours' real ones, and agree with each other, can outvote a node for
a round: lockstep is a study mode for a trusted bus (``--secure`` where forgers are possible).

Why this rule: without authentication (insecure mode) a receiver cannot tell the sender's copy from a forged
one, so arrival order must not decide. A forger that sends first cannot evict the real message (the
real one is not refused as a duplicate), a grossly false copy never passes the gate, and a plausible false copy
can at most remove that neighbour from one round: CI over fewer neighbours stays consistent. In realtime a
round counts a sender as in once one of its copies passes the gate, so a forged early copy does not make
the node fuse before the real one arrives; lockstep waits for any copy (nothing there ever times out).

Realtime only: in lockstep there are no deadlines, nothing coasts, nothing warms. A relay node (no sensor)
never counts as stale: its estimate comes from fusion alone. Measurements that arrive before ``ctl/start``
are kept (a few steps' worth) and handled when it comes.
"""
from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np

from zentrack.config.node_config import NodeConfig
from zentrack.fusion.estimates import Estimate
from zentrack.fusion.scan import Scan
from zentrack.node.tracker import MAX_COAST_STEPS, Pair, Tracker
from zentrack.transport import wire
from zentrack.transport.wire import Message

log = logging.getLogger("zentrack.node")

REALTIME_FUTURE_STEPS = 2
#: measurement and prior messages kept while the start is not known yet
EARLY_KEPT = 256
COAST_MARGIN_S = 0.02
#: fusion after the deadline ends this long before the next sample, so the next measurement finds it done
FUSION_MARGIN_S = 0.005
#: a warming node with no state of its own that hears nothing for this many steps cold-starts
COLD_AFTER_STEPS = 20
#: distinct messages kept per (step, round, sender): the real one and a few forged copies
MAX_COPIES = 3
#: consecutive rounds in which the gate refused every sender heard, after which the node is outvoted
OUTVOTED_STREAK = 5
#: estimates carry the node's counters every this many steps (about 200 bytes and a dict build saved on the
#: others); a node that exits writes them all to ``node-<i>.json``, so only a killed node's last few steps of
#: counts can be missing from a run's summary
COUNTERS_EVERY_STEPS = 10
#: how long a stop before the run's end waits for the truth's liveliness token to go before it is refused
STOP_CONFIRM_S = 3.0


class RejectLog:
    """Counts rejections per reason; logs the first of each reason, then a summary at most every 5 s."""

    def __init__(self, node: int, clock: Callable[[], float]) -> None:
        self.node, self.clock = node, clock
        self.counts: dict[str, int] = defaultdict(int)
        self._since: dict[str, int] = defaultdict(int)
        self._last = -math.inf

    def add(self, where: str, err: wire.WireError) -> None:
        first = self.counts[err.reason] == 0
        self.counts[err.reason] += 1
        self._since[err.reason] += 1
        now = self.clock()
        if first:
            log.warning("node %d: rejected %s message (%s); further rejections are summarised", self.node, where, err)
            self._since.clear()
            self._last = now
        elif now - self._last > 5.0 and self._since:
            log.warning("node %d: rejected in the last 5 s: %s", self.node, dict(self._since))
            self._since.clear()
            self._last = now


def same_scan(a: Scan, b: Scan) -> bool:
    """Whether two relayed copies of one origin's scan carry the same returns, pose and noise."""
    return (np.array_equal(a.returns, b.returns) and np.array_equal(a.pose, b.pose)
            and np.array_equal(a.noise_cov, b.noise_cov))


class NodeSchedule:
    """Node ``tracker.id``'s schedule. ``send(channel, payload)`` publishes on ``est`` or ``prior``."""

    def __init__(self, keys, cfg: NodeConfig, tracker: Tracker, clock: Callable[[], float],
                 send: Callable[[str, bytes], None], cold_after: int = COLD_AFTER_STEPS, incarnation: int = 0,
                 fusion_after_deadline: bool | None = None) -> None:
        self.keys, self.tracker, self.clock, self.send = keys, tracker, clock, send
        self.incarnation = incarnation
        self.id = tracker.id
        self.mode = cfg.mode
        self.frac = cfg.deadline_frac
        self.ts = cfg.ts
        self.relay = cfg.role == "relay"
        self.exchange = tracker.rule.exchanges_scans  # forward scans to the neighbours before the update
        self.fwd: dict[int, dict[int, dict]] = defaultdict(dict)  # step -> sender -> forwarded scan
        self.relayed: dict[int, dict[int, dict]] = defaultdict(dict)  # step -> sender -> relay (relay_scans)
        self.scans_done_upto = -1  # the last step whose forwarded scans were used (a later copy is late)
        self.relays_done_upto = -1  # the last step whose relays were used
        self.core_scans: list[Scan] = []  # the step's one-hop scans, waiting for the relayed ones
        self.post: Estimate | None = None  # the step's posterior, waiting for the relayed scans (await_relays)
        self.pending: dict | None = None  # own measurement message waiting for the neighbours' scans
        self.cold_after = cold_after
        self.t0: float | None = None
        self.steps: int | None = None
        self.participants: set[int] | None = None
        self.live: set[int] = set()
        self.gone: set[int] = set()  # nodes whose liveliness token went away (and has not come back)
        self.truth_alive = False
        self.truth_gone_since: float | None = None
        self.coast_run = 0  # consecutive steps without a measurement
        self.phase = "idle"
        self.step = 0  # the step being processed (await_meas) or whose measurement produced own_pair
        self.fuse_step: int | None = None
        self.fuse_round = 1
        self.own_pair: Pair | None = None
        self.warm_published: int | None = None  # the step of the last warm pair published while warming
        self.empty_warm_steps = 0
        self.meas: dict[int, dict] = {}
        # (step, round) -> sender -> the distinct messages received (see "Neighbours' messages are checked")
        self.priors: dict[tuple[int, int], dict[int, list[Pair]]] = defaultdict(dict)
        self.early: list[Message] = []  # measurement and prior messages that came before the start
        self.warm_next = False
        self.last_fused = 0
        self.fused_upto = 0  # the last step whose prior has been fused (the cold prior is step 0)
        self.counters = {"meas_rx": 0, "prior_rx": 0, "late": 0, "coasted": 0, "misses": 0, "steps": 0,
                         "warm_starts": 0, "warm_self": 0, "cold_restarts": 0, "partial_rounds": 0,
                         "relays_rx": 0, "partial_relays": 0, "relay_left_out": 0,
                         "gated": 0, "equivocations": 0, "outvoted": 0, "gate_lifted": 0}
        self.refused_streak = 0  # consecutive rounds in which the gate refused every sender heard
        self.round_started = 0.0  # when the round being fused began (its own message sent)
        self.round_deadline = 0.0  # when the round being fused stops waiting (realtime)
        self.round_ms: list[float] = []  # the durations of the rounds of the step being fused
        self.last_round_ms: list[float] = []  # ... and of the rounds that made the current prior
        self.rejects = RejectLog(self.id, clock)
        self.dropped: dict[str, int] = {}  # dropped before decoding by the process's flood guard (tag/reason)
        self.stopped = False
        self.start_payload: bytes | None = None  # truth's ctl/start as received, served to a restarted truth
        self.start_fields: dict = {}
        self.stop_pending_since: float | None = None  # a stop before the run's end, waiting for the truth to go  # ... and decoded: a later start must repeat it
        self.hold_until: float | None = None  # realtime: when the held round-1 message goes out (fusion after the deadline)
        self._fusion_after_deadline = fusion_after_deadline  # None: decided by the timing (fusion_after_deadline())

    # ------------------------------------------------------------------ public interface
    @property
    def stale(self) -> bool:
        """Too long without a measurement: the own prior is only a prediction (realtime; in lockstep every
        node steps through its gaps exactly as the batched simulator does)."""
        return self.mode == "realtime" and self.coast_run > MAX_COAST_STEPS

    def done(self) -> bool:
        return self.stopped or (self.mode == "lockstep" and self.steps is not None and self.step >= self.steps)

    def timeout(self) -> float:
        """How long to wait for a message before the next timed action (at most 0.2 s, at least 1 ms)."""
        if self.mode != "realtime" or self.t0 is None or (self.steps is not None and self.step >= self.steps):
            return 0.2
        now = self.clock()
        if self.phase == "fusing":
            wait = (self.hold_until if self.hold_until is not None else self._round_deadline()) - now
        elif self.phase == "await_meas":
            wait = self._deadline(self.step) - COAST_MARGIN_S - now
        elif self.phase == "await_scans":
            wait = self._scan_deadline(self.step) - now
        elif self.phase == "await_relays":
            wait = self._relay_deadline(self.step) - now
        elif self.phase == "warming" and self.fuse_step is not None:
            wait = self._fusion_window_end(self.fuse_step) - now
        else:
            wait = 0.05
        return min(0.2, max(0.001, wait))

    def handle(self, msg: Message) -> None:
        """One message: validated, then buffered or acted on; a bad one is counted under its reason."""
        try:
            if msg.tag == "alive":
                self._on_alive(msg.key, msg.payload == b"put")
            elif msg.tag == "start":
                self._on_start(wire.decode_start(msg.payload))
                self.start_payload = msg.payload
            elif msg.tag == "meas":
                self._on_meas(msg)
            elif msg.tag == "prior":
                self._on_prior(msg)
            elif msg.tag == "scan":
                self._on_scan(msg)
            elif msg.tag == "stop":
                self._on_stop(msg.payload)
        except wire.WireError as err:
            self.rejects.add(msg.tag, err)

    def advance(self) -> None:
        """Take the transitions that are due now (a few per wake-up, e.g. fuse then a buffered measurement)."""
        self._check_pending_stop()
        for _ in range(4):
            before = (self.phase, self.step, self.fuse_step, self.fuse_round)
            now = self.clock()
            if self.phase == "await_meas":
                self._try_step(now)
            elif self.phase == "await_scans":
                self._try_scans(now)
            elif self.phase == "await_relays":
                self._try_relays(now)
            elif self.phase == "fusing":
                self._try_fuse(now)
            elif self.phase == "warming":
                self._try_warm(now)
            if (self.phase, self.step, self.fuse_step, self.fuse_round) == before:
                return

    def snapshot(self) -> dict:
        """The counters as published with every ``COUNTERS_EVERY_STEPS``-th estimate and written to
        ``node-<i>.json`` (``incarnation`` tells a restarted process's counters from its predecessor's)."""
        return {**self.counters, "rejected": dict(self.rejects.counts), "dropped": dict(self.dropped),
                "refused": dict(self.tracker.refused), "incarnation": self.incarnation}

    # ------------------------------------------------------------------ messages
    def _on_stop(self, payload: bytes) -> None:
        """A stop once the run is over ends the node. One before that (the truth interrupted or aborting, or a
        forgery) waits up to :data:`STOP_CONFIRM_S` for the truth's liveliness token to go, as it does when the
        truth really ends; if the truth is still there the stop is refused and counted (``conflict``)."""
        msg = wire.unpack(payload)
        if msg["kind"] != "stop" or msg.get("sender") != "truth":
            raise wire.WireError("kind", "ctl/stop that is not a stop message from truth")
        if self._run_over() or not self.truth_alive:
            log.info("node %d: stop received", self.id)
            self.stopped = True
        elif self.stop_pending_since is None:
            log.info("node %d: stop received before the run's end; stopping if the truth leaves", self.id)
            self.stop_pending_since = self.clock()

    def _run_over(self) -> bool:
        if self.t0 is None or self.steps is None:
            return False
        if self.mode == "lockstep":
            return self.step >= self.steps
        return self.clock() >= self._deadline(self.steps - 1)

    def _check_pending_stop(self) -> None:
        if self.stop_pending_since is None:
            return
        if not self.truth_alive or self._run_over():
            log.info("node %d: the truth left after its stop; stopping", self.id)
            self.stopped = True
        elif self.clock() - self.stop_pending_since > STOP_CONFIRM_S:
            self.stop_pending_since = None
            self.rejects.add("stop", wire.WireError("conflict", "a stop before the run's end while the truth is "
                                                                "still there"))

    def _on_alive(self, key: str, present: bool) -> None:
        name, node = self.keys.last_segment(key), self.keys.node_of(key)
        if node is not None:
            (self.live.add if present else self.live.discard)(node)
            (self.gone.discard if present else self.gone.add)(node)
        elif name == "truth":
            # after a freeze or a cut link every token looks gone for a moment: only a lasting absence counts
            self.truth_alive = present
            self.truth_gone_since = None if present else self.clock()

    def _on_start(self, start: dict) -> None:
        if start["mode"] != self.mode:
            raise wire.WireError("schema", f"run mode {start['mode']} differs from this node's {self.mode}")
        first = self.t0 is None
        if not first:
            # the run is under way: a start can only repeat it (truth re-sends it when a node joins, a restarted
            # truth resumes it); one that moves t0, the timing, the participants or x0 is refused and counted
            diff = self._start_conflicts(start)
            if diff:
                raise wire.WireError("conflict", f"a start that contradicts the run under way ({', '.join(diff)})")
            return
        if first:
            try:
                self.tracker.set_initial(start["x0"])
            except ValueError as exc:
                raise wire.WireError("shape", f"start: {exc}") from None
        self.t0, self.steps, self.ts = start["t0"], start["steps"], start["ts"]
        self.participants = set(start["participants"])
        self.start_fields = start
        now = self.clock()
        fresh = self.mode == "lockstep" or now < self._deadline(0) - COAST_MARGIN_S
        if fresh and self.id in self.participants:
            self.tracker.cold_start(0)
            self.phase, self.step = "await_meas", 0
            log.info("node %d: cold start, %d participants", self.id, len(self.participants))
        else:
            self._start_warming(now)
        early, self.early = self.early, []
        for msg in early:  # messages that came before the start
            self.handle(msg)

    def _start_conflicts(self, start: dict) -> list[str]:
        """The fields in which ``start`` differs from the run's start (none for a repeat)."""
        run = self.start_fields
        diff = [key for key in ("t0", "ts", "steps", "mode", "deadline_frac") if start[key] != run[key]]
        if sorted(start["participants"]) != sorted(run["participants"]):
            diff.append("participants")
        if not np.array_equal(start["x0"], run["x0"]):
            diff.append("x0")
        return diff

    def _meas_window(self, now: float) -> tuple[int, int]:
        if self.t0 is None:
            raise wire.WireError("unexpected", "measurement before the run's start message")
        lo = self.step + (1 if self.phase == "fusing" else 0)
        if self.mode == "lockstep":
            return lo, lo + 1
        k_now = self._k_now(now)
        return max(lo, k_now - 1), k_now + REALTIME_FUTURE_STEPS

    def _keep_early(self, msg: Message) -> None:
        if len(self.early) >= EARLY_KEPT:
            raise wire.WireError("unexpected", f"more than {EARLY_KEPT} messages before the run's start")
        self.early.append(msg)

    def _on_meas(self, msg: Message) -> None:
        if self.t0 is None:  # before the start (a lost or late ctl/start): keep it for when the start comes
            self._keep_early(msg)
            return
        lo, hi = self._meas_window(msg.t_recv)
        m = wire.decode_meas(msg.payload, self.id, self.tracker.measurement_dim, lo, hi)
        self._check_returns(m["returns"], f"measurement of step {m['k']}")
        if m["k"] in self.meas:
            raise wire.WireError("duplicate", f"second measurement for step {m['k']}")
        m["t_recv"] = msg.t_recv
        self.meas[m["k"]] = m
        self.counters["meas_rx"] += 1

    def _on_prior(self, msg: Message) -> None:
        sender = self.keys.node_of(msg.key)
        if sender is None:
            raise wire.WireError("sender_mismatch", f"prior on key {msg.key!r}")
        if self.t0 is None:  # a neighbour that got the start first: keep its message for when ours comes
            self._keep_early(msg)
            return
        if self.mode == "lockstep":
            lo = self.fused_upto + 1
            hi = lo + 1
        else:
            k_now = self._k_now(msg.t_recv)
            lo, hi = k_now - 1, k_now + REALTIME_FUTURE_STEPS + 1
        p = wire.decode_prior(msg.payload, sender, self.tracker.block_dims, lo, hi, max_round=wire.MAX_ROUNDS)
        k, rnd = p["k"], p["round"]
        if rnd > self.tracker.rounds(k):
            raise wire.WireError("schema", f"round {rnd} of step {k}: this run's rule has {self.tracker.rounds(k)}")
        if k <= self.fused_upto or (self.phase == "fusing" and k == self.fuse_step and rnd < self.fuse_round):
            self.counters["late"] += 1  # a genuine message that came after we fused that step or round
            return
        copies = self.priors[(k, rnd)].setdefault(sender, [])
        if any(c.raw == msg.payload for c in copies):
            raise wire.WireError("duplicate", f"second copy of node {sender}'s prior for step {k} round {rnd}")
        if len(copies) >= MAX_COPIES:
            raise wire.WireError("flood", f"more than {MAX_COPIES} different priors from node {sender} for step {k} "
                                          f"round {rnd}")
        copies.append(Pair(k, p["blocks"], warm=p["warm"], round=rnd, raw=msg.payload))
        self.counters["prior_rx"] += 1

    def _on_scan(self, msg: Message) -> None:
        """A neighbour's forwarded scan (rules that exchange scans)."""
        key_node = self.keys.node_of(msg.key)
        if key_node is None or key_node not in self.tracker.neighbours:
            raise wire.WireError("sender_mismatch", f"scan on key {msg.key!r}")
        if self.t0 is None:
            self._keep_early(msg)
            return
        lo, hi = self._meas_window(msg.t_recv)
        sc = wire.decode_scan(msg.payload, key_node, self.tracker.measurement_dim, lo - 1, hi)
        sender, k = sc["sender"], sc["k"]
        if sc["kind"] == "relay":
            if not self.tracker.rule.relays_scans:
                raise wire.WireError("unexpected", f"relay from node {sender}: this run's rule relays no scans")
            links = self.tracker.cfg.neighbour_links.get(sender)
            for entry in sc["scans"]:  # node j relays its own neighbours' scans, nobody else's
                origin = entry["origin"]
                if not 0 <= origin < self.tracker.cfg.nodes or (links is not None and origin not in links):
                    raise wire.WireError("sender_mismatch", f"relay from node {sender}: origin {origin} is not "
                                                            f"one of its neighbours")
                self._check_returns(entry["returns"], f"relay from node {sender}: scan of origin {origin}")
            if k <= self.relays_done_upto:  # a copy of a relay this node already used (or gave up on)
                self.counters["late"] += 1
                return
            box = self.relayed[k]
            self.counters["relays_rx"] += sender not in box
        else:
            if sc["origin"] != sender:
                raise wire.WireError("sender_mismatch", f"scan from node {sender} claims origin {sc['origin']}: a "
                                                        f"forwarded scan is the sender's own (relays carry others')")
            self._check_returns(sc["returns"], f"scan from node {sender}")
            if k <= self.scans_done_upto:
                self.counters["late"] += 1
                return
            box = self.fwd[k]
        if sender in box:
            raise wire.WireError("duplicate", f"second {sc['kind']} from node {sender} for step {k}")
        box[sender] = sc

    def _check_returns(self, returns: np.ndarray | None, what: str) -> None:
        """A scan with more returns than this node's filter takes is refused, not fed to the filter."""
        cap = self.tracker.max_returns
        if returns is not None and cap is not None and returns.shape[0] > cap:
            raise wire.WireError("shape", f"{what}: {returns.shape[0]} returns, this node's filter "
                                          f"({self.tracker.cfg.filter}) takes at most {cap} per scan")

    # ------------------------------------------------------------------ stepping
    def _t0(self) -> float:
        """The run's t0 (only called once the start is known)."""
        assert self.t0 is not None
        return self.t0

    def _fusing(self) -> int:
        """The step being fused (only called in the fusing and warming phases)."""
        assert self.fuse_step is not None
        return self.fuse_step

    def _deadline(self, k: int) -> float:
        return self._t0() + (k + self.frac) * self.ts

    def _round_deadline(self) -> float:
        return self.round_deadline

    def fusion_after_deadline(self) -> bool:
        """Whether fusion for the next step waits for this step's deadline: in realtime when the rest of the
        period after the deadline, less ``FUSION_MARGIN_S``, is at least half the measurement window (the
        constructor's ``fusion_after_deadline`` overrides that decision)."""
        if self.mode != "realtime":
            return False
        if self._fusion_after_deadline is not None:
            return self._fusion_after_deadline
        return (1.0 - self.frac) * self.ts - FUSION_MARGIN_S >= 0.5 * self.frac * self.ts

    def _fusion_window_end(self, s: int) -> float:
        """When fusion for step ``s`` must be over (see the module docstring)."""
        if self.fusion_after_deadline():
            return self._t0() + s * self.ts - FUSION_MARGIN_S
        return self._t0() + (s - 1 + self.frac) * self.ts

    def _start_round(self) -> None:
        """Round ``fuse_round`` of step ``fuse_step`` starts now: its deadline is the window's end less a reserve
        per round still to go, at least an equal share of what is left (the module docstring)."""
        s, now = self._fusing(), self.clock()
        self.round_started = now
        rounds = self.tracker.rounds(s)
        window_end = self._fusion_window_end(s)
        left = max(rounds - self.fuse_round + 1, 1)
        reserve = self.frac * self.ts / (4 * rounds)
        share = now + max(0.0, window_end - now) / left
        self.round_deadline = min(window_end, max(share, window_end - (left - 1) * reserve))

    def _scan_deadline(self, k: int) -> float:
        """When a node stops waiting for its neighbours' scans: the first half of round 1's share."""
        return self._t0() + (k + self.frac / (2 * self.tracker.rounds(k + 1))) * self.ts

    def _k_now(self, now: float) -> int:
        return int(math.floor((now - self._t0()) / self.ts + 1e-9))

    def _expected_neighbours(self) -> set[int]:
        """Whose messages to wait for. Realtime: the live neighbours. Lockstep: every participating neighbour
        that has not left, whether or not its liveliness token has reached us yet (right after the start a
        neighbour's scan or pair can arrive before its token, and skipping it would change the numbers)."""
        if self.mode == "lockstep" and self.participants is not None:
            return (set(self.tracker.neighbours) & self.participants) - self.gone
        return set(self.tracker.neighbours) & self.live

    def _try_step(self, now: float) -> None:
        k = self.step
        if self.steps is not None and k >= self.steps:
            return  # the run is over; wait for ctl/stop
        if self.mode == "realtime" and now > self._deadline(k):
            # we fell behind (frozen, overloaded): skip to a step we can still make, predicting through the gap
            k_now = self._k_now(now)
            target = k_now if now < self._deadline(k_now) - COAST_MARGIN_S else k_now + 1
            self.counters["misses"] += target - k  # every skipped step is a missed deadline
            log.warning("node %d: behind by %d step(s); skipping to step %d", self.id, target - k, target)
            self._drop_buffers_before(target)
            self.coast_run += target - k
            if self.tracker.catch_up(target) and not self.stale:
                self.step = target
                return
            self._start_warming(now)
            return
        m = self.meas.pop(k, None)
        if m is None:
            if self.mode == "realtime" and now >= self._deadline(k) - COAST_MARGIN_S:
                self._measured(k, None, now)  # coast: predict only
            return
        if self.stale:
            # a measurement after a long gap: our prior is only a prediction, so rejoin through the warm-up
            # (the neighbours' fresh pairs if there are any) instead of publishing one very wrong posterior
            self._start_warming(now)
            return
        self._measured(k, m, now)

    def _measured(self, k: int, m: dict | None, now: float) -> None:
        """Step k's own measurement message is in (or the node coasts): update now, or first forward the scan
        and wait for the neighbours' (rules that exchange scans)."""
        if not self.exchange:
            self._local_step(k, m, now, [])
            return
        if m is None or self.relay or m["returns"] is None:  # nothing to forward: say so, nobody need wait
            self.send("scan", wire.encode_scan(k, k * self.ts, self.id, self.id, None, None, None, self.clock()))
        else:
            pose = self.tracker.sensor_position if m["pose"] is None else m["pose"]
            self.send("scan", wire.encode_scan(k, k * self.ts, self.id, self.id, m["returns"], pose,
                                               self.tracker.noise_cov, self.clock()))
        self.pending = m
        self.phase = "await_scans"
        self._try_scans(now)

    def _try_scans(self, now: float) -> None:
        k = self.step
        got = self.fwd.get(k, {})
        if not self._expected_neighbours() <= set(got) and not (self.mode == "realtime" and now >= self._scan_deadline(k)):
            return
        extra = [Scan(k, sc["origin"], sc["returns"], sc["pose"], sc["noise_cov"])
                 for _, sc in sorted(got.items()) if sc["returns"] is not None]
        m, self.pending = self.pending, None
        self.fwd.pop(k, None)
        self.scans_done_upto = max(self.scans_done_upto, k)
        self._local_step(k, m, now, extra)

    def _local_step(self, k: int, m: dict | None, now: float, forwarded: list[Scan]) -> None:
        """Local update with the own scan and any forwarded ones, then publish the estimate and round 1."""
        t_start = self.clock()
        returns = None if m is None else m["returns"]
        scans = [] if m is None or returns is None or self.relay else [self.tracker.scan(k, returns, m["pose"])]
        post = self.tracker.update(scans + forwarded)
        update_us = (self.clock() - t_start) * 1e6
        kin = self.tracker.kinematic(post)
        coasted = returns is None and not self.relay
        self.counters["coasted"] += coasted
        self.coast_run = self.coast_run + 1 if coasted else 0
        self.counters["steps"] += 1
        t_pub = self.clock()
        miss = self.mode == "realtime" and t_pub > self._deadline(k)
        self.counters["misses"] += miss
        self.send("est", wire.encode_est(
            k, k * self.ts, self.id, kin.mean, kin.cov,
            t_meas_pub=None if m is None else m["t_pub"], t_recv=None if m is None else m["t_recv"],
            t_pub=t_pub, update_us=update_us, fused=self.last_fused, coasted=coasted, warm=self.warm_next,
            miss=bool(miss), neighbours=sorted(self._expected_neighbours()), round_ms=self.last_round_ms,
            **self._counters_field(k), **self.tracker.diagnostics(post),
        ))
        self.last_round_ms = []
        self.warm_next = False
        if self.tracker.rule.relays_scans:  # relay the neighbours' scans, then share with the two-hop ones
            relayed = [(s.sensor, s.returns, s.pose, s.noise_cov) for s in forwarded if s.count > 0]
            payload, left_out = wire.encode_relay(k, k * self.ts, self.id, relayed, self.clock())
            self.counters["relay_left_out"] += left_out  # scans that did not fit in one message
            self.send("scan", payload)
            self.core_scans, self.post = scans + forwarded, post
            self.phase = "await_relays"
            self._try_relays(now)
            return
        self._share_prior(post, k)

    def _relay_deadline(self, k: int) -> float:
        """When a node stops waiting for its neighbours' relays: step k's deadline when fusion follows it
        (round 1 is held until then anyway), else halfway from the scan deadline to it."""
        if self.fusion_after_deadline():
            return self._deadline(k)
        return 0.5 * (self._scan_deadline(k) + self._deadline(k))

    def _try_relays(self, now: float) -> None:
        """Once every live neighbour's relay is in (or at the relay deadline): the prior updated with the
        own, the neighbours' and the relayed two-hop scans (own first, then by origin, as the batched
        simulator stacks them; one scan per origin) is what this node shares."""
        k = self.step
        got = self.relayed.get(k, {})
        complete = self._expected_neighbours() <= set(got)
        if not complete and not (self.mode == "realtime" and now >= self._relay_deadline(k)):
            return
        self.counters["partial_relays"] += not complete
        have = {s.sensor for s in self.core_scans} | {self.id, *self.tracker.neighbours}
        extra: dict[int, Scan] = {}
        disputed: set[int] = set()
        for sender in sorted(got):
            for sc in got[sender]["scans"]:
                origin = sc["origin"]
                if origin in have or origin in disputed:
                    continue
                scan = Scan(k, origin, sc["returns"], sc["pose"], sc["noise_cov"])
                if origin in extra and not same_scan(extra[origin], scan):  # two relays disagree: use neither
                    del extra[origin]
                    disputed.add(origin)
                    self.rejects.add("scan", wire.WireError("conflict", f"relays of step {k} carry two different "
                                                                        f"scans of node {origin}; neither is used"))
                    continue
                extra.setdefault(origin, scan)
        self.relayed.pop(k, None)
        self.relays_done_upto = max(self.relays_done_upto, k)
        post, scans = self.post, self.core_scans
        assert post is not None  # set with the phase
        self.core_scans, self.post = [], None
        if extra:
            own = [s for s in scans if s.sensor == self.id]
            others = sorted([s for s in scans if s.sensor != self.id] + list(extra.values()), key=lambda s: s.sensor)
            post = self.tracker.update(own + others)
        self._share_prior(post, k)

    def _share_prior(self, post: Estimate, k: int) -> None:
        """The time update of ``post`` is this node's round-1 message for step k + 1: shared at once, or held
        until step k's deadline when fusion follows it."""
        own = self.tracker.predict_pair(post, k + 1)
        own.warm = self.stale
        self.own_pair = own
        self.round_ms = []
        self.phase, self.fuse_step, self.fuse_round = "fusing", k + 1, 1
        if self.fusion_after_deadline() and self.clock() < self._deadline(k):
            self.hold_until = self._deadline(k)  # round 1 goes out at the deadline (_try_fuse)
            return
        self._publish_round_one()

    def _counters_field(self, k: int) -> dict[str, Any]:
        """``{"counters": snapshot}`` on the estimates that carry them: every ``COUNTERS_EVERY_STEPS``-th step,
        an incarnation's first estimate (a restart shows at once) and the run's last step; else nothing."""
        if k % COUNTERS_EVERY_STEPS == 0 or self.counters["steps"] == 1 or (self.steps is not None and k >= self.steps - 1):
            return {"counters": self.snapshot()}
        return {}

    def _publish_round_one(self) -> None:
        """Share the own predicted pair for the step being fused as its round-1 message, and start the round."""
        own, s = self.own_pair, self._fusing()
        assert own is not None
        self.hold_until = None
        self.send("prior", wire.encode_prior(s, s * self.ts, self.id, own.blocks, self.clock(), warm=own.warm, round=1))
        self._start_round()

    def _passing(self, key: tuple[int, int], own: Pair | None) -> dict[int, list[Pair]]:
        """Per sender, the copies of its round message that pass the gate against ``own`` (checked once each)."""
        out = {}
        for sender, copies in self.priors.get(key, {}).items():
            if own is None:  # nothing to check against (a warm start): every copy counts, nothing is cached
                out[sender] = list(copies)
                continue
            for c in copies:
                if c.gated is None:
                    c.gated = self.tracker.gate(own, c)
            out[sender] = [c for c in copies if c.gated]
        return out

    def _chosen(self, key: tuple[int, int], own: Pair | None) -> tuple[dict[int, Pair], bool]:
        """The message fused per sender (the rule in the module docstring), and whether this node is outvoted
        (then the messages are the refused senders' ones and its own message is left out); counts the
        messages the gate refused (``gated``), the senders left out for sending two that pass
        (``equivocations``) and the rounds in which the node was ``outvoted``."""
        chosen: dict[int, Pair] = {}
        refused_senders: dict[int, list[Pair]] = {}
        received = self.priors.get(key, {})
        for sender, passing in self._passing(key, own).items():
            refused = len(received[sender]) - len(passing)
            if refused and not self.counters["gated"]:
                log.warning("node %d: the gate refused a message from node %d for step %d round %d; further "
                            "refusals are counted under 'gated'", self.id, sender, key[0], key[1])
            self.counters["gated"] += refused
            if len(passing) == 1:
                chosen[sender] = passing[0]
            elif passing:
                self.counters["equivocations"] += 1
                log.warning("node %d: %d different messages from node %d for step %d round %d pass the gate; "
                            "none is fused", self.id, len(passing), sender, key[0], key[1])
            elif not all(c.warm for c in received[sender]):
                refused_senders[sender] = [c for c in received[sender] if not c.warm]
        if own is None or own.warm:
            return chosen, False
        majority, lifted = self._outvoters(refused_senders, heard=len(received))
        if lifted:
            if not self.counters["gate_lifted"]:
                log.warning("node %d: step %d round %d: every neighbour refused for %d rounds; fusing them with "
                            "our own estimate this round (further cases are counted under 'gate_lifted')",
                            self.id, key[0], key[1], OUTVOTED_STREAK)
            self.counters["gate_lifted"] += 1
            return {**chosen, **lifted}, False
        if not majority:
            return chosen, False
        if not self.counters["outvoted"]:
            log.warning("node %d: step %d round %d: the gate refused %d of %d neighbours that agree with each "
                        "other; fusing theirs without our own estimate (further cases are counted under "
                        "'outvoted')", self.id, key[0], key[1], len(majority), len(received))
        self.counters["outvoted"] += 1
        return majority, True

    def _outvoters(self, refused: dict[int, list[Pair]], heard: int) -> tuple[dict[int, Pair], dict[int, Pair]]:
        """The refused senders' messages when they outvote this node, or else when the node lifts its gate
        after a streak of refusals (module docstring): ``(outvoting, lifted)``, at most one of them non-empty."""
        all_refused = bool(refused) and len(refused) == heard
        self.refused_streak = self.refused_streak + 1 if all_refused else 0
        single = {j: copies[0] for j, copies in refused.items() if len(copies) == 1}
        if len(single) >= 2 and 2 * len(single) > heard:
            pairs = list(single.values())
            if all(self.tracker.gate(a, b) for i, a in enumerate(pairs) for b in pairs[i + 1:]):
                self.refused_streak = 0
                return single, {}
        if single and self.refused_streak >= OUTVOTED_STREAK:
            self.refused_streak = 0
            return {}, single
        return {}, {}

    def _heard(self, key: tuple[int, int], own: Pair | None) -> set[int]:
        """The senders whose round message is in: any copy in lockstep, a copy that passes the gate in realtime."""
        if self.mode == "lockstep":
            return set(self.priors.get(key, {}))
        return {j for j, passing in self._passing(key, own).items() if passing}

    def _try_fuse(self, now: float) -> None:
        if self.hold_until is not None:
            if now < self.hold_until:
                return
            self._publish_round_one()
        s, rnd = self._fusing(), self.fuse_round
        complete = self._expected_neighbours() <= self._heard((s, rnd), self.own_pair)
        if not complete and not (self.mode == "realtime" and now >= self._round_deadline()):
            return
        got, outvoted = self._chosen((s, rnd), self.own_pair)
        self.counters["partial_rounds"] += not complete
        self.last_fused, next_pair = self.tracker.fuse(s, None if outvoted else self.own_pair, got, rnd)
        self.priors.pop((s, rnd), None)
        self.round_ms.append((self.clock() - self.round_started) * 1e3)
        if next_pair is not None:  # round rnd + 1 of the same step: share the rule's next message
            self.own_pair = next_pair
            self.send("prior", wire.encode_prior(s, s * self.ts, self.id, next_pair.blocks, self.clock(),
                                                 round=rnd + 1))
            self.fuse_round = rnd + 1
            self._start_round()
            return
        self.last_round_ms, self.round_ms = self.round_ms, []
        self.fused_upto = s
        if self.mode == "realtime" and self.clock() > self._t0() + s * self.ts:
            self.counters["misses"] += 1  # the step overran into the next sample period
        self._drop_buffers_before(s + 1, priors_only=True)
        self._drop_buffers_before(s)
        self.own_pair = None
        self.phase, self.step, self.fuse_step, self.fuse_round = "await_meas", s, None, 1

    def _start_warming(self, now: float) -> None:
        """Enter the warm-up: the next step to fuse is the first whose deadline is still ahead."""
        self.phase = "warming"
        self.own_pair = None
        self.hold_until = None
        self.fuse_round = 1
        if self.t0 is not None:
            k_now = self._k_now(now)
            self.step = k_now if now < self._deadline(k_now) else k_now + 1
            self.fuse_step = self.step + 1
            self._publish_warm_pair()

    def _publish_warm_pair(self) -> None:
        """Share our own prediction for the step we are about to fuse (if we have one), flagged warm."""
        s = self.fuse_step
        if s is None or self.warm_published == s:
            return
        pair = self.tracker.own_pair(s)
        if pair is not None:
            self.warm_published = s
            self.send("prior", wire.encode_prior(s, s * self.ts, self.id, pair.blocks, self.clock(), warm=True))

    def _try_warm(self, now: float) -> None:
        if self.t0 is None:
            return
        if self.fuse_step is None:
            self._start_warming(now)
        s = self._fusing()
        self._publish_warm_pair()
        heard = set(self.priors.get((s, 1), {}))
        # the neighbours' fresh pairs for s come during its fusion window (from the deadline of s - 1 when fusion
        # waits for it): a warming node decides at the window's end, not before they can have come
        deadline_passed = self.mode == "realtime" and now >= self._fusion_window_end(s)
        if not deadline_passed and not (heard and self._expected_neighbours() <= heard):
            return
        got, _ = self._chosen((s, 1), None)  # nothing fresh to gate against: only conflicting copies are left out
        fresh = {j: p for j, p in got.items() if not p.warm}
        own = self.tracker.own_pair(s)
        # a warm start takes round 1 only: the node rejoins the rounds at the next step
        if fresh:  # a warm start: the neighbours' estimates beat our stale prediction
            self.last_fused = self.tracker.fuse(s, None, fresh, final=True)[0]
            self.counters["warm_starts"] += 1
            how = f"warm start from {len(fresh)} neighbour(s)"
        elif own is not None:  # every neighbour is warming too: our own prediction and theirs
            self.last_fused = self.tracker.fuse(s, own, got, final=True)[0]
            self.counters["warm_self"] += 1
            how = f"resumed from its own prediction and {len(got)} warm pair(s)"
        elif got:
            self.last_fused = self.tracker.fuse(s, None, got, final=True)[0]
            self.counters["warm_starts"] += 1
            how = f"warm start from {len(got)} warming neighbour(s)"
        elif not self.tracker.neighbours or self.empty_warm_steps >= self.cold_after:
            self.tracker.cold_start(s)
            self.last_fused = 0
            self.counters["cold_restarts"] += 1
            how = "cold start: no neighbour has a state"
        else:
            if deadline_passed:  # nothing to start from yet: try the next step
                self.empty_warm_steps += 1
                self._drop_buffers_before(s + 1, priors_only=True)
                self.fused_upto = s
                self.step, self.fuse_step = s, s + 1
                self._publish_warm_pair()
            return
        self.fused_upto = s
        self.empty_warm_steps = 0
        self.coast_run = 0
        self.warm_next = True
        log.info("node %d: step %d: %s", self.id, s, how)
        self._drop_buffers_before(s + 1, priors_only=True)
        self._drop_buffers_before(s)
        self.scans_done_upto, self.relays_done_upto = min(self.scans_done_upto, s - 1), min(self.relays_done_upto, s - 1)
        self.phase, self.step, self.fuse_step, self.fuse_round = "await_meas", s, None, 1

    def _drop_buffers_before(self, step: int, priors_only: bool = False) -> None:
        for key in [key for key in self.priors if key[0] < step]:
            del self.priors[key]
        if not priors_only:
            for k in [k for k in self.fwd if k < step]:
                del self.fwd[k]
            for k in [k for k in self.relayed if k < step]:
                del self.relayed[k]
            for k in [k for k in self.meas if k < step]:
                del self.meas[k]
