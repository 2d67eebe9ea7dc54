"""The tracker's schedule, its fusion rounds: when a round waits and when it fuses (the scan exchange and its
deadline, the reserve per round still to go, fusion held to the deadline or round 1 at once).

Stepped by hand on the in-memory network of :mod:`schedule_net` (no Zenoh, no processes)."""
from __future__ import annotations

import numpy as np
import pytest
from schedule_net import FRAC, SETTLE, T0, TS, Net, deadline, ests, run_steps

from zentrack.node.timing import FUSION_MARGIN_S
from zentrack.transport import wire
from zentrack.transport.messages import EstimateMessage


def test_scan_exchange_waits_for_the_neighbours_scans_or_its_deadline(monkeypatch):
    """A rule that exchanges scans: each node forwards its scan, updates once every live neighbour's scan is in
    (with all of them), and does not wait for a silent neighbour past the scan deadline."""
    from pathlib import Path

    monkeypatch.syspath_prepend(str(Path(__file__).parent / "plugins"))
    net = Net(fusion="ci-scans", plugins=["scan_exchange_rule"])
    net.start()
    net.at(T0 + 0.001)
    net.measure(0)
    net.at(T0 + 0.002)
    assert all(node.payload.state.phase == "await_scans" for node in net.nodes)
    sent = net.deliver()
    assert sorted((i, ch) for i, ch, _ in sent) == [(i, "scan") for i in range(3)]
    net.at(T0 + 0.003)  # every neighbour's scan is in: update with three scans, publish, fuse
    assert all(node.payload.state.phase == "fusing" for node in net.nodes)
    net.deliver()
    net.at(T0 + 0.004 + SETTLE)
    assert all(node.payload.state.phase == "await_meas" and node.payload.state.step == 1 for node in net.nodes)
    # step 1: node 2 is silent; nodes 0 and 1 wait for its scan until the scan deadline, then go on
    net.at(T0 + TS + 0.001)
    net.measure(1, [0, 1])
    net.at(T0 + TS + 0.002)
    net.deliver()
    net.at(T0 + TS + 0.003)
    assert net.nodes[0].payload.state.phase == "await_scans"
    scan_deadline = T0 + TS + FRAC * TS / 2
    net.at(scan_deadline - 0.001)
    assert net.nodes[0].payload.state.phase == "await_scans" and 0 < net.nodes[0].timeout() <= 0.001 + 1e-9
    net.at(scan_deadline + 0.0001)
    assert net.nodes[0].payload.state.phase == "fusing" and net.nodes[1].payload.state.phase == "fusing"


def round_deadline(now: float, window_end: float, left: int, rounds: int) -> float:
    reserve = FRAC * TS / (4 * rounds)
    return min(window_end, max(now + (window_end - now) / left, window_end - (left - 1) * reserve))


def test_each_round_waits_up_to_the_window_end_less_a_reserve_per_round_to_go():
    """ci with 4 rounds: a round waits for every live neighbour or its own deadline, set when it starts to the
    fusion window's end less a reserve per round still to go; a round fused without a neighbour's message
    counts as partial, its duration goes out with the next estimate, and the last round still ends inside the
    fusion window."""
    net = Net(fusion="ci", fusion_params={"rounds": 4})
    net.start()
    node = net.nodes[0]
    net.at(T0 + 0.001)
    net.measure(0)
    net.at(T0 + 0.010)
    window_end = deadline(0)  # t0 + frac Ts for the fusion of step 1
    assert node.payload.state.phase == "fusing" and node.payload.state.fuse_round == 1
    assert node.payload.state.round_deadline == pytest.approx(round_deadline(T0 + 0.010, window_end, 4, 4))
    assert node.payload.state.round_deadline == pytest.approx(window_end - 3 * FRAC * TS / 16)  # the reserve rules here
    net.deliver()
    net.at(T0 + 0.012)  # round 1 complete at once, but it waits its settle time
    assert node.payload.state.fuse_round == 1
    net.at(T0 + 0.010 + SETTLE)  # then round 2 starts with a share of the rest over 3 rounds
    assert node.payload.state.fuse_round == 2 and node.payload.counters.partial_rounds == 0
    assert node.payload.state.round_deadline == pytest.approx(round_deadline(T0 + 0.010 + SETTLE, window_end, 3, 4))
    net.now = window_end - 0.001  # a round that starts late gets an equal share of what is left instead
    node.payload.rounds.start_round()
    assert node.payload.state.round_deadline == pytest.approx(window_end - 0.001 + 0.001 / 3)
    net.now = T0 + 0.010 + SETTLE
    node.payload.rounds.start_round()
    net.frozen.add(2)  # node 2 stalls after sending round 2: rounds 3-4 of nodes 0 and 1 wait to their deadlines
    net.deliver()
    for _ in range(4):
        if node.payload.state.phase == "fusing":
            net.at(max(node.payload.state.round_deadline, net.now + 1e-4))
            net.deliver()
    assert node.payload.state.phase == "await_meas" and node.payload.state.step == 1
    assert node.payload.counters.partial_rounds == 2 and net.nodes[1].payload.counters.partial_rounds == 2
    assert node.clock() <= window_end + 1e-9 and node.payload.counters.misses == 0
    assert len(node.payload.state.last_round_ms) == 4 and node.payload.state.last_round_ms[0] == pytest.approx(SETTLE * 1e3)
    net.frozen.clear()
    net.at(T0 + TS + 0.001)
    net.measure(1, [0])
    net.at(T0 + TS + 0.002)
    raw = [data for i, ch, data in net.sent if i == 0 and ch == "est"]
    est = EstimateMessage.decode(raw[0], 0)
    assert est.round_ms is not None and est.round_ms.size == 4  # the rounds that made this step's prior
    est = EstimateMessage.decode(EstimateMessage(1, 0.1, 0, np.zeros(6), np.eye(6), 0.0,
                                                 round_ms=np.array([1.0, 2.0])).encode(), 0)
    assert est.round_ms is not None and est.round_ms.tolist() == [1.0, 2.0]
    with pytest.raises(wire.WireError, match="round_ms"):
        EstimateMessage.decode(EstimateMessage(1, 0.1, 0, np.zeros(6), np.eye(6), 0.0,
                                               round_ms=np.array([-1.0])).encode(), 0)


