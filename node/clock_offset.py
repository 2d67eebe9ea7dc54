"""A tracker's clock against the run's schedule: the offset estimated from what it receives, and the corrected clock.

The run's schedule is the truth's clock: step k is published at (about) ``t0 + k ts`` in it, and every
measurement message carries its publication time ``t_pub`` in it. A measurement that arrives at local time
``t_recv`` gives one sample ``t_recv - t_pub`` = the local clock's offset + the message's delay (never
negative). :class:`OffsetEstimator` (pure: samples in, offset out) keeps the last :data:`WINDOW` samples, one
per step, and takes a low quantile (:data:`QUANTILE`) of them: the offset plus the least delay, robust to
delayed samples and to a few forged ones (a forger must own more than a fifth of the window to move it, and
can never move it beyond the tolerance). What the node applies is that whole estimate once it lies beyond a
dead band of :data:`DEAD_BAND_S` either way, bounded to :data:`TOLERANCE_S`; within the band nothing (hosts
synchronised by NTP, or a few ms of network delay, are left exactly as they are). Once applied it stays
applied down to half the band, so an estimate at the band's edge does not move the clock back and forth.
Applying the estimate *less* the band (as before issue 52) left a corrected clock a band (10 ms) off the run's,
ahead of it for a host ahead: every deadline test of that tracker 10 ms early, so it counted as missed the
steps it ended in the last 10 ms before their deadlines (and one behind, 10 ms late: it missed them uncounted).

:class:`RunClock` is the node's clock: the local clock less the applied offset. ``node/process.py`` passes
every received message through :meth:`RunClock.receive`, which takes a sample from a measurement *before*
admission (so a node whose clock is off still gets the very samples it needs: admission, on the local clock,
would refuse them as ``stale`` or ``future``) and turns the message's receive time into the run's time. The
schedule (``node/schedule.py``) runs on this clock: coast deadline, windows, round deadlines, ``k_now``.
:class:`StartGate` holds the start of a run already under way until the clock has a sample, so a late
joiner's warm-up picks its step on the corrected clock.

Logged: the offset once established (:data:`MIN_SAMPLES` samples) and whenever it moves by
:data:`LOG_CHANGE_S`; an offset beyond the tolerance is one warning naming the clock as the cause.
"""
from __future__ import annotations

import bisect
import logging
import time
from collections import deque
from collections.abc import Callable

from zentrack.transport.codec import Message, WireError
from zentrack.transport.messages import Measurement, Start

log = logging.getLogger("zentrack.node")

#: the largest clock offset against the run's schedule a tracker corrects (s)
TOLERANCE_S = 0.5
#: offsets (offset + least delay) within this either way are not corrected: synchronised hosts stay as they are
DEAD_BAND_S = 0.01
#: samples kept (one per step): about 6 s at a 0.1 s period
WINDOW = 64
#: the quantile of the window taken as the estimate (low: delays only ever add to a sample)
QUANTILE = 0.2
#: samples before the estimate counts as established (it is applied from the first one)
MIN_SAMPLES = 5
#: a change of the applied offset by this much is logged
LOG_CHANGE_S = 0.02
#: a start of a run under way waits at most this long for the clock's first sample (:class:`StartGate`)
HOLD_START_S = 0.5
#: a measurement of step k published outside [t0 + k ts - slack, t0 + (k + 1) ts + slack] is no sample
SCHEDULE_SLACK_S = 0.05


class OffsetEstimator:
    """The local clock's offset (local - run) from samples ``local time - run time`` of the same event."""

    def __init__(self, tolerance: float = TOLERANCE_S, window: int = WINDOW, quantile: float = QUANTILE,
                 min_samples: int = MIN_SAMPLES, dead_band: float = DEAD_BAND_S) -> None:
        if not (tolerance > 0 and window >= 1 and 0 <= quantile <= 1 and min_samples >= 1 and dead_band >= 0):
            raise ValueError("clock offset: tolerance > 0, window >= 1, quantile in [0, 1], min_samples >= 1, "
                             "dead_band >= 0")
        self.tolerance, self.quantile, self.min_samples, self.dead_band = tolerance, quantile, min_samples, dead_band
        self._recent: deque[tuple[object, float]] = deque(maxlen=window)  # (key, sample) in arrival order
        self._keys: set[object] = set()
        self._sorted: list[float] = []
        self._applying = False  # the estimate lies beyond the dead band (or has not come back within half of it)
        self.samples = 0  #: samples taken in all

    def add(self, local: float, run: float, key: object = None) -> bool:
        """One sample: the local and the run's time of one event (``key``: e.g. its step; a key already in the
        window is not taken again). False if it was not taken."""
        sample = local - run
        if sample != sample or key is not None and key in self._keys:  # NaN, or a second copy of a step
            return False
        recent = self._recent
        if len(recent) == recent.maxlen:
            old_key, old = recent.popleft()
            self._keys.discard(old_key)
            del self._sorted[bisect.bisect_left(self._sorted, old)]
        recent.append((key, sample))
        if key is not None:
            self._keys.add(key)
        bisect.insort(self._sorted, sample)
        self.samples += 1
        est = self.estimate
        assert est is not None
        self._applying = abs(est) > (0.5 * self.dead_band if self._applying else self.dead_band)
        return True

    @property
    def converged(self) -> bool:
        """Whether enough samples are in for the estimate to count (it is applied before)."""
        return len(self._sorted) >= self.min_samples

    @property
    def estimate(self) -> float | None:
        """The window's low quantile (offset + least delay), unbounded; None before any sample."""
        s = self._sorted
        return s[int(self.quantile * (len(s) - 1))] if s else None

    @property
    def exceeded(self) -> bool:
        """Whether the established estimate lies beyond the tolerance (the node cannot keep the schedule)."""
        est = self.estimate
        return self.converged and est is not None and abs(est) > self.tolerance

    @property
    def offset(self) -> float:
        """The offset to subtract from the local clock: the whole estimate within the tolerance, once it lies
        beyond the dead band (until it comes back within half of it); else 0 (and before any sample)."""
        est = self.estimate
        if est is None or not self._applying:
            return 0.0
        return max(-self.tolerance, min(self.tolerance, est))


