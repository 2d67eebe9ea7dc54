"""A tracker's detections from sensors of their own: their time on its clock, the checks of hostile time, and
the buffer that hands them to the local step in measurement-time order (issue 52).

A sensor stamps each detection with the measurement time on *its* clock; the tracker maps it to its own:
``t = stamp - offset``, the sensor's offset either configured (a calibrated or disciplined clock) or estimated
from the stream (:class:`~zentrack.node.clock_offset.OffsetEstimator` over ``receive time - stamp`` = the
least latency less the offset; the slice's ``min_latency_s`` is added back). A detection is then

- **refused**, one reason each, counted, the tracker serving on: ``future`` (more than :data:`FUTURE_S` ahead
  of the tracker's clock: a forged or broken time), ``stale`` (more than :data:`STALE_S` behind: a clock that
  jumped back, a replay), ``rate`` (the sensor sends faster than :data:`RATE_FACTOR` times its rate, beyond a
  burst), ``duplicate`` (a sequence number already taken), ``sender_mismatch`` (not one of its sensors, or a
  forged id: ``Detection.decode``);
- **too old** when its time is before the tracker's processed window (older than the lag): counted
  ``too_old``, and dropped;
- else **kept** until the local step takes the window it falls in (:meth:`DetectionIntake.take`).

A detection that never comes (lost on the way: a router down, a lossy link; or never sent: its sensor down) is
counted ``missing``: a gap in its sensor's sequence numbers (a sensor numbers its detections 0, 1, 2, ...), taken
off again when the detection comes late after all.

Pure: times come in as arguments, so every rule is unit tested without a clock.
"""
from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass, field

from zentrack.node.clock_offset import OffsetEstimator
from zentrack.transport.codec import WireError
from zentrack.transport.detection_messages import Detection

#: a detection more than this far ahead of the tracker's clock is from the future (s)
FUTURE_S = 1.0
#: a detection more than this far behind the tracker's clock is refused as stale, not counted too old (s)
STALE_S = 10.0
#: a sensor may send this many times its configured rate ...
RATE_FACTOR = 3.0
#: ... with a burst of this many seconds' worth at that rate (and at least :data:`MIN_BURST` detections)
BURST_S = 1.0
MIN_BURST = 4
#: sequence numbers remembered per sensor (duplicates)
SEQ_KEPT = 256
#: a jump of a sensor's sequence numbers larger than this is no gap (``missing``) but a new count: a restarted
#: third-party sensor, a forged number (a sensor at 1000 Hz, the most a scenario has, down for 100 s)
MAX_SEQ_GAP = 100_000
#: samples of a sensor's clock kept, and the quantile taken (``clock_offset.OffsetEstimator``: low, as latency
#: only ever adds to a sample; above the minimum, so a few forged stamps cannot set it alone)
CLOCK_WINDOW, CLOCK_QUANTILE = 64, 0.05
#: the largest sensor clock offset a tracker estimates (s)
CLOCK_TOLERANCE_S = 3600.0
#: a sensor whose detections all come this many in a row from the future (by the established estimate) has
#: stepped its clock forward: its estimate starts again from the next (a forger must outnumber the genuine
#: sensor's detections this many to one to do the same, and the gate still weighs what it sends)
FOLLOW_FORWARD = CLOCK_WINDOW // 2


@dataclass(frozen=True)
class SensorLink:
    """One sensor a tracker takes: its id, its nominal rate (Hz), its clock's offset to the tracker's clock
    (seconds, sensor - tracker; None: estimated from the stream) and its least latency (s)."""

    sensor: int
    rate_hz: float
    offset_s: float | None = None
    min_latency_s: float = 0.0


@dataclass(slots=True)
class TimedDetection:
    """A detection kept: its measurement time on the tracker's clock and when it arrived (tracker clock)."""

    t: float
    det: Detection
    t_recv: float


@dataclass
class SensorState:
    """What the intake remembers of one sensor: its clock, its token bucket, its recent sequence numbers."""

    link: SensorLink
    clock: OffsetEstimator
    tokens: float
    refilled: float | None = None
    seqs: deque[int] = field(default_factory=lambda: deque(maxlen=SEQ_KEPT))
    future_run: int = 0  #: detections in a row refused as from the future
    seq_first: int | None = None  #: where the sequence numbers counted for ``missing`` start ...
    seq_last: int | None = None  #: ... and the highest one of them so far


@dataclass
class DetectionCounts:
    """Counted per tracker (with the refusals the schedule counts by reason)."""

    det_rx: int = 0  #: detections kept (applied, or waiting for their window)
    too_old: int = 0  #: genuine detections older than the lag (dropped; one kept whose window went by is moved here)
    out_of_order: int = 0  #: kept detections older than one already kept from the same sensor (reordered)
    missing: int = 0  #: detections that never came: gaps in a sensor's sequence numbers (module docstring)


