"""A tracker's clock against its neighbours' (sensors of their own, issue 52): each neighbour's clock offset
estimated from its round messages, the step of this tracker's schedule its messages belong to, and their
prediction to this tracker's time.

With sensors of their own no truth measurement reaches a tracker (``RunClock`` takes no sample), so each runs on
its own host's clock: its windows, and the time of validity of what it shares, are on that clock. The prior a
tracker shares for step s is its estimate at the end of window s - 1, valid at ``t0 + (s - 1) ts`` on its clock
(:func:`prior_valid_at`; the message's ``t`` says so, after ``t0``). A neighbour whose clock is ``o`` ahead of
this tracker's (``o`` = its clock - this one's) publishes every message ``o`` earlier in this tracker's time, and
its message for step s' is valid at ``t0 + (s' - 1) ts - o`` on this tracker's clock.

**Offset.** Each round message carries ``t_pub``, its publication on the sender's clock; received at ``t_recv`` on
this tracker's, ``t_recv - t_pub`` is ``-o`` plus the message's delay (never negative). One
:class:`~zentrack.node.clock_offset.OffsetEstimator` per neighbour, the one the run's clock and the sensors' use,
keeps the last :data:`~zentrack.node.clock_offset.WINDOW` samples (one per step and round) and takes their
:data:`~zentrack.node.clock_offset.QUANTILE`: ``-o`` plus the least delay, robust to delayed samples and to a few
forged stamps (a forger must own a fifth of the window). Within its dead band (10 ms) nothing is applied: hosts
on NTP run exactly as before. The sample is taken before admission, so a neighbour whose messages are refused on
this tracker's unmapped schedule still gives the samples that map them. The estimate is biased by the least
one-way delay (``o`` comes out that much low); on one host, under a millisecond.

**Step.** This tracker fuses step s when its round for s opens, at ``t0 + (s - 1 + frac) ts`` on its clock (the
held round 1, ``node/timing.py``), and not before the settle time :data:`ALLOWANCE_S` after that
(``fusion_policy.py``). By then the neighbour has published its message for ``s + n``,
``n = floor((o + ALLOWANCE_S) / ts)`` (:meth:`NeighbourClocks.shift`): the newest one due by the end of the settle
time, so the round never waits longer for a neighbour whose clock is off. (A many-target tracker, which waits
for its neighbours' lists until its fusion window ends, allows that wait instead: ``allowance_s``,
``node/track_lists/payload.py``.) That message is kept as the
neighbour's for step s, and predicted over ``dt = o - n ts`` (``-ALLOWANCE_S <= dt < ts - ALLOWANCE_S``:
:meth:`NeighbourClocks.lead`; back, with the process noise of ``|dt|``, when it is valid a few ms after this
tracker's time) by the tracker's own filter over that interval
(:class:`~zentrack.fusion.filters.interval.IntervalPredictor`, :func:`~zentrack.fusion.models.plant_over`)
before the gate and covariance intersection see it (:func:`predicted_blocks`). Taking the freshest message
matters: one a period older, predicted a period forward, carries a period's process noise more and its
sender's last window less. ``n`` keeps its value until ``(o + ALLOWANCE_S) / ts`` leaves
``[n - SHIFT_HYSTERESIS, n + 1 + SHIFT_HYSTERESIS)``, so an estimate that jitters at a period's edge does not
remap the messages back and forth (each change costs one round of that neighbour: a conflict or a missing
message).

``clock = "configured"`` (``[sensor_timing]``): the trackers' clocks are taken as synchronised (the one
configured form: an offset per host would have to be measured anyway; NTP gives it), nothing is estimated.
Pure: times come in as arguments.
"""
from __future__ import annotations

import logging
import math

from zentrack.fusion.filters.interval import INTERVAL_TOLERANCE_S
from zentrack.fusion.gate import information_mean_cov
from zentrack.fusion.linalg import GaussianState
from zentrack.node.clock_offset import LOG_CHANGE_S, OffsetEstimator
from zentrack.node.diffusion.fusion_policy import CONFLICT_SETTLE_S
from zentrack.node.diffusion.tracker import Blocks, Tracker

log = logging.getLogger("zentrack.node")

#: the largest offset to a neighbour's clock a tracker maps (s); beyond it, one warning
TOLERANCE_S = 5.0
#: a neighbour's message published up to this long after this tracker's round opens is waited for: the round's
#: settle time, which it waits anyway (``fusion_policy.CONFLICT_SETTLE_S``)
ALLOWANCE_S = CONFLICT_SETTLE_S
#: a neighbour's step shift changes only once its offset has left the current shift's period by this many periods
SHIFT_HYSTERESIS = 0.05
#: a message's stated time of validity may differ from its step's by this much (s)
VALIDITY_SLACK_S = 1e-6


def prior_valid_at(s: int, ts: float) -> float:
    """When the prior a tracker of sensors of their own shares for step ``s`` is valid, after ``t0`` on its clock:
    the start of window s, ``(s - 1) ts`` (``local_step.py``, ``window``: it is the estimate of step s - 1)."""
    return (s - 1) * ts


