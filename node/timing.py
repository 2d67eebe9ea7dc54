"""When a tracker acts: step k's sample time, deadline, scan and relay deadlines and the fusion window.

Pure arithmetic on the run's ``t0``, period ``ts`` and deadline fraction ``frac``: the schedule passes the
time it read from its injected clock, so every rule here is unit tested without a clock.

- Step k is sampled at ``t0 + k ts``; its **deadline** is ``t0 + (k + frac) ts``: the estimate is due then.
- **Fusion after the deadline** (realtime, when the period leaves room: the rest of it after the deadline,
  less :data:`FUSION_MARGIN_S`, is at least half the measurement window): the round-1 message for k + 1 is held
  until step k's deadline and the **fusion window** for k + 1 ends ``FUSION_MARGIN_S`` before its sample, so
  no node's fusion competes for the CPU with another's measurement update (every node wakes at the same
  sample time). Otherwise (lockstep, or a deadline late in the period) round 1 goes out at once and the window
  ends at step k's deadline.
- Each fusion round's **deadline** is set when the round starts: the window's end less a reserve of
  ``frac ts / (4 L)`` per round still to go, but never less than an equal share of what is left, so a round
  can ride out a neighbour's stall while the later rounds, which take a few ms each, still fit.
- Scans forwarded before the update are waited for until ``t0 + (k + frac / (2 L)) ts``; relays until step
  k's deadline when fusion follows it, else halfway there from the scan deadline.
- A **latency budget** ``budget`` (seconds, the node configuration's ``latency_budget_ms``; 0 by default) runs
  the node's whole schedule that much behind the run's: every deadline and window above is taken from
  ``t0 + budget`` (:meth:`StepTiming.start`), so a measurement or a neighbour's message that spends up to the
  budget more on the network than on loopback still arrives in time (docs/networks.md says how to choose it).
  Sample times stay ``k ts``, and how far ahead a message may be is judged against the run's own clock
  (``t0``), so a budget never makes a timely measurement look like one from the future.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: a node coasts (predicts only) this long before step k's deadline when its measurement has not come
COAST_MARGIN_S = 0.02
#: fusion after the deadline ends this long before the next sample, so the next measurement finds it done
FUSION_MARGIN_S = 0.005
#: realtime: measurements are accepted up to this many steps ahead of the wall clock
REALTIME_FUTURE_STEPS = 2


@dataclass
class StepTiming:
    """The run's timing as one node sees it; ``t0`` is None until the start message. ``after_deadline``
    overrides the decision :meth:`fusion_after_deadline` takes from the timing (None: decided by it);
    ``budget`` is the latency budget in seconds (module docstring)."""

    mode: str  #: "realtime" or "lockstep"
    frac: float
    ts: float
    t0: float | None = None
    after_deadline: bool | None = None
    budget: float = 0.0

    @property
    def realtime(self) -> bool:
        return self.mode == "realtime"

    def start(self) -> float:
        """The origin of this node's schedule: the run's t0 plus the latency budget (only asked once the start
        is known)."""
        assert self.t0 is not None
        return self.t0 + self.budget

    def deadline(self, k: int) -> float:
        t0 = self.t0  # (start() inlined: this runs several times per step)
        assert t0 is not None
        return t0 + self.budget + (k + self.frac) * self.ts

    def k_now(self, now: float) -> int:
        """The step of this node's schedule whose period ``now`` falls in (the run's step, ``budget`` later)."""
        t0 = self.t0
        assert t0 is not None
        return int(math.floor((now - t0 - self.budget) / self.ts + 1e-9))

    def k_run(self, now: float) -> int:
        """The run's step at ``now``: the latest sample the truth can have published (no budget)."""
        t0 = self.t0
        assert t0 is not None
        return int(math.floor((now - t0) / self.ts + 1e-9))

    def fusion_after_deadline(self) -> bool:
        """Whether fusion for the next step waits for this step's deadline (module docstring)."""
        if not self.realtime:
            return False
        if self.after_deadline is not None:
            return self.after_deadline
        return (1.0 - self.frac) * self.ts - FUSION_MARGIN_S >= 0.5 * self.frac * self.ts

    def fusion_window_end(self, s: int) -> float:
        """When fusion for step ``s`` must be over."""
        if self.fusion_after_deadline():
            return self.start() + s * self.ts - FUSION_MARGIN_S
        return self.start() + (s - 1 + self.frac) * self.ts

    def round_deadline(self, now: float, s: int, fuse_round: int, rounds: int) -> float:
        """The deadline of round ``fuse_round`` of ``rounds`` for step ``s``, starting ``now``: the window's
        end less a reserve per round still to go, at least an equal share of what is left."""
        window_end = self.fusion_window_end(s)
        left = max(rounds - fuse_round + 1, 1)
        reserve = self.frac * self.ts / (4 * rounds)
        share = now + max(0.0, window_end - now) / left
        return min(window_end, max(share, window_end - (left - 1) * reserve))

    def scan_deadline(self, k: int, rounds_next: int) -> float:
        """When a node stops waiting for its neighbours' scans: the first half of round 1's share
        (``rounds_next``: the rule's rounds for step k + 1)."""
        return self.start() + (k + self.frac / (2 * rounds_next)) * self.ts

    def relay_deadline(self, k: int, rounds_next: int) -> float:
        """When a node stops waiting for its neighbours' relays of step k."""
        if self.fusion_after_deadline():
            return self.deadline(k)
        return 0.5 * (self.scan_deadline(k, rounds_next) + self.deadline(k))

    def meas_window(self, first: int, now: float) -> tuple[int, int]:
        """The steps a measurement (or forwarded scan) may carry, ``first`` being the next one the node
        needs: that one only in lockstep; in realtime from one step behind the node's schedule (but not before
        ``first``) to :data:`REALTIME_FUTURE_STEPS` ahead of the run's clock."""
        if not self.realtime:
            return first, first + 1
        return max(first, self.k_now(now) - 1), self.k_run(now) + REALTIME_FUTURE_STEPS

    def prior_window(self, fused_upto: int, now: float) -> tuple[int, int]:
        """The steps a neighbour's round message may carry: the next to fuse in lockstep; in realtime one step
        behind the node's schedule to one more than a measurement may be ahead of the run's clock."""
        if not self.realtime:
            return fused_upto + 1, fused_upto + 2
        return self.k_now(now) - 1, self.k_run(now) + REALTIME_FUTURE_STEPS + 1
