"""The latency budget (``node/timing.py``, the node configuration's ``latency_budget_ms``): a node whose
measurements and neighbours' messages come late still uses them, and a budget of 0 is the schedule as before."""
from __future__ import annotations

import argparse

import pytest
from test_node_schedule import FRAC, T0, TS, Net

from zentrack.config.node_config import NodeConfigError
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.node.timing import COAST_MARGIN_S, FUSION_MARGIN_S, REALTIME_FUTURE_STEPS, StepTiming
from zentrack.transport import wire
from zentrack.transport.messages import Measurement


def timing(budget: float) -> StepTiming:
    return StepTiming("realtime", FRAC, TS, t0=T0, budget=budget)


def test_a_budget_shifts_every_deadline_and_window_of_the_schedule_by_itself():
    plain, late = timing(0.0), timing(0.25)
    for k in (0, 1, 7):
        assert late.deadline(k) == pytest.approx(plain.deadline(k) + 0.25)
        assert late.fusion_window_end(k + 1) == pytest.approx(plain.fusion_window_end(k + 1) + 0.25)
        assert late.scan_deadline(k, 2) == pytest.approx(plain.scan_deadline(k, 2) + 0.25)
        assert late.relay_deadline(k, 2) == pytest.approx(plain.relay_deadline(k, 2) + 0.25)
        assert late.round_deadline(T0 + 0.25 + k * TS, k + 1, 1, 2) == pytest.approx(
            plain.round_deadline(T0 + k * TS, k + 1, 1, 2) + 0.25)
    assert late.start() == T0 + 0.25 and late.fusion_after_deadline() == plain.fusion_after_deadline()
    assert late.k_now(T0 + 0.3) == plain.k_now(T0 + 0.05) == 0 and late.k_run(T0 + 0.3) == 3


def test_budget_zero_is_the_schedule_as_before():
    t = timing(0.0)
    assert t.deadline(3) == pytest.approx(T0 + (3 + FRAC) * TS)
    assert t.fusion_window_end(4) == pytest.approx(T0 + 4 * TS - FUSION_MARGIN_S)
    assert t.meas_window(5, T0 + 5.02 * TS) == (5, 5 + REALTIME_FUTURE_STEPS)
    assert t.prior_window(4, T0 + 5.02 * TS) == (4, 5 + REALTIME_FUTURE_STEPS + 1)


def test_how_far_ahead_a_message_may_be_is_judged_on_the_run_clock_not_the_late_schedule():
    late = timing(2.5 * TS)  # the schedule is still at step 2 when the truth publishes step 5
    now = T0 + 5 * TS + 0.001
    lo, hi = late.meas_window(2, now)
    assert lo == 2 and hi == 5 + REALTIME_FUTURE_STEPS  # step 5's measurement is not from the future
    lo, hi = late.prior_window(2, now)
    assert lo == 1 and hi == 5 + REALTIME_FUTURE_STEPS + 1


def drive(budget_ms: float, meas_delay: float, link_delay: float, steps: int = 30,
          frozen: tuple[int, float, float] | None = None) -> tuple[Net, dict[int, dict[int, bool]]]:
    """Three realtime nodes (fusion after the deadline, as a tracker process decides it) whose measurements
    come ``meas_delay`` after their sample time and whose messages to each other take ``link_delay``;
    ``frozen``: (node, from, to) in seconds after t0, a node that neither receives nor acts meanwhile.
    Returns the schedules and each node's estimates (step: coasted)."""
    net = Net(fusion_after_deadline=None, latency_budget_ms=budget_ms)
    net.start()
    queue: list[tuple[float, int, str, bytes]] = []
    estimates: dict[int, dict[int, bool]] = {i: {} for i in range(len(net.nodes))}
    tick = 0.001
    for n in range(int(steps * TS / tick)):
        net.now = T0 + n * tick
        k, phase = divmod(n * tick, TS)
        asleep = {frozen[0]} if frozen is not None and frozen[1] <= n * tick < frozen[2] else set()
        if abs(phase - meas_delay) < tick / 2 and int(k) < steps:
            for i, node in enumerate(net.nodes):
                z = net.scn.measurements[0, int(k), i]
                if i not in asleep:
                    node.handle(net.msg("meas", net.keys.meas(i), Measurement(int(k), k * TS, i, z, None, net.now - meas_delay).encode()))
        for i, node in enumerate(net.nodes):
            if i not in asleep:
                node.advance()
        for i, ch, data in net.sent:
            if ch == "est":
                est = wire.unpack(data)
                estimates[i][est["k"]] = est["coasted"]
        queue += [(net.now + link_delay, i, ch, data) for i, ch, data in net.sent if ch == "prior"]
        net.sent = []
        due = [q for q in queue if q[0] <= net.now]
        queue = [q for q in queue if q[0] > net.now]
        for _, i, ch, data in due:
            for j, node in enumerate(net.nodes):
                if i in node.payload.tracker.neighbours and j not in asleep:
                    node.handle(net.msg(ch, net.keys.prior(i), data))
    return net, estimates


def test_measurements_later_than_the_coast_point_are_used_within_the_budget():
    late_meas = FRAC * TS - COAST_MARGIN_S + 0.03  # 30 ms after the point where a node coasts without a budget
    without, _ = drive(0.0, late_meas, 0.03)
    assert all(node.payload.counters.coasted >= 25 for node in without.nodes), [n.payload.counters.coasted for n in without.nodes]
    within, _ = drive(100.0, late_meas, 0.03)
    for node in within.nodes:
        c = node.payload.counters
        assert c.coasted == 0 and c.misses == 0 and c.steps >= 28, (c.coasted, c.misses, c.steps)
        assert c.partial_rounds == 0 and node.payload.state.last_fused == 3  # the neighbours' priors, 30 ms late, are fused


def test_the_budget_is_a_checked_option_and_a_checked_field():
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    assert p.parse_args(["--latency-budget-ms", "60"]).latency_budget_ms == 60.0
    for bad in ("-1", "nan", "1e9"):
        with pytest.raises(SystemExit):
            p.parse_args(["--latency-budget-ms", bad])
    cfg = Net().setup.node_config(0)
    assert cfg.latency_budget_ms == 0.0
    cfg.latency_budget_ms = -5.0
    with pytest.raises(NodeConfigError, match="latency_budget_ms"):
        cfg.validate("node 0")


def test_a_node_frozen_under_a_budget_catches_up_and_uses_its_measurements_again():
    late_meas = FRAC * TS - COAST_MARGIN_S + 0.03
    net, estimates = drive(100.0, late_meas, 0.03, steps=40, frozen=(1, 1.0, 1.35))  # steps 10-13 asleep
    node = net.nodes[1]
    assert node.payload.counters.misses >= 3  # the steps it slept through
    back = sorted(k for k in estimates[1] if k >= 14)
    assert back and back[0] <= 20 and back[-1] >= 37, back  # publishing again within a few steps, to the end
    assert not any(estimates[1][k] for k in back if k >= back[0] + 3), estimates[1]  # with its measurements
    assert all(not any(c for k, c in estimates[i].items() if k > 0) for i in (0, 2))  # the others never coasted