class NeighbourClocks:
    """Tracker ``node``'s offsets to its ``neighbours``' clocks (module docstring); ``estimated`` False: taken as
    synchronised (``clock = "configured"``)."""

    def __init__(self, node: int, neighbours: list[int], ts: float, estimated: bool = True,
                 allowance_s: float = ALLOWANCE_S) -> None:
        self.node, self.ts, self.estimated = node, float(ts), estimated
        #: how long after this tracker's own message a neighbour's may come and still be fused (s): a round's
        #: settle time (:data:`ALLOWANCE_S`), or a many-target tracker's wait for its neighbours' lists
        self.allowance_s = float(allowance_s)
        self.clocks = {j: OffsetEstimator(tolerance=TOLERANCE_S) for j in neighbours}
        self._shift = dict.fromkeys(neighbours, 0)
        self._logged: dict[int, float] = {}
        self._warned: set[int] = set()

    def observe(self, j: int, t_recv: float, t_pub: float, key: object) -> None:
        """A message of neighbour ``j`` published at ``t_pub`` (its clock), received at ``t_recv`` (this one's);
        ``key`` (its step and round) is taken once."""
        est = self.clocks.get(j)
        if est is None or not self.estimated or not est.add(t_recv, t_pub, key):
            return
        o = self.offset(j)
        if est.exceeded and j not in self._warned:
            self._warned.add(j)
            log.warning("node %d: neighbour %d's clock is %+.1f s off this tracker's, beyond ±%.0f s: its messages "
                        "cannot be mapped to this schedule until the clocks are synchronised (NTP)",
                        self.node, j, -(est.estimate or 0.0), TOLERANCE_S)
        if est.converged and (j not in self._logged or abs(o - self._logged[j]) >= LOG_CHANGE_S):
            what = "established" if j not in self._logged else "now"
            self._logged[j] = o
            how = (f"its messages of step s{self.shift(j):+d} are fused at step s, predicted over "
                   f"{self.lead_s(j):.3f} s" if o else f"within ±{est.dead_band:.3f} s: taken as synchronised")
            log.info("node %d: neighbour %d's clock offset %s %+.3f s (estimate %+.3f s from %d samples; %s)",
                     self.node, j, what, o, -(est.estimate or 0.0), est.samples, how)

    def offset(self, j: int) -> float:
        """Neighbour ``j``'s clock less this tracker's as applied now (s): 0 within the dead band, before any
        sample and when configured."""
        est = self.clocks.get(j)
        return 0.0 if est is None or not self.estimated else 0.0 - est.offset

    def shift(self, j: int) -> int:
        """The steps ``n`` by which neighbour ``j``'s messages run ahead: its step s + n is this tracker's s."""
        x = (self.offset(j) + self.allowance_s) / self.ts
        n = self._shift.get(j, 0)
        if not n - SHIFT_HYSTERESIS <= x < n + 1 + SHIFT_HYSTERESIS:
            n = self._shift[j] = math.floor(x)
        return n

    def own_step(self, j: int, k: int) -> int:
        """The step of this tracker's schedule that neighbour ``j``'s message of step ``k`` belongs to."""
        return k - self.shift(j)

    def lead_s(self, j: int) -> float:
        """How far neighbour ``j``'s messages are predicted now: its offset less its shift (s)."""
        return self.offset(j) - self.shift(j) * self.ts

    def lead(self, j: int, s: int, t_valid: float) -> float:
        """How far to predict neighbour ``j``'s message for this tracker's step ``s``, valid at ``t_valid`` (after
        ``t0``) on ``j``'s clock: this tracker's time of validity of step s's prior less the message's on this
        clock (``t_valid - o``)."""
        return self.lead_to(j, prior_valid_at(s, self.ts), t_valid)

    def lead_to(self, j: int, t_own: float, t_valid: float) -> float:
        """How far to predict an estimate of neighbour ``j``'s valid at ``t_valid`` (after ``t0``, on ``j``'s clock)
        to ``t_own`` (after ``t0``, on this tracker's): ``t_own - (t_valid - o)`` (a many-target tracker's list of
        step k is valid at ``k ts``, ``node/track_lists/admission.py``)."""
        return t_own - (t_valid - self.offset(j))

    def report(self) -> dict[str, float | None]:
        """Each neighbour's offset as applied now (s; None before any sample when estimated)."""
        return {str(j): None if self.estimated and est.estimate is None else round(self.offset(j), 6)
                for j, est in self.clocks.items()}


def predicted_blocks(tracker: Tracker, blocks: Blocks, dt: float) -> Blocks:
    """A neighbour's round-1 message ``blocks`` predicted ``dt`` seconds ahead (back when negative) by
    ``tracker``'s filter over that interval (``tracker.interval``, ``fusion/filters/interval.py``), as the same
    rule's message; ``dt`` of (about) zero, or a message that is not an estimate (no rule that runs with sensors of
    their own), as is. ValueError: its information matrix is not positive definite (admission refuses it)."""
    if abs(dt) <= INTERVAL_TOLERANCE_S:
        return blocks
    info = tracker.rule.message_estimate(1, blocks)
    if info is None:
        return blocks
    mean_cov = information_mean_cov(*info)
    if mean_cov is None:
        raise ValueError("its information matrix is not positive definite")
    mean, cov = mean_cov
    like = tracker.shared if tracker.shared is not None else tracker.prior
    est = tracker.filter.from_fused({"state": GaussianState(mean[None], cov[None])}, like)
    return tracker.message_blocks(tracker.interval.predict(est, dt))


__all__ = ["NeighbourClocks", "predicted_blocks", "prior_valid_at", "ALLOWANCE_S", "TOLERANCE_S",
           "SHIFT_HYSTERESIS", "VALIDITY_SLACK_S"]
