"""A tracker's view of the run: who is alive (liveliness tokens), the run's start and its stop.

- **Membership**: a node waits for its live neighbours in realtime; in lockstep for every participating
  neighbour that has not left, whether or not its token has reached it yet (right after the start a
  neighbour's scan or pair can arrive before its token, and skipping it would change the numbers).
- **Start**: the first ``ctl/start`` fixes t0, the timing, the participants and the initial estimate; later
  ones (truth re-sends it when a node joins, a restarted truth resumes) may only repeat it.
- **Stop**: a stop once the run is over ends the node. One before that (the truth interrupted or aborting, or
  a forgery) waits up to :data:`STOP_CONFIRM_S` for the truth's liveliness token to go, as it does when the
  truth really ends; if the truth is still there the stop is refused (``conflict``).
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from zentrack.node.counters import RejectLog
from zentrack.node.timing import StepTiming
from zentrack.transport.codec import WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Start, Stop

log = logging.getLogger("zentrack.node")

#: how long a stop before the run's end waits for the truth's liveliness token to go before it is refused
STOP_CONFIRM_S = 3.0


@dataclass
class Membership:
    """Which nodes' liveliness tokens are present, which went away, and whether the truth is there."""

    live: set[int] = field(default_factory=set)
    gone: set[int] = field(default_factory=set)  #: nodes whose token went away (and has not come back)
    truth_alive: bool = False
    truth_gone_since: float | None = None

    def node_token(self, node: int, present: bool) -> None:
        (self.live.add if present else self.live.discard)(node)
        (self.gone.discard if present else self.gone.add)(node)

    def truth_token(self, present: bool, now: float) -> None:
        # after a freeze or a cut link every token looks gone for a moment: only a lasting absence counts
        self.truth_alive = present
        self.truth_gone_since = None if present else now

    def expected(self, neighbours: list[int], participants: set[int] | None, lockstep: bool) -> set[int]:
        """Whose messages to wait for (module docstring)."""
        if lockstep and participants is not None:
            return (set(neighbours) & participants) - self.gone
        return set(neighbours) & self.live


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


class ControlledRun:
    """The stop and liveliness handling every tracker schedule shares (single- and many-target): a mixin over the
    schedule's ``id``, ``mode``, ``step``, ``steps``, ``timing``, ``members``, ``stop_confirm``, ``rejects``,
    ``keys``, ``clock`` and ``stopped``."""

    id: int
    mode: str
    step: int
    steps: int | None
    stopped: bool
    members: Membership
    stop_confirm: StopConfirm
    timing: StepTiming
    rejects: RejectLog
    keys: Keys
    clock: Callable[[], float]

    def _on_stop(self, payload: bytes) -> None:
        """ctl/stop (``node/run_control.py``): at once once the run is over or the truth is gone, else once the
        truth leaves."""
        Stop.decode(payload)  # a stop message from the truth, or WireError
        if self._run_over() or not self.members.truth_alive:
            log.info("node %d: stop received", self.id)
            self.stopped = True
        elif self.stop_confirm.pending_since is None:
            log.info("node %d: stop received before the run's end; stopping if the truth leaves", self.id)
            self.stop_confirm.pending_since = self.clock()

    def _run_over(self) -> bool:
        if self.timing.t0 is None or self.steps is None:
            return False
        if self.mode == "lockstep":
            return self.step >= self.steps
        return self.clock() >= self.timing.deadline(self.steps - 1)

    def _check_pending_stop(self) -> None:
        if self.stop_confirm.pending_since is None:
            return
        action = self.stop_confirm.decide(self._run_over(), self.members.truth_alive, self.clock())
        if action == "stop":
            log.info("node %d: the truth left after its stop; stopping", self.id)
            self.stopped = True
        elif action == "refuse":
            self.rejects.add("stop", WireError("conflict", "a stop before the run's end while the truth is still there"))

    def _on_alive(self, key: str, present: bool) -> None:
        node = self.keys.node_of(key)
        if node is not None:
            self.members.node_token(node, present)
        elif self.keys.last_segment(key) == "truth":
            self.members.truth_token(present, self.clock())

