"""The local step of a single-target tracker: its measurement in, the update, its estimate out.

The step waits for its own measurement (or, realtime, the coast deadline: predict only); a node that fell
behind (frozen, overloaded) skips to a step it can still make, predicting through the gap. Rules that exchange
scans forward the own scan and wait for the neighbours' (``AWAIT_SCANS``); the update takes them all, the
estimate goes out on ``est``, and rules with ``relay_scans`` relay the neighbours' scans and update the prior
with the two-hop ones once the relays are in (``AWAIT_RELAYS``, ``relays.py``). Then the rounds take over
(``rounds.py``). A measurement after a long gap, or a skip too long to predict through, goes to the warm start.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from zentrack.fusion.scan import Scan
from zentrack.node.context import NodeContext
from zentrack.node.counters import COUNTERS_EVERY_STEPS, Counters
from zentrack.node.detections import DetectionIntake
from zentrack.node.diffusion.admission import Arrival, Buffers
from zentrack.node.diffusion.relays import merge_relays, relayable, with_relayed
from zentrack.node.diffusion.rounds import Rounds
from zentrack.node.diffusion.state import StepState
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.diffusion.warm_start import WarmStart
from zentrack.node.phases import Phase
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.transport.codec import WireError
from zentrack.transport.messages import EstimateMessage
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan

log = logging.getLogger("zentrack.node")


class LocalStep:
    """Node ``ctx.id``'s local step (module docstring); ``relay``: a node without a sensor."""

    def __init__(self, ctx: NodeContext, state: StepState, tracker: Tracker, buffers: Buffers, counters: Counters,
                 rounds: Rounds, warm: WarmStart, relay: bool, snapshot: Callable[[], dict],
                 intake: DetectionIntake | None = None) -> None:
        self.ctx, self.state, self.tracker, self.buffers, self.counters = ctx, state, tracker, buffers, counters
        self.rounds, self.warm, self.relay, self.snapshot = rounds, warm, relay, snapshot
        self.exchange = tracker.rule.exchanges_scans
        #: sensors of their own (``node/detections.py``): step k takes the detections of its window
        self.intake = intake

    def log_start(self, participants: int) -> None:
        log.info("node %d: cold start, %d participants", self.ctx.id, participants)

    # ------------------------------------------------------------------ await_meas -> [await_scans]
    def try_step(self, now: float) -> None:
        ctx, state, timing = self.ctx, self.state, self.ctx.timing
        k = state.step
        if ctx.steps is not None and k >= ctx.steps:
            return  # the run is over; wait for ctl/stop
        if ctx.realtime and now > timing.deadline(k):
            # we fell behind (frozen, overloaded): skip to a step we can still make, predicting through the gap
            k_now = timing.k_now(now)
            target = k_now if now < timing.deadline(k_now) - COAST_MARGIN_S else k_now + 1
            self.counters.misses += target - k  # every skipped step is a missed deadline
            state.note_miss(k, "skipped", now - timing.deadline(k), ctx.idle_s, target - k)
            log.warning("node %d: behind by %d step(s); skipping to step %d", ctx.id, target - k, target)
            self.buffers.drop_before(target)
            state.coast_run += target - k
            if self.tracker.catch_up(target) and not self.rounds.stale:
                state.step = target
                return
            self.warm.start_warming(now)
            return
        if self.intake is not None:
            if now >= timing.start() + k * timing.ts:  # the window and the lag after it are over
                self.window_step(k, now)
            return
        m = self.buffers.meas.pop(k, None)
        if m is None:
            if ctx.realtime and now >= timing.deadline(k) - COAST_MARGIN_S:
                self.measured(k, None, now)  # coast: predict only
            return
        if self.rounds.stale:
            # a measurement after a long gap: our prior is only a prediction, so rejoin through the warm-up
            # (the neighbours' fresh pairs if there are any) instead of publishing one very wrong posterior
            self.warm.start_warming(now)
            return
        self.measured(k, m, now)

    def window(self, k: int) -> tuple[float, float]:
        """Sensors of their own: step k's window of measurement times on the tracker's clock, ``[t_(k-1), t_k)``
        (step 0: none; the prior of step k is valid at its start, the estimate of step k at its end)."""
        timing = self.ctx.timing
        assert timing.t0 is not None
        t_to = timing.t0 + k * timing.ts
        return (t_to - timing.ts if k > 0 else t_to), t_to

    def window_step(self, k: int, now: float) -> None:
        """Sensors of their own: the detections of step k's window in time order, each at its own time, then the
        prediction to the window's end: the estimate of step k (published) and the round-1 message for k + 1."""
        assert self.intake is not None
        if self.rounds.stale and self.intake.pending():
            self.warm.start_warming(now)  # detections after a long gap: rejoin through the warm-up
            return
        ctx, state, tracker, counters = self.ctx, self.state, self.tracker, self.counters
        t_start = ctx.clock()
        t_from, t_to = self.window(k)
        taken = self.intake.take(t_from, t_to)
        timed = [(d.t, Scan(k, d.det.sensor, d.det.returns, d.det.pose, d.det.noise_cov)) for d in taken
                 if d.det.returns.shape[0] > 0 and not self.relay]
        est = tracker.update_over(t_from, t_to, timed)
        update_us = (ctx.clock() - t_start) * 1e6
        coasted = not timed and not self.relay
        counters.coasted += coasted
        state.coast_run = state.coast_run + 1 if coasted else 0
        counters.steps += 1
        last = taken[-1] if taken else None
        # (the detection's publication time on the tracker's clock: its sensor's offset taken off, as its time's)
        t_det_pub = None if last is None else last.det.t_pub - (self.intake.offset(last.det.sensor) or 0.0)
        self.publish_estimate(k, est, update_us, coasted, t_det_pub, None if last is None else last.t_recv)
        self.rounds.share_prior(est, k, predicted=True)

    def measured(self, k: int, m: Arrival | None, now: float) -> None:
        """Step k's own measurement message is in (or the node coasts): update now, or first forward the scan
        and wait for the neighbours' (rules that exchange scans)."""
        if not self.exchange:
            self.local_step(k, m, now, [])
            return
        ctx = self.ctx
        t = k * ctx.timing.ts
        if m is None or self.relay or m.meas.returns is None:  # nothing to forward: say so, nobody need wait
            scan = ForwardedScan(k, t, ctx.id, ctx.id, None, None, None, ctx.clock())
        else:
            pose = self.tracker.sensor_position if m.meas.pose is None else m.meas.pose
            scan = ForwardedScan(k, t, ctx.id, ctx.id, m.meas.returns, pose, self.tracker.noise_cov, ctx.clock())
        ctx.send("scan", scan.encode())
        self.state.pending = m
        self.state.enter(Phase.AWAIT_SCANS)
        self.try_scans(now)

    def try_scans(self, now: float) -> None:
        state, buffers = self.state, self.buffers
        k = state.step
        if not self.rounds.expected() <= set(buffers.fwd.get(k)) and not (
                self.ctx.realtime and now >= self.ctx.timing.scan_deadline(k, self.tracker.rounds(k + 1))):
            return
        got = buffers.fwd.take(k)
        # a forwarded scan carries returns, pose and noise together, or none of them ("no scan")
        extra = [Scan(k, sc.origin, sc.returns, sc.pose, sc.noise_cov) for _, sc in sorted(got.items())
                 if sc.returns is not None and sc.pose is not None and sc.noise_cov is not None]
        m, state.pending = state.pending, None
        self.local_step(k, m, now, extra)

    # ------------------------------------------------------------------ update, estimate -> [await_relays] -> fusing
    def local_step(self, k: int, m: Arrival | None, now: float, forwarded: list[Scan]) -> None:
        """Local update with the own scan and any forwarded ones, then publish the estimate and round 1."""
        ctx, state = self.ctx, self.state
        t_start = ctx.clock()
        tracker, counters, ts = self.tracker, self.counters, ctx.timing.ts
        returns = None if m is None else m.meas.returns
        scans = [] if m is None or returns is None or self.relay else [tracker.scan(k, returns, m.meas.pose)]
        post = tracker.update(scans + forwarded)
        update_us = (ctx.clock() - t_start) * 1e6
        coasted = returns is None and not self.relay
        counters.coasted += coasted
        state.coast_run = state.coast_run + 1 if coasted else 0
        counters.steps += 1
        self.publish_estimate(k, post, update_us, coasted, None if m is None else m.meas.t_pub,
                              None if m is None else m.t_recv)
        if tracker.rule.relays_scans:  # relay the neighbours' scans, then share with the two-hop ones
            relayed = tuple(RelayedScan(s.sensor, s.returns, s.pose, s.noise_cov) for s in relayable(forwarded))
            payload, left_out = Relay(k, k * ts, ctx.id, relayed, ctx.clock()).encode_capped()
            counters.relay_left_out += left_out  # scans that did not fit in one message
            ctx.send("scan", payload)
            state.core_scans, state.post = scans + forwarded, post
            state.enter(Phase.AWAIT_RELAYS)
            self.try_relays(now)
            return
        self.rounds.share_prior(post, k)

    def publish_estimate(self, k: int, post: Any, update_us: float, coasted: bool, t_meas_pub: float | None,
                         t_recv: float | None) -> None:
        """Step k's estimate on ``est``: the kinematic part of ``post`` with its timings, flags and counters;
        one that comes after the step's deadline counts as a miss."""
        ctx, state, tracker, ts = self.ctx, self.state, self.tracker, self.ctx.timing.ts
        kin = tracker.kinematic(post)
        t_pub = ctx.clock()
        miss = ctx.realtime and t_pub > ctx.timing.deadline(k)
        self.counters.misses += miss
        if miss:
            state.note_miss(k, "late_estimate", t_pub - ctx.timing.deadline(k), ctx.idle_s, work_s=update_us * 1e-6)
        notes, state.miss_notes = tuple(state.miss_notes), []
        diagnostics = tracker.diagnostics(post)
        ctx.send("est", EstimateMessage(
            k, k * ts, ctx.id, kin.mean, kin.cov, t_pub, t_meas_pub=t_meas_pub, t_recv=t_recv, update_us=update_us,
            fused=state.last_fused, coasted=coasted, warm=state.warm_next, miss=bool(miss),
            neighbours=tuple(sorted(self.rounds.expected())),
            round_ms=np.asarray(state.last_round_ms, dtype=float) if state.last_round_ms else None,
            samples=diagnostics.get("samples"), beta=diagnostics.get("beta"), counters=self._counters(k),
            miss_notes=notes,
        ).encode())
        state.last_round_ms = []
        state.warm_next = False

    def try_relays(self, now: float) -> None:
        """Once every live neighbour's relay is in (or at the relay deadline): the prior updated with the
        own, the neighbours' and the relayed two-hop scans is what this node shares (``relays.py``)."""
        ctx, state, buffers = self.ctx, self.state, self.buffers
        k = state.step
        complete = self.rounds.expected() <= set(buffers.relayed.get(k))
        if not complete and not (ctx.realtime and now >= ctx.timing.relay_deadline(k, self.tracker.rounds(k + 1))):
            return
        got = buffers.relayed.take(k)
        self.counters.partial_relays += not complete
        have = {s.sensor for s in state.core_scans} | {ctx.id, *self.tracker.neighbours}
        relays = {sender: [Scan(k, sc.origin, sc.returns, sc.pose, sc.noise_cov) for sc in relay.scans]
                  for sender, relay in got.items()}
        merged = merge_relays(relays, have)
        for origin in merged.disputed:
            ctx.rejects.add("scan", WireError("conflict", f"relays of step {k} carry two different scans of node "
                                                          f"{origin}; neither is used"))
        post, scans = state.post, state.core_scans
        assert post is not None  # set with the phase
        state.core_scans, state.post = [], None
        if merged.extra:
            post = self.tracker.update(with_relayed(scans, merged.extra, ctx.id))
        self.rounds.share_prior(post, k)

    def _counters(self, k: int) -> dict[str, Any] | None:
        """The counters' snapshot on the estimates that carry them: every ``COUNTERS_EVERY_STEPS``-th step, an
        incarnation's first estimate (a restart shows at once) and the run's last step; else None."""
        steps = self.ctx.steps
        if k % COUNTERS_EVERY_STEPS == 0 or self.counters.steps == 1 or (steps is not None and k >= steps - 1):
            return self.snapshot()
        return None
