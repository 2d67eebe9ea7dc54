"""The transitions of a tracker's step: update, publish, fuse the rounds, warm up (mixed into the schedule).

Each ``_try_*`` method is one phase's wake-up: it checks whether what the phase waits for is in (or its
deadline has passed) and, if so, acts and moves to the next phase through ``_enter`` (the table in
``node/phases.py``). The state they read and write is the schedule's (``node/schedule.py``); the decisions
come from the parts: timing (``node/timing.py``), the fusion policy, relays and warm start.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from zentrack.fusion.estimates import Estimate
from zentrack.fusion.scan import Scan
from zentrack.node.admission import Admission, Arrival, Buffers
from zentrack.node.counters import COUNTERS_EVERY_STEPS, Counters, RejectLog
from zentrack.node.fusion_policy import CONFLICT_SETTLE_S, FusionPolicy
from zentrack.node.phases import Phase, check_transition
from zentrack.node.relays import merge_relays, relayable, with_relayed
from zentrack.node.run_control import Membership
from zentrack.node.timing import COAST_MARGIN_S, StepTiming
from zentrack.node.tracker import MAX_COAST_STEPS, Pair, Tracker
from zentrack.transport.codec import WireError
from zentrack.transport.messages import EstimateMessage, RoundMessage
from zentrack.transport.miss_notes import MAX_MISS_NOTES, MAX_NOTE_MS, MissNote
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan

log = logging.getLogger("zentrack.node")


class Stepping:
    """The step transitions of :class:`~zentrack.node.schedule.NodeSchedule` (which owns every attribute)."""

    id: int
    mode: str
    relay: bool
    exchange: bool
    cold_after: int
    tracker: Tracker
    timing: StepTiming
    clock: Callable[[], float]
    send: Callable[[str, bytes], None]
    counters: Counters
    rejects: RejectLog
    buffers: Buffers
    admission: Admission
    policy: FusionPolicy
    steps: int | None
    phase: Phase
    step: int
    fuse_step: int | None
    fuse_round: int
    own_pair: Pair | None
    pending: Arrival | None
    core_scans: list[Scan]
    post: Estimate | None
    coast_run: int
    warm_published: int | None
    empty_warm_steps: int
    warm_next: bool
    last_fused: int
    fused_upto: int
    round_started: float
    round_deadline: float
    round_ms: list[float]
    last_round_ms: list[float]
    hold_until: float | None
    miss_notes: list[MissNote]  #: misses seen since the last estimate, sent with the next one
    idle_s: float  #: how much later than planned this wake-up came (schedule.advance: frozen or starved)

    members: Membership
    participants: set[int] | None

    def snapshot(self) -> dict:
        raise NotImplementedError  # the schedule's counters snapshot

    @property
    def stale(self) -> bool:
        """Too long without a measurement: the own prior is only a prediction (realtime; in lockstep every
        node steps through its gaps exactly as the batched simulator does)."""
        return self.mode == "realtime" and self.coast_run > MAX_COAST_STEPS

    def _enter(self, phase: Phase) -> None:
        self.phase = check_transition(self.phase, phase)

    def _start_warming(self, now: float) -> None:
        raise NotImplementedError  # node/warm_start.py

    def _fusing(self) -> int:
        """The step being fused (only called in the fusing and warming phases)."""
        assert self.fuse_step is not None
        return self.fuse_step

    def _expected_neighbours(self) -> set[int]:
        return self.members.expected(self.tracker.neighbours, self.participants, self.mode == "lockstep")

    # ------------------------------------------------------------------ await_meas -> [await_scans]
    def _try_step(self, now: float) -> None:
        k, timing = self.step, self.timing
        if self.steps is not None and k >= self.steps:
            return  # the run is over; wait for ctl/stop
        if self.mode == "realtime" and now > timing.deadline(k):
            # we fell behind (frozen, overloaded): skip to a step we can still make, predicting through the gap
            k_now = timing.k_now(now)
            target = k_now if now < timing.deadline(k_now) - COAST_MARGIN_S else k_now + 1
            self.counters.misses += target - k  # every skipped step is a missed deadline
            self._note_miss(k, "skipped", now - timing.deadline(k), target - k)
            log.warning("node %d: behind by %d step(s); skipping to step %d", self.id, target - k, target)
            self.buffers.drop_before(target)
            self.coast_run += target - k
            if self.tracker.catch_up(target) and not self.stale:
                self.step = target
                return
            self._start_warming(now)
            return
        m = self.buffers.meas.pop(k, None)
        if m is None:
            if self.mode == "realtime" and now >= timing.deadline(k) - COAST_MARGIN_S:
                self._measured(k, None, now)  # coast: predict only
            return
        if self.stale:
            # a measurement after a long gap: our prior is only a prediction, so rejoin through the warm-up
            # (the neighbours' fresh pairs if there are any) instead of publishing one very wrong posterior
            self._start_warming(now)
            return
        self._measured(k, m, now)

    def _measured(self, k: int, m: Arrival | None, now: float) -> None:
        """Step k's own measurement message is in (or the node coasts): update now, or first forward the scan
        and wait for the neighbours' (rules that exchange scans)."""
        if not self.exchange:
            self._local_step(k, m, now, [])
            return
        t = k * self.timing.ts
        if m is None or self.relay or m.meas.returns is None:  # nothing to forward: say so, nobody need wait
            scan = ForwardedScan(k, t, self.id, self.id, None, None, None, self.clock())
        else:
            pose = self.tracker.sensor_position if m.meas.pose is None else m.meas.pose
            scan = ForwardedScan(k, t, self.id, self.id, m.meas.returns, pose, self.tracker.noise_cov, self.clock())
        self.send("scan", scan.encode())
        self.pending = m
        self._enter(Phase.AWAIT_SCANS)
        self._try_scans(now)

    def _try_scans(self, now: float) -> None:
        k = self.step
        got = self.buffers.fwd.get(k, {})
        if not self._expected_neighbours() <= set(got) and not (
                self.mode == "realtime" and now >= self.timing.scan_deadline(k, self.tracker.rounds(k + 1))):
            return
        # a forwarded scan carries returns, pose and noise together, or none of them ("no scan")
        extra = [Scan(k, sc.origin, sc.returns, sc.pose, sc.noise_cov) for _, sc in sorted(got.items())
                 if sc.returns is not None and sc.pose is not None and sc.noise_cov is not None]
        m, self.pending = self.pending, None
        self.buffers.fwd.pop(k, None)
        self.buffers.scans_done_upto = max(self.buffers.scans_done_upto, k)
        self._local_step(k, m, now, extra)

    # ------------------------------------------------------------------ update, estimate -> [await_relays] -> fusing
    def _local_step(self, k: int, m: Arrival | None, now: float, forwarded: list[Scan]) -> None:
        """Local update with the own scan and any forwarded ones, then publish the estimate and round 1."""
        t_start = self.clock()
        tracker, counters, ts = self.tracker, self.counters, self.timing.ts
        returns = None if m is None else m.meas.returns
        scans = [] if m is None or returns is None or self.relay else [tracker.scan(k, returns, m.meas.pose)]
        post = tracker.update(scans + forwarded)
        update_us = (self.clock() - t_start) * 1e6
        kin = tracker.kinematic(post)
        coasted = returns is None and not self.relay
        counters.coasted += coasted
        self.coast_run = self.coast_run + 1 if coasted else 0
        counters.steps += 1
        t_pub = self.clock()
        miss = self.mode == "realtime" and t_pub > self.timing.deadline(k)
        counters.misses += miss
        if miss:
            self._note_miss(k, "late_estimate", t_pub - self.timing.deadline(k), work_s=update_us * 1e-6)
        notes, self.miss_notes = tuple(self.miss_notes), []
        diagnostics = tracker.diagnostics(post)
        self.send("est", EstimateMessage(
            k, k * ts, self.id, kin.mean, kin.cov, t_pub,
            t_meas_pub=None if m is None else m.meas.t_pub, t_recv=None if m is None else m.t_recv,
            update_us=update_us, fused=self.last_fused, coasted=coasted, warm=self.warm_next, miss=bool(miss),
            neighbours=tuple(sorted(self._expected_neighbours())),
            round_ms=np.asarray(self.last_round_ms, dtype=float) if self.last_round_ms else None,
            samples=diagnostics.get("samples"), beta=diagnostics.get("beta"), counters=self._counters(k),
            miss_notes=notes,
        ).encode())
        self.last_round_ms = []
        self.warm_next = False
        if tracker.rule.relays_scans:  # relay the neighbours' scans, then share with the two-hop ones
            relayed = tuple(RelayedScan(s.sensor, s.returns, s.pose, s.noise_cov) for s in relayable(forwarded))
            payload, left_out = Relay(k, k * ts, self.id, relayed, self.clock()).encode_capped()
            counters.relay_left_out += left_out  # scans that did not fit in one message
            self.send("scan", payload)
            self.core_scans, self.post = scans + forwarded, post
            self._enter(Phase.AWAIT_RELAYS)
            self._try_relays(now)
            return
        self._share_prior(post, k)

    def _try_relays(self, now: float) -> None:
        """Once every live neighbour's relay is in (or at the relay deadline): the prior updated with the
        own, the neighbours' and the relayed two-hop scans is what this node shares (``node/relays.py``)."""
        k, buffers = self.step, self.buffers
        got = buffers.relayed.get(k, {})
        complete = self._expected_neighbours() <= set(got)
        if not complete and not (
                self.mode == "realtime" and now >= self.timing.relay_deadline(k, self.tracker.rounds(k + 1))):
            return
        self.counters.partial_relays += not complete
        have = {s.sensor for s in self.core_scans} | {self.id, *self.tracker.neighbours}
        relays = {sender: [Scan(k, sc.origin, sc.returns, sc.pose, sc.noise_cov) for sc in relay.scans]
                  for sender, relay in got.items()}
        merged = merge_relays(relays, have)
        for origin in merged.disputed:
            self.rejects.add("scan", WireError("conflict", f"relays of step {k} carry two different scans of node "
                                                           f"{origin}; neither is used"))
        buffers.relayed.pop(k, None)
        buffers.relays_done_upto = max(buffers.relays_done_upto, k)
        post, scans = self.post, self.core_scans
        assert post is not None  # set with the phase
        self.core_scans, self.post = [], None
        if merged.extra:
            post = self.tracker.update(with_relayed(scans, merged.extra, self.id))
        self._share_prior(post, k)

    def _share_prior(self, post: Estimate, k: int) -> None:
        """The time update of ``post`` is this node's round-1 message for step k + 1: shared at once, or held
        until step k's deadline when fusion follows it."""
        own = self.tracker.predict_pair(post, k + 1)
        own.warm = self.stale
        self.own_pair = own
        self.round_ms = []
        self._enter(Phase.FUSING)
        self.fuse_step, self.fuse_round = k + 1, 1
        if self.timing.fusion_after_deadline() and self.clock() < self.timing.deadline(k):
            self.hold_until = self.timing.deadline(k)  # round 1 goes out at the deadline (_try_fuse)
            return
        self._publish_round_one()

    def _note_miss(self, k: int, kind: str, late_s: float, steps: int = 1, work_s: float = 0.0) -> None:
        """Note a deadline miss for the next estimate (the first ``MAX_MISS_NOTES`` since the last one)."""
        if len(self.miss_notes) < MAX_MISS_NOTES:
            ms = [min(MAX_NOTE_MS, max(0.0, s) * 1e3) for s in (late_s, self.idle_s, work_s)]  # what decoding takes
            self.miss_notes.append(MissNote(k, kind, self.phase.value, ms[0], max(1, steps), ms[1], ms[2]))

    def _counters(self, k: int) -> dict[str, Any] | None:
        """The counters' snapshot on the estimates that carry them: every ``COUNTERS_EVERY_STEPS``-th step, an
        incarnation's first estimate (a restart shows at once) and the run's last step; else None."""
        if k % COUNTERS_EVERY_STEPS == 0 or self.counters.steps == 1 or (self.steps is not None and k >= self.steps - 1):
            return self.snapshot()
        return None

    # ------------------------------------------------------------------ fusing -> await_meas
    def _publish_round_one(self) -> None:
        """Share the own predicted pair for the step being fused as its round-1 message, and start the round."""
        own, s = self.own_pair, self._fusing()
        assert own is not None
        self.hold_until = None
        self.send("prior", RoundMessage(s, s * self.timing.ts, self.id, 1, own.blocks, self.clock(), own.warm).encode())
        self._start_round()

    def _start_round(self) -> None:
        """Round ``fuse_round`` of step ``fuse_step`` starts now, with its deadline (``node/timing.py``)."""
        s, now = self._fusing(), self.clock()
        self.round_started = now
        self.round_deadline = self.timing.round_deadline(now, s, self.fuse_round, self.tracker.rounds(s))

    def settle_until(self) -> float:
        """Realtime: the round being fused does not fuse before this (``CONFLICT_SETTLE_S`` after it started,
        at most a quarter of its time to the deadline), even with every neighbour's message in."""
        return self.round_started + min(CONFLICT_SETTLE_S, 0.25 * max(0.0, self.round_deadline - self.round_started))

    def _try_fuse(self, now: float) -> None:
        if self.hold_until is not None:
            if now < self.hold_until:
                return
            self._publish_round_one()
        s, rnd, policy = self._fusing(), self.fuse_round, self.policy
        received = self.buffers.priors.get((s, rnd), {})
        complete = self._expected_neighbours() <= policy.heard(received, self.own_pair)
        if self.mode == "realtime" and now < self.round_deadline and (not complete or now < self.settle_until()):
            return  # realtime: wait for every neighbour, and at least the settle time (node/fusion_policy.py)
        if not complete and self.mode != "realtime":
            return
        got, outvoted = policy.chosen((s, rnd), received, self.own_pair)
        self.counters.partial_rounds += not complete
        self.last_fused, next_pair = self.tracker.fuse(s, None if outvoted else self.own_pair, got, rnd)
        self.buffers.priors.pop((s, rnd), None)
        self.round_ms.append((self.clock() - self.round_started) * 1e3)
        if next_pair is not None:  # round rnd + 1 of the same step: share the rule's next message
            self.own_pair = next_pair
            self.send("prior", RoundMessage(s, s * self.timing.ts, self.id, rnd + 1, next_pair.blocks,
                                            self.clock()).encode())
            self.fuse_round = rnd + 1
            self._start_round()
            return
        self.last_round_ms, self.round_ms = self.round_ms, []
        self.fused_upto = s
        if self.mode == "realtime" and self.clock() > self.timing.start() + s * self.timing.ts:
            self.counters.misses += 1  # the step overran into the next sample period
            self._note_miss(s, "overran", self.clock() - self.timing.start() - s * self.timing.ts,
                            work_s=sum(self.last_round_ms) * 1e-3)
        self.buffers.drop_before(s + 1, priors_only=True)
        self.buffers.drop_before(s)
        self.own_pair = None
        self._enter(Phase.AWAIT_MEAS)
        self.step, self.fuse_step, self.fuse_round = s, None, 1
