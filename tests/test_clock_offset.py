"""A tracker's clock offset against the run's schedule (``node/clock_offset.py``): the estimator on injected
samples, the corrected clock's log lines, and a schedule whose local clock is off by ±0.3 s, driven by hand."""
from __future__ import annotations

import logging

import numpy as np
import pytest
from test_node_schedule import T0, TS, Net

from zentrack.node.clock_offset import (
    DEAD_BAND_S,
    HOLD_START_S,
    TOLERANCE_S,
    WINDOW,
    OffsetEstimator,
    RunClock,
    StartGate,
    fits_schedule,
)
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.schedule import NodeSchedule
from zentrack.transport.codec import Message
from zentrack.transport.messages import Measurement, Start


def delays(n: int, seed: int = 1) -> np.ndarray:
    """One-way delays as a loaded host sees them: a few ms, a long tail."""
    return 0.001 + np.random.default_rng(seed).exponential(0.004, n)


@pytest.mark.parametrize("offset", [0.3, -0.3, 0.05, -0.45])
def test_the_estimate_is_the_offset_plus_the_least_delay(offset):
    est = OffsetEstimator()
    for k, d in enumerate(delays(200)):
        est.add(1000.0 + k * TS + offset + d, 1000.0 + k * TS, key=k)
    assert est.converged and not est.exceeded
    assert offset < est.estimate < offset + 0.005
    assert est.offset == pytest.approx(est.estimate - np.sign(offset) * DEAD_BAND_S)


def test_applied_from_the_first_sample_established_after_a_few():
    est = OffsetEstimator()
    assert est.offset == 0.0 and est.estimate is None and not est.converged
    est.add(10.302, 10.0, key=0)
    assert est.offset == pytest.approx(0.302 - DEAD_BAND_S) and not est.converged
    for k in range(1, 5):
        est.add(10.3015 + k, 10.0 + k, key=k)
    assert est.converged


def test_synchronised_hosts_and_small_delays_are_left_alone():
    est = OffsetEstimator()
    for k, d in enumerate(delays(100)):
        est.add(5.0 + k + 0.002 + d, 5.0 + k, key=k)
    assert est.estimate < DEAD_BAND_S and est.offset == 0.0


def test_delayed_samples_and_a_few_forged_ones_do_not_move_it():
    est = OffsetEstimator()
    for k, d in enumerate(delays(WINDOW)):
        est.add(k + 0.3 + d, float(k), key=k)
    clean = est.estimate
    for k in range(WINDOW, WINDOW + 8):  # forged: "published" 0.4 s later than they were (pulls it down)
        est.add(k + 0.3, k + 0.7, key=k)
    for k in range(WINDOW + 8, WINDOW + 16):  # delayed by 2 s (a stall): pushes it up
        est.add(k + 2.3, float(k), key=k)
    assert est.estimate == pytest.approx(clean, abs=0.003)


def test_forged_samples_cannot_drag_the_applied_offset_beyond_the_tolerance():
    est = OffsetEstimator()
    for k in range(3 * WINDOW):
        est.add(float(k) - 50.0, float(k), key=k)  # a whole window of forgeries saying -50 s
    assert est.exceeded and est.offset == -TOLERANCE_S


def test_a_step_is_one_sample_and_nan_is_none():
    est = OffsetEstimator()
    assert est.add(1.3, 1.0, key=7)
    assert not est.add(0.0, 1.0, key=7)  # a second copy of step 7, however early
    assert not est.add(float("nan"), 1.0, key=8)
    assert est.samples == 1 and est.estimate == pytest.approx(0.3)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="tolerance"):
        OffsetEstimator(tolerance=0)
    with pytest.raises(ValueError, match="quantile"):
        OffsetEstimator(quantile=1.5)


def test_a_sample_must_fit_the_schedule():
    assert fits_schedule(3, 100.31, None, None)  # before the start: anything
    assert fits_schedule(3, 100.301, 100.0, 0.1)
    assert not fits_schedule(3, 100.9, 100.0, 0.1)  # step 3 "published" 6 periods late: no sample
    assert not fits_schedule(3, 99.0, 100.0, 0.1)


