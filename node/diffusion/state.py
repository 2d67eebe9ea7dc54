"""Where a single-target tracker is in its step: the state its parts (the local step, the rounds, the warm start)
read and write, each field declared once here.

``phase`` moves only through :meth:`StepState.enter`, which checks the table in ``node/phases.py``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from zentrack.fusion.estimates import Estimate
from zentrack.fusion.scan import Scan
from zentrack.node.diffusion.admission import Arrival
from zentrack.node.diffusion.tracker import Pair
from zentrack.node.phases import Phase, check_transition
from zentrack.transport.miss_notes import MAX_MISS_NOTES, MAX_NOTE_MS, MissNote


@dataclass
class StepState:
    """The step's state (module docstring)."""

    phase: Phase = Phase.IDLE
    step: int = 0  #: the step being processed (await_meas) or whose measurement produced own_pair
    fuse_step: int | None = None  #: the step whose prior is being fused (fusing, warming)
    fuse_round: int = 1
    own_pair: Pair | None = None  #: the own message of the round being fused
    pending: Arrival | None = None  #: own measurement waiting for the neighbours' scans
    core_scans: list[Scan] = field(default_factory=list)  #: the step's one-hop scans, waiting for the relayed ones
    post: Estimate | None = None  #: the step's posterior, waiting for the relayed scans (await_relays)
    coast_run: int = 0  #: consecutive steps without a measurement
    warm_published: int | None = None  #: the step of the last warm pair published while warming
    empty_warm_steps: int = 0  #: fusion windows a warming node ended with nothing to start from
    warm_next: bool = False  #: the next estimate is the first after a warm start
    last_fused: int = 0  #: how many neighbours' messages the last fusion took
    fused_upto: int = 0  #: the last step whose prior has been fused (the cold prior is step 0)
    round_started: float = 0.0  #: when the round being fused began (its own message sent)
    round_deadline: float = 0.0  #: when the round being fused stops waiting (realtime)
    round_ms: list[float] = field(default_factory=list)  #: the durations of the rounds of the step being fused
    last_round_ms: list[float] = field(default_factory=list)  #: ... and of the rounds that made the current prior
    hold_until: float | None = None  #: realtime: when the held round-1 message goes out
    miss_notes: list[MissNote] = field(default_factory=list)  #: misses since the last estimate, sent with the next

    def enter(self, phase: Phase) -> None:
        self.phase = check_transition(self.phase, phase)

    def fusing(self) -> int:
        """The step being fused (only called in the fusing and warming phases)."""
        assert self.fuse_step is not None
        return self.fuse_step

    def note_miss(self, k: int, kind: str, late_s: float, idle_s: float, steps: int = 1, work_s: float = 0.0) -> None:
        """Note a deadline miss for the next estimate (the first ``MAX_MISS_NOTES`` since the last one): how late,
        how late the wake-up came (``idle_s``) and what the work took."""
        if len(self.miss_notes) < MAX_MISS_NOTES:
            ms = [min(MAX_NOTE_MS, max(0.0, s) * 1e3) for s in (late_s, idle_s, work_s)]
            self.miss_notes.append(MissNote(k, kind, self.phase.value, ms[0], max(1, steps), ms[1], ms[2]))

    def marker(self) -> tuple:
        """What changes when a transition is taken."""
        return self.phase, self.step, self.fuse_step, self.fuse_round