class RunClock:
    """Node ``node``'s clock on the run's schedule: ``local()`` less the applied offset. Callable (the time now).
    ``sampling`` False (lockstep, whose steps keep no wall-clock schedule): no samples, the local clock as is."""

    def __init__(self, node: int, local: Callable[[], float] = time.time, estimator: OffsetEstimator | None = None,
                 sampling: bool = True) -> None:
        self.node, self.local, self.sampling = node, local, sampling
        self.estimator = estimator or OffsetEstimator()
        self.offset = 0.0  #: applied now (s): run time = local time - offset
        self.logged: float | None = None  # the offset last logged
        self.warned = False  # the beyond-tolerance warning is given once

    def __call__(self) -> float:
        return self.local() - self.offset

    def to_run(self, local: float) -> float:
        return local - self.offset

    def observe(self, local: float, run: float, key: object = None) -> None:
        """One sample (:meth:`OffsetEstimator.add`); the applied offset follows the estimate."""
        est = self.estimator
        if not est.add(local, run, key):
            return
        self.offset = est.offset
        if not est.converged:
            return
        if est.exceeded and not self.warned:
            self.warned = True
            value = est.estimate
            assert value is not None
            log.warning("node %d: clock offset %+.1f s against the run's schedule exceeds ±%.1f s: this host's clock "
                        "is off (or its measurements come that late); its measurements will be refused as stale or "
                        "future until the clocks are synchronised (NTP)", self.node, value, est.tolerance)
        if self.logged is None or abs(self.offset - self.logged) >= LOG_CHANGE_S:
            what = "established" if self.logged is None else "now"
            self.logged = self.offset
            how = "the node runs on the corrected clock" if self.offset else f"within ±{est.dead_band:.3f} s: not corrected"
            log.info("node %d: clock offset %s %+.3f s against the run's schedule (estimate %+.3f s from %d samples; "
                     "%s)", self.node, what, self.offset, est.estimate, est.samples, how)

    def receive(self, msg: Message, m: int, t0: float | None, ts: float | None) -> None:
        """A message as received (``t_recv`` on the local clock): a measurement on this node's key gives a sample
        (decoded whatever step it carries; ``m``: the measurement's width), and ``t_recv`` becomes run time.
        ``t0``, ``ts``: the run's start and period once known (a sample must fit the schedule)."""
        if msg.tag == "meas" and self.sampling:
            try:
                meas = Measurement.decode(msg.payload, self.node, m)
            except WireError:
                meas = None  # admission counts it
            if meas is not None:
                msg.decoded = meas  # admission checks its step window, without decoding it again
                if fits_schedule(meas.k, meas.t_pub, t0, ts):
                    self.observe(msg.t_recv, meas.t_pub, meas.k)
        msg.t_recv = self.to_run(msg.t_recv)

    def report(self) -> dict:
        """What ``node-<i>.json`` says about the clock."""
        est = self.estimator
        value = est.estimate
        return {"clock_offset_s": round(self.offset, 6), "clock_offset_estimate_s": None if value is None else round(value, 6),
                "clock_samples": est.samples, "clock_exceeded": est.exceeded}


class StartGate:
    """Holds the start of a realtime run already under way (a late join, a restart) until the clock has its first
    sample -- a measurement, due within a period -- or :data:`HOLD_START_S` has passed: the warm-up then picks
    its step on the corrected clock, not on a local clock up to 0.5 s off. A cold start is never held."""

    def __init__(self, clock: RunClock) -> None:
        self.clock = clock
        self.held: list[Message] = []  # the start, and any repeat of it that came meanwhile
        self.until = 0.0

    def hold(self, msg: Message, started: bool, realtime: bool) -> bool:
        """Whether the start ``msg`` (``t_recv`` on the run's time) is held; ``started``: the node has a start."""
        if self.held:
            self.held.append(msg)
            return True
        if started or not realtime or self.clock.estimator.samples:
            return False
        try:
            start = Start.decode(msg.payload)
        except WireError:
            return False  # the schedule counts it
        if msg.t_recv <= start.t0 + start.ts:
            return False
        self.held, self.until = [msg], self.clock() + HOLD_START_S
        return True

    def due(self) -> list[Message]:
        """The held messages to hand on now (the clock has a sample, or the wait is over), in order."""
        if not self.held or (not self.clock.estimator.samples and self.clock() < self.until):
            return []
        out, self.held = self.held, []
        return out


def fits_schedule(k: int, t_pub: float, t0: float | None, ts: float | None) -> bool:
    """Whether a measurement of step ``k`` published at ``t_pub`` (the run's time) fits the run's schedule: the
    truth publishes step k during its period (anything fits before the start is known)."""
    if t0 is None or not ts:
        return True
    return t0 + k * ts - SCHEDULE_SLACK_S <= t_pub <= t0 + (k + 1) * ts + SCHEDULE_SLACK_S