def test_logged_once_established_then_on_a_material_change(caplog):
    local = [0.0]
    clock = RunClock(4, local=lambda: local[0])
    with caplog.at_level(logging.INFO, logger="zentrack.node"):
        for k in range(20):
            clock.observe(k + 0.301, float(k), key=k)
        lines = [r.getMessage() for r in caplog.records if "clock offset" in r.getMessage()]
        assert len(lines) == 1 and "node 4: clock offset established +0.291 s" in lines[0], lines
        for k in range(20, 20 + WINDOW):  # the clock steps by 0.1 s (NTP stepped it): logged again
            clock.observe(k + 0.401, float(k), key=k)
    lines = [r.getMessage() for r in caplog.records if "clock offset" in r.getMessage()]
    assert len(lines) == 2 and "now +0.391 s" in lines[1], lines
    local[0] = 100.0
    assert clock() == pytest.approx(100.0 - 0.391) and clock.to_run(50.0) == pytest.approx(50.0 - 0.391)
    assert clock.report()["clock_offset_s"] == pytest.approx(0.391) and not clock.report()["clock_exceeded"]


def test_beyond_the_tolerance_one_line_names_the_clock(caplog):
    clock = RunClock(2, local=lambda: 0.0)
    with caplog.at_level(logging.INFO, logger="zentrack.node"):
        for k in range(100):
            clock.observe(k + 0.8, float(k), key=k)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [warnings[0]] and warnings[0].startswith(
        "node 2: clock offset +0.8 s against the run's schedule exceeds ±0.5 s: this host's clock is off"), warnings
    assert clock.offset == TOLERANCE_S and clock.report()["clock_exceeded"]


# ---------------------------------------------------------------- a schedule whose local clock is off

class SkewedNet(Net):
    """:class:`Net` whose node 0 reads a local clock ``skew`` s off the run's, corrected (or not) by a
    :class:`RunClock` that every message to it passes through, as ``node/process.py`` does."""

    def __init__(self, skew: float, corrected: bool = True) -> None:
        super().__init__(fusion_after_deadline=None)
        self.skew, self.corrected = skew, corrected
        self.clock = RunClock(0, local=lambda: self.now + skew)
        cfg = self.setup.node_config(0)
        node = NodeSchedule.diffusion(self.keys, cfg, Tracker(cfg), clock=self.clock if corrected else self.clock.local,
                            send=lambda ch, data: self.sent.append((0, ch, data)), incarnation=100)
        handle, width = node.handle, cfg.measurement_dim

        def skewed_handle(msg):
            msg.t_recv += skew  # received on the local clock
            if corrected:
                self.clock.receive(msg, width, node.t0, node.ts)
            handle(msg)

        node.handle = skewed_handle
        self.nodes[0] = node


def run_realtime(net: Net, steps: int) -> None:
    """Steps 0..steps-1 at realtime, each node acting whenever its own timeout says (a node's clock may be off)."""
    for k in range(steps):
        net.at(T0 + k * TS + 0.001)
        net.measure(k)
        for t in np.arange(T0 + k * TS + 0.002, T0 + (k + 1) * TS, 0.005):
            net.at(float(t))
            net.deliver()


def measured_estimates(log: list, node: int) -> set[int]:
    return {m["k"] for i, ch, m in log if i == node and ch == "est" and not m["coasted"]}


