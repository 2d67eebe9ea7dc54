"""A many-target tracker of sensors of their own (issue 52), stepped by hand: ``mt-async``'s node 0 under its real
schedule (``node/track_lists/payload.py`` and ``windows.py``) with an injected clock, the sensors' simulated scans
(``multitarget_stream``) encoded as ``det`` messages and handed in at their publication times. Its neighbours
are not alive, so each step fuses nothing: what is compared is the windowed step itself, against the maths
(``NetworkTracker.local_step_over``) on the same scans at their true times."""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pytest

from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.fusion.models import plant_over
from zentrack.fusion.multitarget.network import NetworkTracker
from zentrack.fusion.scan import Scan
from zentrack.node.schedule import NodeSchedule
from zentrack.node.track_lists.payload import tracker_settings
from zentrack.transport.codec import Message
from zentrack.transport.detection_messages import Detection
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Start
from zentrack.transport.track_messages import TrackList
from zentrack.truth.simulation.sensor_stream import Latency, SimulatedDetection, multitarget_stream

T0, STEPS = 1000.0, 20
KEYS = Keys("w")


def setup():
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    return resolve_setup(p.parse_args(["--scenario", "mt-async", "--steps", str(STEPS)]))


class AsyncBench:
    """Node 0 taking the sensors ``takes``, each at its configured clock offset (``clock = "configured"``)."""

    def __init__(self, takes: tuple[int, ...] = (0,)) -> None:
        self.setup = setup()
        timing = self.setup.sensor_timing
        assert timing is not None
        self.cfg = self.setup.node_config(0)
        self.lag = timing.lag_ms / 1e3
        self.cfg.detections = {"lag_ms": timing.lag_ms, "clock": timing.clock, "sensors": [
            {"sensor": s, "rate_hz": timing.stream(s).rate_hz, "offset_s": timing.stream(s).offset_s,
             "min_latency_s": timing.stream(s).latency.low_s} for s in takes]}
        self.cfg.validate()
        self.now = T0 - 0.5
        self.sent: list[tuple[str, bytes]] = []
        self.node = NodeSchedule.track_lists(KEYS, self.cfg, lambda: self.now, lambda ch, b: self.sent.append((ch, b)))
        self.node.handle(Message("alive", KEYS.alive("truth"), b"put", self.now))
        self.node.handle(Message("start", KEYS.start, Start(T0, 1.0, STEPS, "realtime", tuple(range(8)), 0.5,
                                                            np.zeros(6)).encode(), self.now))
        self.node.advance()

    def stream(self, sensor: int, **change) -> list[SimulatedDetection]:
        """Sensor ``sensor``'s scans (its timing changed by ``change``)."""
        s = self.setup
        spec = replace(s.sensor_timing.stream(sensor), **change)
        return multitarget_stream(s.multitarget_data, s.multitarget, float(s.spec.noise_levels()[sensor]), spec, s.seed)

    def run(self, arrivals: list[tuple[float, int, SimulatedDetection]]) -> list[TrackList]:
        """Every step to the run's end, the detections handed in at their run times ``arrivals`` ((time, sensor,
        scan)); the lists the node published."""
        data = self.setup.multitarget_data
        events = [(T0 + t, 0, s, d) for t, s, d in arrivals]
        events += [(T0 + self.lag + k + dt, 1, -1, None) for k in range(STEPS) for dt in (0.001, 0.6)]
        for t, _, sensor, d in sorted(events, key=lambda e: (e[0], e[1])):
            self.now = t
            if d is not None:
                wire = Detection(d.seq, T0 + d.stamp, sensor, d.returns, data.sensors[sensor],
                                 data.noise_cov[sensor], T0 + d.stamp)
                self.node.handle(Message("det", KEYS.det(sensor), wire.encode(), self.now))
            self.node.advance()
        return [TrackList.decode(b, 0, 6) for ch, b in self.sent if ch == "tracks"]

    @property
    def counts(self):
        return self.node.payload.windows.intake.counts


def estimates(lists: list[TrackList]) -> list[list[tuple]]:
    """Per step, the tracks' status, mean and covariance (their serials start at the node's start time)."""
    return [[(e.status, e.mean, e.cov) for e in lst.tracks] for lst in lists]


def assert_same(a: list[TrackList], b: list[TrackList]) -> int:
    assert [lst.k for lst in a] == [lst.k for lst in b] == list(range(STEPS))
    held = 0
    for ka, kb in zip(estimates(a), estimates(b)):
        assert [e[0] for e in ka] == [e[0] for e in kb]
        for (_, ma, ca), (_, mb, cb) in zip(ka, kb):
            np.testing.assert_array_equal(ma, mb)
            np.testing.assert_array_equal(ca, cb)
        held += len(ka)
    return held


def test_scans_out_of_order_within_the_lag_give_the_tracks_of_the_same_scans_in_order() -> None:
    """Two 4 Hz sensors' scans (0 and 3, clocks 0.12 s ahead and 0.15 s behind) come 10-90 ms late, and a third of
    them a period (0.25 s) later still, after the next: all within the lag (0.35 s). The lists equal, to the last
    bit, those of the same scans handed in at their measurement times, in order."""
    runs, benches = [], []
    for late in (True, False):
        b = AsyncBench(takes=(0, 3))
        arrivals = [(d.t_publish if late else d.t, s, d) for s in (0, 3)
                    for d in b.stream(s, latency=Latency("uniform", 0.01, 0.09), reorder=0.3)]
        runs.append(b.run(arrivals))
        benches.append(b)
    late_counts, timely_counts = benches[0].counts, benches[1].counts
    assert late_counts.out_of_order >= 10 and timely_counts.out_of_order == 0, (late_counts, timely_counts)
    assert late_counts.too_old == timely_counts.too_old == 0
    assert late_counts.det_rx == timely_counts.det_rx == len(benches[0].stream(0)) + len(benches[0].stream(3))
    assert assert_same(runs[0], runs[1]) >= 4 * (STEPS - 5)  # (its tentative tracks of clutter too)


