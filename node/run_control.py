"""A tracker's view of the run: who is alive (liveliness tokens), the run's start and its stop.

- **Liveliness**: the tokens update the context's membership (``node/context.py``: whose messages a step waits
  for).
- **Start**: the first ``ctl/start`` fixes t0, the timing, the participants and the initial estimate; later
  ones (truth re-sends it when a node joins, a restarted truth resumes) may only repeat it.
- **Stop**: a stop once the run is over ends the node. One before that (the truth interrupted or aborting, or
  a forgery) waits up to :data:`STOP_CONFIRM_S` for the truth's liveliness token to go, as it does when the
  truth really ends; if the truth is still there the stop is refused (``conflict``). A realtime run whose truth
  has gone (killed, and not back) sends no stop: the node stops by itself once the run is over (a tracker with
  sensors of its own tracks without the truth to the end).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from zentrack.node.context import NodeContext
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.transport.codec import WireError
from zentrack.transport.messages import Start, Stop

log = logging.getLogger("zentrack.node")

#: how long a stop before the run's end waits for the truth's liveliness token to go before it is refused
STOP_CONFIRM_S = 3.0


def start_conflicts(start: Start, run: Start) -> list[str]:
    """The fields in which ``start`` differs from the run's start ``run`` (none for a repeat)."""
    diff = [key for key in ("t0", "ts", "steps", "mode", "deadline_frac") if getattr(start, key) != getattr(run, key)]
    if sorted(start.participants) != sorted(run.participants):
        diff.append("participants")
    if not np.array_equal(start.x0, run.x0):
        diff.append("x0")
    return diff


@dataclass
class StopConfirm:
    """A stop received before the run's end, waiting for the truth to leave."""

    pending_since: float | None = None

    def decide(self, run_over: bool, truth_alive: bool, now: float) -> str:
        """What a waiting stop does now: ``"stop"`` (the truth left, or the run is over), ``"refuse"`` (the
        truth is still there after :data:`STOP_CONFIRM_S`) or ``"wait"``; ``"none"`` without a stop pending."""
        if self.pending_since is None:
            return "none"
        if not truth_alive or run_over:
            return "stop"
        if now - self.pending_since > STOP_CONFIRM_S:
            self.pending_since = None
            return "refuse"
        return "wait"


class RunControl:
    """The start, stop and liveliness handling of a tracker's schedule (single- and many-target): the part of
    :class:`~zentrack.node.schedule.NodeSchedule` that reads ``ctl/start``, ``ctl/stop`` and the tokens."""

    def __init__(self, ctx: NodeContext) -> None:
        self.ctx = ctx
        self.stop_confirm = StopConfirm()
        self.stopped = False
        self.start_payload: bytes | None = None  #: truth's ctl/start as received, served to a restarted truth

    def check_start(self, start: Start) -> bool:
        """True for the run's first start; False for a repeat of it (truth re-sends it when a node joins, a
        restarted truth resumes it); WireError for one of another mode or one that contradicts the run."""
        ctx = self.ctx
        if start.mode != ctx.mode:
            raise WireError("schema", f"run mode {start.mode} differs from this node's {ctx.mode}")
        if ctx.start is None:
            return True
        diff = start_conflicts(start, ctx.start)  # one that moves t0, the timing, the participants or x0
        if diff:
            raise WireError("conflict", f"a start that contradicts the run under way ({', '.join(diff)})")
        return False

    def take_start(self, start: Start, payload: bytes) -> bool:
        """The run's first start fixes t0, the period, the steps and the participants; True if it starts fresh
        (lockstep, or before step 0's coast deadline), else the node joins the run under way."""
        ctx, timing = self.ctx, self.ctx.timing
        timing.t0, ctx.steps, timing.ts = start.t0, start.steps, start.ts
        ctx.participants, ctx.start, self.start_payload = set(start.participants), start, payload
        return ctx.lockstep or ctx.clock() < timing.deadline(0) - COAST_MARGIN_S

    def on_stop(self, payload: bytes, step: int) -> None:
        """ctl/stop (module docstring): at once once the run is over or the truth is gone, else once the truth
        leaves."""
        Stop.decode(payload)  # a stop message from the truth, or WireError
        ctx = self.ctx
        if self.run_over(step) or not ctx.members.truth_alive:
            log.info("node %d: stop received", ctx.id)
            self.stopped = True
        elif self.stop_confirm.pending_since is None:
            log.info("node %d: stop received before the run's end; stopping if the truth leaves", ctx.id)
            self.stop_confirm.pending_since = ctx.clock()

    def run_over(self, step: int) -> bool:
        """Whether the run is over for a node at ``step``: lockstep, its last step is done; realtime, the last
        step's deadline has passed."""
        ctx = self.ctx
        if ctx.timing.t0 is None or ctx.steps is None:
            return False
        if ctx.lockstep:
            return step >= ctx.steps
        return ctx.clock() >= ctx.timing.deadline(ctx.steps - 1)

    def check_pending_stop(self, step: int) -> None:
        """A stop received before the run's end, once the truth has left or the run is over; and the run's end
        when the truth has gone, which sends no stop (module docstring)."""
        ctx = self.ctx
        if ctx.realtime and ctx.members.truth_gone_since is not None and not self.stopped and self.run_over(step):
            log.info("node %d: the run is over and the truth is gone (no stop will come); stopping", ctx.id)
            self.stopped = True
            return
        if self.stop_confirm.pending_since is None:
            return
        action = self.stop_confirm.decide(self.run_over(step), ctx.members.truth_alive, ctx.clock())
        if action == "stop":
            log.info("node %d: the truth left after its stop; stopping", ctx.id)
            self.stopped = True
        elif action == "refuse":
            ctx.rejects.add("stop", WireError("conflict", "a stop before the run's end while the truth is still there"))

    def on_alive(self, key: str, present: bool) -> None:
        ctx = self.ctx
        node = ctx.keys.node_of(key)
        if node is not None:
            ctx.members.node_token(node, present)
        elif ctx.keys.last_segment(key) == "truth":
            ctx.members.truth_token(present, ctx.clock())