class DetectionIntake:
    """The detections of ``links``' sensors, admitted (module docstring) and buffered by time."""

    def __init__(self, links: list[SensorLink]) -> None:
        self.sensors = {link.sensor: SensorState(link, self._estimator(), tokens=self._burst(link)) for link in links}
        self.counts = DetectionCounts()
        self._times: list[float] = []  # sorted measurement times of the kept detections
        self._kept: list[TimedDetection] = []  # in the same order
        self._last_t: dict[int, float] = {}

    @property
    def period_s(self) -> float:
        """The longest its sensors leave between two detections when all is well: the fastest one's period (s)."""
        return 1.0 / max(st.link.rate_hz for st in self.sensors.values())

    @staticmethod
    def _estimator() -> OffsetEstimator:
        return OffsetEstimator(tolerance=CLOCK_TOLERANCE_S, window=CLOCK_WINDOW, quantile=CLOCK_QUANTILE, dead_band=0.0)

    @staticmethod
    def _burst(link: SensorLink) -> float:
        return max(float(MIN_BURST), RATE_FACTOR * link.rate_hz * BURST_S)

    def offset(self, sensor: int) -> float | None:
        """Sensor ``sensor``'s clock offset to the tracker's as applied now (None before any sample)."""
        st = self.sensors[sensor]
        if st.link.offset_s is not None:
            return st.link.offset_s
        est = st.clock.estimate
        return None if est is None else -(est - st.link.min_latency_s)

    def tracker_time(self, det: Detection, t_recv: float) -> float:
        """``det``'s measurement time on the tracker's clock, taking a sample of the sensor's clock first unless
        the estimate is established and the detection would be from the future with it (a forged or broken
        stamp moves nothing; a clock that jumps *back* is followed once most of the window says so)."""
        st = self.sensors[det.sensor]
        if st.link.offset_s is None:
            offset = self.offset(det.sensor)
            if not (st.clock.converged and offset is not None and det.t_meas - offset > t_recv + FUTURE_S):
                st.clock.add(t_recv, det.t_meas, key=det.seq)
        offset = self.offset(det.sensor)
        return det.t_meas - (offset or 0.0)

    def admit(self, det: Detection, t_recv: float, processed_upto: float | None) -> TimedDetection | None:
        """Keep ``det`` (arrived at ``t_recv``, tracker clock) unless refused (WireError) or older than
        ``processed_upto``, the end of the last window the local step took (then counted ``too_old``: None)."""
        st = self.sensors.get(det.sensor)
        if st is None:
            raise WireError("sender_mismatch", f"sensor {det.sensor} does not feed this tracker")
        self._take_token(st, t_recv)
        if det.seq in st.seqs:
            raise WireError("duplicate", f"sensor {det.sensor}'s detection {det.seq} came twice")
        self._note_seq(st, det.seq)
        t = self.tracker_time(det, t_recv)
        if t > t_recv + FUTURE_S:
            st.future_run += 1
            if st.future_run >= FOLLOW_FORWARD and st.link.offset_s is None:  # the sensor's clock stepped forward
                st.clock, st.future_run = self._estimator(), 0
            raise WireError("future", f"sensor {det.sensor}'s detection {det.seq} is {t - t_recv:.3f} s ahead "
                                      "of this tracker's clock")
        st.future_run = 0
        if t < t_recv - STALE_S:
            raise WireError("stale", f"sensor {det.sensor}'s detection {det.seq} is {t_recv - t:.3f} s old")
        st.seqs.append(det.seq)
        if processed_upto is not None and t < processed_upto:
            self.counts.too_old += 1
            return None
        if t < self._last_t.get(det.sensor, float("-inf")):
            self.counts.out_of_order += 1
        self._last_t[det.sensor] = max(t, self._last_t.get(det.sensor, float("-inf")))
        kept = TimedDetection(t, det, t_recv)
        at = bisect.bisect_right(self._times, t)
        self._times.insert(at, t)
        self._kept.insert(at, kept)
        self.counts.det_rx += 1
        return kept

    def _note_seq(self, st: SensorState, seq: int) -> None:
        """Count the sequence numbers skipped before ``seq`` (``missing``): a gap of at most :data:`MAX_SEQ_GAP`
        past the highest so far; one inside a counted gap that comes late after all is taken off again. A larger jump
        either way (a restarted third-party sensor numbering from 0 again, a forged number) counts nothing: the
        count goes on from ``seq``."""
        last, first = st.seq_last, st.seq_first
        if last is None or first is None or abs(seq - last) > MAX_SEQ_GAP:
            st.seq_first = st.seq_last = seq
        elif seq > last:
            self.counts.missing += seq - last - 1
            st.seq_last = seq
        elif seq > first:  # not a duplicate (refused before): one counted missing came late
            self.counts.missing = max(0, self.counts.missing - 1)

    def _take_token(self, st: SensorState, now: float) -> None:
        limit = RATE_FACTOR * st.link.rate_hz
        burst = self._burst(st.link)
        if st.refilled is not None:
            st.tokens = min(burst, st.tokens + max(0.0, now - st.refilled) * limit)
        st.refilled = now
        if st.tokens < 1.0:
            raise WireError("rate", f"sensor {st.link.sensor} sends faster than {limit:g} detections a second")
        st.tokens -= 1.0

    def take(self, t_from: float, t_to: float) -> list[TimedDetection]:
        """The kept detections with ``t_from <= t < t_to``, in time order (earlier ones are dropped as too old:
        their window is gone, a tracker that fell behind skipped it; they count as too old, not kept)."""
        lo = bisect.bisect_left(self._times, t_from)
        hi = bisect.bisect_left(self._times, t_to)
        self.counts.too_old += lo
        self.counts.det_rx -= lo
        taken = self._kept[lo:hi]
        del self._times[:hi], self._kept[:hi]
        return taken

    def pending(self) -> int:
        return len(self._kept)
