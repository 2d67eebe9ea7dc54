"""How a warming tracker rejoins: the choice it makes at the end of each fusion window.

A node warms when it has no usable prior (a restart) or a stale one (more than ``MAX_COAST_STEPS`` without a
measurement: a freeze, a cut link, a truth or router stall). While warming it publishes its own (stale)
prediction every step flagged ``warm``, if it has one. At the end of the fusion window it takes, in this order:

1. the neighbours' fresh pairs (``WARM_START``): their estimates beat its stale prediction;
2. its own prediction fused with the warm pairs that arrived (``RESUME_OWN``), once one has arrived: with
   none, it first waits up to ``RESUME_ALONE_AFTER_S`` (at least a step) for its neighbours' pairs. A node back
   from a freeze or a cut finds its links closed by its peers' lease and re-opening; resuming at once from its
   own prediction (seconds old) published estimates 150 m off in the loaded soak, where its neighbours' fresh
   pairs came a few steps later;
3. with no state of its own, the warm pairs (``WARM_START_FROM_WARMING``);
4. nothing: it tries again at the next step, and after ``cold_after`` empty steps (or at once with no
   neighbours) takes the configured initial prior (``COLD_START``).

So a network in which every node warms at once recovers at the first window's end: every node that has a
state fuses its own pair with its neighbours' warm ones.
"""
from __future__ import annotations

import logging
import math
from enum import Enum

from zentrack.node.context import NodeContext
from zentrack.node.counters import Counters
from zentrack.node.diffusion.admission import Buffers
from zentrack.node.diffusion.fusion_policy import FusionPolicy
from zentrack.node.diffusion.rounds import Rounds
from zentrack.node.diffusion.state import StepState
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.phases import Phase
from zentrack.transport.messages import RoundMessage

log = logging.getLogger("zentrack.node")

#: a warming node with no state of its own that hears nothing for this many steps cold-starts
COLD_AFTER_STEPS = 20
#: a warming node with a state of its own but no neighbour's pair waits this long for one before it resumes alone
RESUME_ALONE_AFTER_S = 1.0


class WarmChoice(Enum):
    WARM_START = "warm start from the neighbours' fresh pairs"
    RESUME_OWN = "resumed from its own prediction and the warm pairs"
    WARM_START_FROM_WARMING = "warm start from warming neighbours' pairs"
    COLD_START = "cold start: no neighbour has a state"
    WAIT = "nothing to start from yet"


def warm_choice(fresh: int, own: bool, warm: int, neighbours: int, empty_steps: int, cold_after: int,
                alone_after: int = 0) -> WarmChoice:
    """The choice (module docstring) from how many fresh and warm pairs came (``fresh``, ``warm``: all the
    pairs chosen, fresh ones included), whether the node has its own prediction, how many neighbours it has,
    for how many steps it has waited with nothing, and after how many such steps it resumes alone."""
    if fresh:
        return WarmChoice.WARM_START
    if own and (warm or not neighbours or empty_steps >= alone_after):
        return WarmChoice.RESUME_OWN
    if warm:
        return WarmChoice.WARM_START_FROM_WARMING
    if not neighbours or empty_steps >= cold_after:
        return WarmChoice.COLD_START
    return WarmChoice.WAIT


