"""A deadline miss as the tracker saw it (issue 36): :class:`MissNote`, carried on the tracker's next estimate
(``EstimateMessage.miss_notes``) so that a recorder can say which node missed which step, how late, and what the
process was doing.

A note's ``kind``: ``skipped`` (the tracker woke past step k's deadline and skipped ``steps`` steps, predicting
through them), ``late_estimate`` (step k's estimate went out after its deadline) or ``overran`` (the fusion for
step k ended after step k's sample time). ``phase`` is the tracker's phase when it saw the miss (a node phase
name, e.g. ``await_meas``, ``fusing``); ``late_ms`` how far past the deadline; ``idle_ms`` how much later than it
planned the process woke up when it saw the miss (long: it was frozen or starved of CPU); ``work_ms`` how long the work that was late
took (the local update, or the step's fusion; 0 for a skip). Decoding checks every field and raises
:class:`~zentrack.transport.codec.WireError` only.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Self

from zentrack.transport.codec import WireError

#: the kinds of miss a tracker notes
MISS_KINDS = ("skipped", "late_estimate", "overran")
#: at most this many notes ride on one estimate (a frozen node's one skip is one note, however many steps)
MAX_MISS_NOTES = 8
#: the longest time a note carries (ms): a day
MAX_NOTE_MS = 86_400_000.0
_PHASE = re.compile(r"[a-z_]{1,24}")


@dataclass(frozen=True)
class MissNote:
    """One deadline miss (module docstring)."""

    k: int
    kind: str
    phase: str
    late_ms: float
    steps: int = 1
    idle_ms: float = 0.0
    work_ms: float = 0.0

    def pack(self) -> list[Any]:
        return [self.k, self.kind, self.phase, float(self.late_ms), self.steps, float(self.idle_ms),
                float(self.work_ms)]

    @classmethod
    def unpack(cls, obj: Any) -> Self:
        """A note from its packed list; WireError naming the field that is wrong."""
        if type(obj) is not list or len(obj) != 7:
            raise WireError("schema", "miss_notes: a note is a list of 7 fields")
        k, kind, phase, late, steps, idle, work = obj
        if type(k) is not int or not 0 <= k < 2**53:
            raise WireError("schema", "miss_notes: k is not a step")
        if kind not in MISS_KINDS:
            raise WireError("schema", f"miss_notes: kind must be one of {', '.join(MISS_KINDS)}")
        if type(phase) is not str or not _PHASE.fullmatch(phase):
            raise WireError("schema", "miss_notes: phase is not a phase name")
        if type(steps) is not int or not 1 <= steps < 2**53:
            raise WireError("schema", "miss_notes: steps is not a positive count")
        times = []
        for name, value in (("late_ms", late), ("idle_ms", idle), ("work_ms", work)):
            if type(value) not in (int, float) or not math.isfinite(value) or not 0 <= value <= MAX_NOTE_MS:
                raise WireError("schema", f"miss_notes: {name} must be a time from 0 to {MAX_NOTE_MS:g} ms")
            times.append(float(value))
        return cls(k, kind, phase, times[0], steps, times[1], times[2])

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.k, "kind": self.kind, "phase": self.phase, "late_ms": round(self.late_ms, 2),
                "steps": self.steps, "idle_ms": round(self.idle_ms, 2), "work_ms": round(self.work_ms, 2)}


def unpack_notes(obj: Any) -> tuple[MissNote, ...]:
    """An estimate's ``miss_notes`` (absent: none)."""
    if obj is None:
        return ()
    if type(obj) is not list or len(obj) > MAX_MISS_NOTES:
        raise WireError("schema", f"miss_notes: expected a list of at most {MAX_MISS_NOTES} notes")
    return tuple(MissNote.unpack(n) for n in obj)
