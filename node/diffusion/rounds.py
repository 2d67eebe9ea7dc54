"""The fusion rounds of a single-target tracker: share the own message, fuse the neighbours' once they are in.

After the local step the time update of the posterior is the node's round-1 message for step k + 1, shared at
once or held until step k's deadline when fusion follows it (``node/timing.py``). Each round fuses once every
live neighbour's message is in (realtime: after a short settle time, so a conflicting copy can still come) or
at the round's deadline; a rule with more rounds shares its next message and starts the next round. The
fusion policy chooses which messages a round takes (``fusion_policy.py``). A round fused without every live
neighbour's message counts as ``partial_rounds``; a step whose fusion ends after the next sample is a miss.
"""
from __future__ import annotations

from zentrack.fusion.estimates import Estimate
from zentrack.node.context import NodeContext
from zentrack.node.counters import Counters
from zentrack.node.diffusion.admission import Buffers
from zentrack.node.diffusion.fusion_policy import CONFLICT_SETTLE_S, FusionPolicy
from zentrack.node.diffusion.neighbour_clocks import prior_valid_at
from zentrack.node.diffusion.state import StepState
from zentrack.node.diffusion.tracker import MAX_COAST_STEPS, Tracker
from zentrack.node.phases import Phase
from zentrack.transport.messages import RoundMessage


class Rounds:
    """Node ``ctx.id``'s fusion rounds (module docstring)."""

    def __init__(self, ctx: NodeContext, state: StepState, tracker: Tracker, buffers: Buffers, counters: Counters,
                 policy: FusionPolicy) -> None:
        self.ctx, self.state, self.tracker = ctx, state, tracker
        self.buffers, self.counters, self.policy = buffers, counters, policy
        #: steps without a measurement after which the own prior is stale (sensors of their own that sample
        #: slower than the run allow for their period on top: ``DiffusionPayload``)
        self.max_coast_steps = MAX_COAST_STEPS
        #: sensors of their own: the tracker runs on its own clock, its prior of step s valid at the start of
        #: window s (``neighbour_clocks.py``)
        self.own_clock = False

    def valid_at(self, s: int) -> float:
        """When this tracker's message for step ``s`` is valid, after ``t0`` (the message's ``t``): on its own
        clock, the start of window s; else the step's sample time."""
        ts = self.ctx.timing.ts
        return prior_valid_at(s, ts) if self.own_clock else s * ts

    @property
    def stale(self) -> bool:
        """Too long without a measurement: the own prior is only a prediction (realtime; in lockstep every
        node steps through its gaps exactly as the batched simulator does)."""
        return self.ctx.realtime and self.state.coast_run > self.max_coast_steps

    def expected(self) -> set[int]:
        """Whose messages the step waits for (``node/run_control.py``: membership)."""
        return self.ctx.expected(self.tracker.neighbours)

    def share_prior(self, post: Estimate, k: int, predicted: bool = False) -> None:
        """The time update of ``post`` is this node's round-1 message for step k + 1: shared at once, or held
        until step k's deadline when fusion follows it (``predicted``: ``post`` is that already, sensors of
        their own)."""
        state, timing = self.state, self.ctx.timing
        own = self.tracker.predict_pair(post, k + 1, predicted)
        own.warm = self.stale
        state.own_pair = own
        state.round_ms = []
        state.enter(Phase.FUSING)
        state.fuse_step, state.fuse_round = k + 1, 1
        if timing.fusion_after_deadline() and self.ctx.clock() < timing.deadline(k):
            state.hold_until = timing.deadline(k)  # round 1 goes out at the deadline (try_fuse)
            return
        self.publish_round_one()

    def publish_round_one(self) -> None:
        """Share the own predicted pair for the step being fused as its round-1 message, and start the round."""
        state, ctx = self.state, self.ctx
        own, s = state.own_pair, state.fusing()
        assert own is not None
        state.hold_until = None
        ctx.send("prior", RoundMessage(s, self.valid_at(s), ctx.id, 1, own.blocks, ctx.clock(), own.warm).encode())
        self.start_round()

    def start_round(self) -> None:
        """Round ``fuse_round`` of step ``fuse_step`` starts now, with its deadline (``node/timing.py``)."""
        state, now = self.state, self.ctx.clock()
        s = state.fusing()
        state.round_started = now
        state.round_deadline = self.ctx.timing.round_deadline(now, s, state.fuse_round, self.tracker.rounds(s))

    def settle_until(self) -> float:
        """Realtime: the round being fused does not fuse before this (``CONFLICT_SETTLE_S`` after it started,
        at most a quarter of its time to the deadline), even with every neighbour's message in."""
        state = self.state
        return state.round_started + min(CONFLICT_SETTLE_S, 0.25 * max(0.0, state.round_deadline - state.round_started))

    def try_fuse(self, now: float) -> None:
        state, ctx, policy = self.state, self.ctx, self.policy
        if state.hold_until is not None:
            if now < state.hold_until:
                return
            self.publish_round_one()
        s, rnd = state.fusing(), state.fuse_round
        received = self.buffers.priors.get((s, rnd), {})
        complete = self.expected() <= policy.heard(received, state.own_pair)
        if ctx.realtime and now < state.round_deadline and (not complete or now < self.settle_until()):
            return  # realtime: wait for every neighbour, and at least the settle time (fusion_policy.py)
        if not complete and not ctx.realtime:
            return
        got, outvoted = policy.chosen((s, rnd), received, state.own_pair)
        self.counters.partial_rounds += not complete
        state.last_fused, next_pair = self.tracker.fuse(s, None if outvoted else state.own_pair, got, rnd)
        self.buffers.priors.pop((s, rnd), None)
        state.round_ms.append((ctx.clock() - state.round_started) * 1e3)
        if next_pair is not None:  # round rnd + 1 of the same step: share the rule's next message
            state.own_pair = next_pair
            ctx.send("prior", RoundMessage(s, self.valid_at(s), ctx.id, rnd + 1, next_pair.blocks,
                                           ctx.clock()).encode())
            state.fuse_round = rnd + 1
            self.start_round()
            return
        state.last_round_ms, state.round_ms = state.round_ms, []
        state.fused_upto = s
        sample = ctx.timing.start() + s * ctx.timing.ts
        if ctx.realtime and ctx.clock() > sample:
            self.counters.misses += 1  # the step overran into the next sample period
            state.note_miss(s, "overran", ctx.clock() - sample, ctx.idle_s, work_s=sum(state.last_round_ms) * 1e-3)
        self.buffers.drop_before(s + 1, priors_only=True)
        self.buffers.drop_before(s)
        state.own_pair = None
        state.enter(Phase.AWAIT_MEAS)
        state.step, state.fuse_step, state.fuse_round = s, None, 1