@pytest.mark.parametrize("skew", [0.3, -0.3, 0.05])
def test_a_node_whose_clock_is_off_keeps_the_schedule_on_the_corrected_clock(skew):
    steps, log = 60, []
    for corrected in (False, True):
        net = SkewedNet(skew, corrected)
        net.now = T0 - 0.5
        net.start()
        sent: list = []
        orig = net.deliver

        def deliver(orig=orig, sent=sent):
            out = orig()
            sent.extend(out)
            return out

        net.deliver = deliver
        run_realtime(net, steps)
        log.append((measured_estimates(sent, 0), net.nodes[0].ctx.rejects.counts, measured_estimates(sent, 1)))
    (raw, raw_rejects, _), (fixed, fixed_rejects, neighbour) = log
    assert len(raw) < 0.5 * steps, (len(raw), raw_rejects)  # today's behaviour: its measurements are refused or late
    assert len(fixed) >= 0.95 * steps, (sorted(set(range(steps)) - fixed), fixed_rejects)
    assert len(neighbour) == steps
    assert net.clock.offset == pytest.approx(skew - np.sign(skew) * DEAD_BAND_S, abs=0.003)
    assert net.nodes[0].payload.counters.misses <= 0.05 * steps



def start_msg(t0: float, t_recv: float) -> Message:
    payload = Start(t0, TS, 100, "realtime", (0, 1, 2), 0.5, np.zeros(4)).encode()
    return Message("start", "zentrack/unit/ctl/start", payload, t_recv)


def test_a_late_joiners_start_waits_for_the_clocks_first_sample():
    local = [T0 + 10.0]
    clock = RunClock(0, local=lambda: local[0])
    gate = StartGate(clock)
    assert not gate.hold(start_msg(T0, T0 - 0.4), started=False, realtime=True)  # a cold start: never held
    first, again = start_msg(T0, T0 + 10.0), start_msg(T0, T0 + 10.01)
    assert gate.hold(first, started=False, realtime=True) and gate.hold(again, started=False, realtime=True)
    assert gate.due() == []
    clock.observe(T0 + 10.05, T0 + 9.75, key=97)  # a measurement: the clock has a sample
    assert gate.due() == [first, again] and gate.due() == []
    assert not gate.hold(start_msg(T0, T0 + 11.0), started=False, realtime=True)  # the clock has samples now


def test_without_a_measurement_the_start_goes_on_after_the_hold():
    local = [T0 + 10.0]
    clock = RunClock(0, local=lambda: local[0])
    gate = StartGate(clock)
    msg = start_msg(T0, T0 + 10.0)
    assert gate.hold(msg, started=False, realtime=True) and gate.due() == []
    local[0] += HOLD_START_S
    assert gate.due() == [msg]
    assert not gate.hold(msg, started=True, realtime=True) and not gate.hold(msg, started=False, realtime=False)
    assert not gate.hold(Message("start", "k", b"garbage", T0 + 20.0), started=False, realtime=True)


def test_lockstep_takes_no_samples():
    clock = RunClock(0, local=lambda: 5.0, sampling=False)
    meas = Measurement(3, 0.3, 0, None, None, 4.0).encode()
    msg = Message("meas", "zentrack/unit/meas/0", meas, 5.0)
    clock.receive(msg, 2, None, None)
    assert clock.estimator.samples == 0 and msg.t_recv == 5.0
    sampled = RunClock(0, local=lambda: 5.0)
    sampled.receive(msg, 2, None, None)
    assert sampled.estimator.samples == 1 and msg.t_recv == pytest.approx(5.0 - sampled.offset)


def test_node_prefix_is_checked_against_the_run():
    import argparse

    from zentrack.cluster.run.options import node_prefix_arg, node_prefixes

    assert node_prefix_arg("1=faketime -f '+0.3s'") == (1, ["faketime", "-f", "+0.3s"])
    for bad in ("x", "1=", "a=faketime"):
        with pytest.raises(argparse.ArgumentTypeError, match="expected I=COMMAND"):
            node_prefix_arg(bad)
    assert node_prefixes({2: ["env"]}, 6) == {2: ["env"]}
    with pytest.raises(ValueError, match="the run has trackers 0..5"):
        node_prefixes({6: ["env"]}, 6)
    with pytest.raises(ValueError, match="no command 'no-such-command-here' on PATH"):
        node_prefixes({0: ["no-such-command-here", "-x"]}, 6)