class WarmStart:
    """A warming node's transitions (module docstring) on the step's state."""

    def __init__(self, ctx: NodeContext, state: StepState, tracker: Tracker, buffers: Buffers, counters: Counters,
                 policy: FusionPolicy, rounds: Rounds, cold_after: int = COLD_AFTER_STEPS) -> None:
        self.ctx, self.state, self.tracker, self.buffers, self.counters = ctx, state, tracker, buffers, counters
        self.policy, self.rounds, self.cold_after = policy, rounds, cold_after

    def start_warming(self, now: float) -> None:
        """Enter the warm-up: the next step to fuse is the first whose deadline is still ahead."""
        state, timing = self.state, self.ctx.timing
        state.enter(Phase.WARMING)
        state.own_pair = None
        state.hold_until = None
        state.fuse_round = 1
        if timing.t0 is not None:
            k_now = timing.k_now(now)
            state.step = k_now if now < timing.deadline(k_now) else k_now + 1
            state.fuse_step = state.step + 1
            self.publish_warm_pair()

    def publish_warm_pair(self) -> None:
        """Share our own prediction for the step we are about to fuse (if we have one), flagged warm."""
        ctx, state, timing = self.ctx, self.state, self.ctx.timing
        s = state.fuse_step
        if s is None or state.warm_published == s:
            return
        if timing.realtime and ctx.clock() < timing.start() - timing.budget + (s - 1) * timing.ts:
            return  # not before step s - 1 is sampled: earlier, the neighbours refuse it as early (admission)
        pair = self.tracker.own_pair(s)
        if pair is not None:
            state.warm_published = s
            ctx.send("prior", RoundMessage(s, self.rounds.valid_at(s), ctx.id, 1, pair.blocks, ctx.clock(),
                                           True).encode())

    def try_warm(self, now: float) -> None:
        """At the end of the fusion window (or once every neighbour's pair is in): the choice of the module
        docstring."""
        ctx, state, tracker = self.ctx, self.state, self.tracker
        if ctx.timing.t0 is None:
            return
        if state.fuse_step is None:
            self.start_warming(now)
        s = state.fusing()
        self.publish_warm_pair()
        received = self.buffers.priors.get((s, 1), {})
        heard = set(received)
        # the neighbours' fresh pairs for s come during its fusion window (from the deadline of s - 1 when fusion
        # waits for it): a warming node decides at the window's end, not before they can have come
        window_over = ctx.realtime and now >= ctx.timing.fusion_window_end(s)
        if not window_over and not (heard and self.rounds.expected() <= heard):
            return
        got, _ = self.policy.chosen((s, 1), received, None)  # nothing to gate against: only conflicting copies go
        fresh = {j: p for j, p in got.items() if not p.warm}
        own = tracker.own_pair(s)
        alone_after = min(self.cold_after, max(1, math.ceil(RESUME_ALONE_AFTER_S / ctx.timing.ts - 1e-9)))
        choice = warm_choice(len(fresh), own is not None, len(got), len(tracker.neighbours),
                             state.empty_warm_steps, self.cold_after, alone_after)
        # a warm start takes round 1 only: the node rejoins the rounds at the next step
        if choice is WarmChoice.WARM_START:
            state.last_fused = tracker.fuse(s, None, fresh, final=True)[0]
            self.counters.warm_starts += 1
            how = f"warm start from {len(fresh)} neighbour(s)"
        elif choice is WarmChoice.RESUME_OWN:
            state.last_fused = tracker.fuse(s, own, got, final=True)[0]
            self.counters.warm_self += 1
            how = f"resumed from its own prediction and {len(got)} warm pair(s)"
        elif choice is WarmChoice.WARM_START_FROM_WARMING:
            state.last_fused = tracker.fuse(s, None, got, final=True)[0]
            self.counters.warm_starts += 1
            how = f"warm start from {len(got)} warming neighbour(s)"
        elif choice is WarmChoice.COLD_START:
            tracker.cold_start(s)
            state.last_fused = 0
            self.counters.cold_restarts += 1
            how = choice.value
        else:
            if window_over:  # nothing to start from yet: try the next step
                state.empty_warm_steps += 1
                self.buffers.drop_before(s + 1, priors_only=True)
                state.fused_upto = s
                state.step, state.fuse_step = s, s + 1
                self.publish_warm_pair()
            return
        state.fused_upto = s
        state.empty_warm_steps = 0
        state.coast_run = 0
        state.warm_next = True
        log.info("node %d: step %d: %s", ctx.id, s, how)
        buffers = self.buffers
        buffers.drop_before(s + 1, priors_only=True)
        buffers.drop_before(s)
        buffers.fwd.done_upto, buffers.relayed.done_upto = min(buffers.fwd.done_upto, s - 1), min(buffers.relayed.done_upto, s - 1)
        state.enter(Phase.AWAIT_MEAS)
        state.step, state.fuse_step, state.fuse_round = s, None, 1