def test_two_sensors_at_their_own_times_are_taken_as_the_maths_takes_them() -> None:
    """Sensors 0 (4 Hz, clock 0.12 s ahead) and 1 (2 Hz, 0.08 s behind) with their latencies: each window's
    scans, mapped to the tracker's clock by each sensor's offset, in time order across the sensors, give the
    tracks ``NetworkTracker.local_step_over`` gives on the scans at their true times."""
    b = AsyncBench(takes=(0, 1))
    streams = {s: b.stream(s, reorder=0.0) for s in (0, 1)}
    lists = b.run([(d.t_publish, s, d) for s, ds in streams.items() for d in ds])
    data, spec = b.setup.multitarget_data, b.setup.spec
    ref = NetworkTracker(0, tracker_settings(b.cfg), over=lambda dt: plant_over(spec.plant, 1.0, dt,
                                                                                dict(spec.plant_params)))
    scans = sorted(((T0 + d.t, s, d) for s, ds in streams.items() for d in ds), key=lambda e: e[0])
    expected = []
    for k in range(STEPS):
        lo, hi = T0 + max(k - 1, 0), T0 + k
        timed = [(t, Scan(k, s, d.returns, data.sensors[s], data.noise_cov[s])) for t, s, d in scans if lo <= t < hi]
        ref.local_step_over(k, lo if ref.step is None else T0 + ref.step, hi, timed)
        expected.append([(e.status, e.mean, e.cov) for e in ref.estimates()])
        ref.fuse({})
    assert b.counts.too_old == 0 and b.counts.det_rx == sum(len(ds) for ds in streams.values())
    got = estimates(lists)
    held = 0
    for k in range(STEPS):
        assert [e[0] for e in got[k]] == [e[0] for e in expected[k]], k
        for (_, m, c), (_, me, ce) in zip(got[k], expected[k]):
            np.testing.assert_allclose(m, me, rtol=0, atol=1e-6)  # (the times through the wire's float64 stamps)
            np.testing.assert_allclose(c, ce, rtol=1e-9, atol=1e-6)
        held += sum(e[0] == "confirmed" for e in got[k])
    assert held >= 4 * (STEPS - 5)


def test_a_scan_after_its_window_is_counted_too_old_and_moves_nothing() -> None:
    """Sensor 0's scan of 4.5 s comes at 6.0 s, after window [4 s, 5 s) was taken (at 5.35 s): counted too old, the
    lists are those of the run without it."""
    runs, benches = [], []
    for straggler in (False, True):
        b = AsyncBench()
        stream = b.stream(0, reorder=0.0)
        late = next(d for d in stream if abs(d.t - 4.5) < 1e-9)
        arrivals = [(d.t_publish, 0, d) for d in stream if d is not late]
        if straggler:
            arrivals.append((6.0, 0, late))
        runs.append(b.run(arrivals))
        benches.append(b)
    assert benches[1].counts.too_old == 1 and benches[0].counts.too_old == 0
    assert benches[1].counts.det_rx == benches[0].counts.det_rx
    assert assert_same(runs[0], runs[1]) > 0


def test_the_list_of_step_k_is_valid_at_its_window_end_and_names_the_last_scan() -> None:
    """Each list says step k (valid at t0 + k ts), is out at its window's end plus the lag, within its deadline,
    and carries the last scan's publication time on the tracker's clock (the sensor's offset taken off)."""
    b = AsyncBench()
    stream = b.stream(0, reorder=0.0)
    lists = b.run([(d.t_publish, 0, d) for d in stream])
    assert all(not lst.miss for lst in lists) and b.node.payload.counters["misses"] == 0
    for lst in lists[1:]:
        last = max((d for d in stream if lst.k - 1 <= d.t < lst.k), key=lambda d: d.t_publish)
        assert lst.t_meas_pub == pytest.approx(T0 + last.stamp - b.setup.sensor_timing.stream(0).offset_s, abs=1e-9)
        assert T0 + lst.k + b.lag <= lst.t_pub < T0 + lst.k + b.lag + 0.01


def test_the_flood_guard_lets_a_fast_sensor_through_to_the_intakes_rate_limit() -> None:
    """A 30 Hz camera feeding a tracker of a 1 s period: the inbox's guard per key (4x what a sender sends) is
    set by the sensor's rate, above the intake's own limit (``RATE_FACTOR`` times it), not by the period."""
    from zentrack.node.detections import RATE_FACTOR

    b = AsyncBench()
    assert b.node.flood_rate() == pytest.approx(4.0 * 4.0 + 20.0)  # sensor 0: 4 Hz, the period 1 Hz
    b.cfg.detections["sensors"][0]["rate_hz"] = 30.0
    fast = NodeSchedule.track_lists(KEYS, b.cfg, lambda: b.now, lambda ch, data: None)
    assert fast.flood_rate() > RATE_FACTOR * 30.0 and fast.flood_rate() == pytest.approx(4.0 * 30.0 + 20.0)