def test_fusion_waits_for_the_deadline_so_the_estimate_work_of_every_node_comes_first():
    """Realtime with room after the deadline (frac 0.5 of 100 ms): the estimate goes out at once, the round-1
    message is held until the step's deadline, a neighbour's message that comes before is kept, and the fusion
    window runs from the deadline to FUSION_MARGIN_S before the next sample."""
    net = Net(fusion_after_deadline=None)
    node = net.nodes[0]
    assert node.ctx.timing.fusion_after_deadline()
    net.start()
    net.at(T0 + 0.001)
    net.measure(0, [0])  # node 0 measured; nodes 1 and 2 later
    net.at(T0 + 0.002)
    sent = net.deliver()
    assert [(i, ch) for i, ch, _ in sent] == [(0, "est")]  # no round-1 message yet
    assert node.payload.state.phase == "fusing" and node.payload.state.hold_until == pytest.approx(deadline(0))
    assert node.timeout() == pytest.approx(deadline(0) - (T0 + 0.002))
    net.measure(0, [1, 2])
    net.at(T0 + 0.010)
    assert [(i, ch) for i, ch, _ in net.deliver()] == [(1, "est"), (2, "est")]
    net.at(deadline(0) - 1e-4)
    assert net.deliver() == [] and node.payload.state.hold_until is not None
    net.at(deadline(0))  # the deadline: every node shares round 1; the neighbours' messages are kept
    sent = net.deliver()
    assert sorted((i, ch) for i, ch, _ in sent) == [(0, "prior"), (1, "prior"), (2, "prior")]
    assert node.payload.state.round_deadline == pytest.approx(T0 + TS - FUSION_MARGIN_S)  # one round: the window's end
    net.at(deadline(0) + SETTLE + 0.001)
    assert node.payload.state.phase == "await_meas" and node.payload.state.step == 1 and node.payload.state.last_fused == 3
    assert node.payload.counters.misses == 0 and node.payload.counters.partial_rounds == 0
    # a silent neighbour: the round waits for it to the window's end, not past the next sample
    log = run_steps(net, 1, 1, measured=lambda k, i: True)
    assert len(ests(log, 1)) == 3
    net.at(deadline(1) + SETTLE + 0.001)  # the round-1 messages shared at the deadline are in: fused then
    assert node.payload.state.phase == "await_meas" and node.payload.state.step == 2 and node.payload.counters.misses == 0
    net.frozen.add(2)
    net.at(T0 + 2 * TS + 0.001)
    net.measure(2)
    net.at(T0 + 2 * TS + 0.002)
    net.at(deadline(2))
    net.deliver()
    assert node.payload.state.phase == "fusing" and node.payload.state.hold_until is None
    net.at(T0 + 3 * TS - FUSION_MARGIN_S - 1e-4)
    assert node.payload.state.phase == "fusing"
    net.at(T0 + 3 * TS - FUSION_MARGIN_S)
    assert node.payload.state.phase == "await_meas" and node.payload.state.step == 3 and node.payload.counters.partial_rounds == 1
    assert node.payload.counters.misses == 0


def test_a_deadline_late_in_the_period_or_lockstep_fuses_at_once():
    """With the deadline at 80 % of the period, 20 ms are left after it: less than half the measurement window,
    so round 1 goes out with the estimate, as it does in lockstep."""
    net = Net(fusion_after_deadline=None)
    net.start()
    for node in net.nodes:
        node.ctx.timing.frac = 0.8
    assert not net.nodes[0].ctx.timing.fusion_after_deadline()
    net.at(T0 + 0.001)
    net.measure(0, [0])
    net.at(T0 + 0.002)
    assert [(i, ch) for i, ch, _ in net.deliver()] == [(0, "est"), (0, "prior")]
    assert net.nodes[0].payload.state.round_deadline <= T0 + 0.8 * TS + 1e-9
    net.nodes[0].ctx.timing.frac, net.nodes[0].ctx.mode, net.nodes[0].ctx.timing.mode = 0.5, "lockstep", "lockstep"
    assert not net.nodes[0].ctx.timing.fusion_after_deadline()
