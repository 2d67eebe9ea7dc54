"""What a tracker's schedule and its payload share: who the node is, its clock and publisher, the run's timing
and membership, and what it refused.

**Membership**: a node waits for its live neighbours in realtime; in lockstep for every participating neighbour
that has not left, whether or not its token has reached it yet (right after the start a neighbour's scan or pair
can arrive before its token, and skipping it would change the numbers).

:class:`NodeContext` is built once by :class:`~zentrack.node.schedule.NodeSchedule` and handed to its payload
(single-target diffusion or many-target track lists, ``node/payload.py``). Every attribute is declared here
once; the schedule's parts and the payload's parts read and write the same object instead of inheriting it.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from zentrack.config.node_config import NodeConfig
from zentrack.node.counters import RejectLog
from zentrack.node.timing import StepTiming
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Start


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


@dataclass
class NodeContext:
    """Node ``id``'s run-level state (module docstring)."""

    id: int
    mode: str  #: "lockstep" or "realtime"
    keys: Keys
    clock: Callable[[], float]  #: the run's clock (``node/clock_offset.py`` corrects it in a process)
    send: Callable[[str, bytes], None]  #: publishes ``payload`` on one of the payload's channels
    timing: StepTiming
    rejects: RejectLog
    incarnation: int = 0  #: the process id: tells a restarted process's counters from its predecessor's
    members: Membership = field(default_factory=Membership)
    dropped: dict[str, int] = field(default_factory=dict)  #: dropped before decoding by the flood guard
    steps: int | None = None  #: the run's steps, from the start
    participants: set[int] | None = None  #: the nodes the start names
    start: Start | None = None  #: the run's start as decoded: a later start must repeat it
    idle_s: float = 0.0  #: how much later than planned this wake-up came (a frozen or starved process)

    @classmethod
    def of(cls, keys: Keys, cfg: NodeConfig, clock: Callable[[], float], send: Callable[[str, bytes], None],
           incarnation: int = 0, fusion_after_deadline: bool | None = None) -> NodeContext:
        lag_ms = 0.0 if cfg.detections is None else float(cfg.detections["lag_ms"])  # sensors of their own
        timing = StepTiming(cfg.mode, cfg.deadline_frac, cfg.ts, after_deadline=fusion_after_deadline,
                            budget=(cfg.latency_budget_ms + lag_ms) / 1000)
        return cls(cfg.node, cfg.mode, keys, clock, send, timing, RejectLog(cfg.node, clock), incarnation)

    @property
    def lockstep(self) -> bool:
        return self.mode == "lockstep"

    @property
    def realtime(self) -> bool:
        return self.mode == "realtime"

    def expected(self, neighbours: list[int]) -> set[int]:
        """Whose messages a step waits for, of ``neighbours`` (``node/run_control.py``: membership)."""
        return self.members.expected(neighbours, self.participants, self.lockstep)

    def snapshot(self, counts: dict, extra: dict) -> dict:
        """The counters as published on estimates and lists and written to ``node-<i>.json``: the payload's
        ``counts``, what was refused and dropped, the payload's ``extra`` and the incarnation."""
        return {**counts, "rejected": dict(self.rejects.counts), "dropped": dict(self.dropped), **extra,
                "incarnation": self.incarnation}
