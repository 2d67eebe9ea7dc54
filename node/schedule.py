"""A tracker's schedule as a state machine free of I/O: the one core every tracker runs, driving its payload.

:class:`NodeSchedule` is fed messages (:meth:`~NodeSchedule.handle`) and wake-ups (:meth:`~NodeSchedule.advance`);
the time comes from an injected clock and every publication goes through an injected ``send(channel,
payload)``, so the whole schedule runs in unit tests without Zenoh (``node/process.py`` only moves bytes).
It holds its parts as objects and calls them:

- ``context.py``: who the node is, its clock, timing (``timing.py``), membership and what it refused;
- ``run_control.py``: the run's start, its stop and the liveliness tokens;
- the payload (``payload.py``): what a step does. One target, ``diffusion/``: scans, rounds of covariance
  intersection, relays and warm start; many targets, ``track_lists/``: a multi-target tracker and track lists.

The schedule keeps the messages that come before ``ctl/start`` (a few steps' worth) and hands them to the
payload when it comes; it wakes the payload when its phase's deadline is due, and notes how late a wake-up came
(a frozen or starved process), which the payload reports with its deadline misses.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Generic, TypeVar

from zentrack.config.node_config import NodeConfig
from zentrack.node.context import NodeContext
from zentrack.node.diffusion.payload import DiffusionPayload
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.payload import Payload
from zentrack.node.run_control import RunControl
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Start

if TYPE_CHECKING:  # a single-target tracker never loads the many-target modules (SciPy's assignment solver)
    from zentrack.node.track_lists.payload import TrackListPayload

__all__ = ["EARLY_KEPT", "NodeSchedule"]

log = logging.getLogger("zentrack.node")

#: data messages kept while the start is not known yet
EARLY_KEPT = 256
#: the longest and the shortest wait for a message between timed actions
MAX_WAIT_S, MIN_WAIT_S = 0.2, 0.001


P = TypeVar("P", bound=Payload)


class NodeSchedule(Generic[P]):
    """Node ``ctx.id``'s schedule: the run's control around ``payload``'s steps (module docstring)."""

    def __init__(self, ctx: NodeContext, payload: P) -> None:
        self.ctx, self.payload = ctx, payload
        self.run = RunControl(ctx)
        self.early: list[Message] = []  #: data messages that came before the start
        self.wake_due: float | None = None  #: when the loop meant to wake (clock)

    @staticmethod
    def diffusion(keys: Keys, cfg: NodeConfig, tracker: Tracker, clock: Callable[[], float],
                  send: Callable[[str, bytes], None], incarnation: int = 0,
                  **options) -> NodeSchedule[DiffusionPayload]:
        """A single-target node: ``tracker`` (``node/diffusion/tracker.py``) under the diffusion payload;
        ``options``: ``cold_after`` (the payload's) and ``fusion_after_deadline`` (the timing's)."""
        ctx = NodeContext.of(keys, cfg, clock, send, incarnation, options.pop("fusion_after_deadline", None))
        return NodeSchedule(ctx, DiffusionPayload(ctx, cfg, tracker, **options))

    @staticmethod
    def track_lists(keys: Keys, cfg: NodeConfig, clock: Callable[[], float], send: Callable[[str, bytes], None],
                    incarnation: int = 0) -> NodeSchedule[TrackListPayload]:
        """A many-target node: a multi-target tracker whose track lists the neighbours fuse."""
        from zentrack.node.track_lists.payload import TrackListPayload

        ctx = NodeContext.of(keys, cfg, clock, send, incarnation)
        return NodeSchedule(ctx, TrackListPayload(ctx, cfg))

    # ------------------------------------------------------------------ what the process reads
    @property
    def id(self) -> int:
        return self.ctx.id

    @property
    def mode(self) -> str:
        return self.ctx.mode

    @property
    def clock(self) -> Callable[[], float]:
        return self.ctx.clock

    @property
    def t0(self) -> float | None:
        return self.ctx.timing.t0

    @property
    def ts(self) -> float:
        return self.ctx.timing.ts

    @property
    def steps(self) -> int | None:
        return self.ctx.steps

    @property
    def live(self) -> set[int]:
        return self.ctx.members.live

    @property
    def truth_gone_since(self) -> float | None:
        return self.ctx.members.truth_gone_since

    @property
    def measurement_dim(self) -> int:
        return self.payload.measurement_dim

    @property
    def start_payload(self) -> bytes | None:
        return self.run.start_payload

    def subscriptions(self) -> list[tuple[str, str]]:
        """``(key, tag)`` of what the node hears besides the control keys (the payload's)."""
        return self.payload.subscriptions()

    def publications(self) -> dict[str, tuple[str, bool]]:
        """channel -> ``(key, express)`` (the payload's)."""
        return self.payload.publications()

    def flood_rate(self) -> float:
        return self.payload.flood_rate()

    def snapshot(self) -> dict:
        """The counters as published with the estimates or lists and written to ``node-<i>.json``."""
        return self.ctx.snapshot(*self.payload.snapshot_parts())

    def report(self) -> dict:
        """The final report's figures (``node-<i>.json``): the counters and what the payload adds to them."""
        return {**self.snapshot(), **self.payload.report_parts()}

    # ------------------------------------------------------------------ the loop's calls
    def done(self) -> bool:
        ctx = self.ctx
        return self.run.stopped or (ctx.lockstep and ctx.steps is not None and self.payload.step >= ctx.steps)

    def timeout(self) -> float:
        """How long to wait for a message before the next timed action (at most 0.2 s, at least 1 ms)."""
        ctx = self.ctx
        if not ctx.realtime or ctx.timing.t0 is None or (ctx.steps is not None and self.payload.step >= ctx.steps):
            self.wake_due = None
            return MAX_WAIT_S
        now = ctx.clock()
        due = self.payload.due(now)
        wait = min(MAX_WAIT_S, max(MIN_WAIT_S, 0.05 if due is None else due - now))
        self.wake_due = now + wait  # a wake-up much later than this: the process did not run (advance)
        return wait

    def handle(self, msg: Message) -> None:
        """One message: validated, then kept or acted on; a bad one is counted under its reason."""
        try:
            tag = msg.tag
            if tag == "alive":
                self.run.on_alive(msg.key, msg.payload == b"put")
            elif tag == "start":
                self._on_start(Start.decode(msg.payload), msg.payload)
            elif tag == "stop":
                self.run.on_stop(msg.payload, self.payload.step)
            elif self.ctx.timing.t0 is None:  # before the start (a lost or late ctl/start): kept for it
                if len(self.early) >= EARLY_KEPT:
                    raise WireError("unexpected", f"more than {EARLY_KEPT} messages before the run's start")
                self.early.append(msg)
            else:
                self.payload.admit(msg)
        except WireError as err:
            self.ctx.rejects.add(msg.tag, err)

    def advance(self) -> None:
        """Take the transitions that are due now (a few per wake-up, e.g. fuse then a buffered measurement)."""
        ctx = self.ctx
        self.run.check_pending_stop(self.payload.step)
        ctx.idle_s = 0.0 if self.wake_due is None else max(0.0, ctx.clock() - self.wake_due)
        for _ in range(4):
            if not self.payload.advance(ctx.clock()):
                return

    def _on_start(self, start: Start, payload: bytes) -> None:
        if not self.run.check_start(start):
            return  # a repeat of the run's start
        self.payload.take_start(start)
        fresh = self.run.take_start(start, payload)
        self.payload.begin(fresh, self.ctx.clock())
        early, self.early = self.early, []
        for msg in early:  # messages that came before the start
            self.handle(msg)
