"""The tracker's schedule as a pure state machine: phase by phase, with an injected clock and an in-memory bus.

No Zenoh and no processes: messages are encoded with the real wire codec and delivered by hand, so every
transition (start, measurement, coasting, deadline fusion, warm-up, recovery when every node warms at once)
is checked deterministically."""
from __future__ import annotations

import numpy as np
import pytest
from schedule_net import FRAC, SETTLE, T0, TS, Net, deadline, ests, run_steps  # noqa: F401 - others import them

from zentrack.node.diffusion.tracker import MAX_COAST_STEPS
from zentrack.transport import wire
from zentrack.transport.messages import RoundMessage, Stop


def test_idle_until_start_then_cold_start_at_step_zero():
    net = Net()
    node = net.nodes[0]
    assert node.payload.state.phase == "idle" and node.timeout() == 0.2
    net.at(T0 + 0.001)
    net.measure(0, [0])  # a measurement before the start is kept, not rejected ...
    assert node.payload.state.phase == "idle" and len(node.early) == 1 and not node.ctx.rejects.counts
    net.start([0])  # ... and used once the start comes: step 0 is updated at once
    assert node.ctx.rejects.counts == {} and node.early == []
    net.at(T0 + 0.002)
    assert node.payload.state.phase == "fusing" and node.payload.state.fuse_step == 1 and node.payload.counters.meas_rx == 1
    sent = net.deliver()
    assert [(i, ch) for i, ch, _ in sent] == [(0, "est"), (0, "prior")] and sent[0][2]["coasted"] is False


def test_messages_before_the_start_are_bounded():
    from zentrack.node.schedule import EARLY_KEPT

    net = Net()
    node = net.nodes[0]
    for _ in range(EARLY_KEPT + 5):
        net.measure(0, [0])
    assert len(node.early) == EARLY_KEPT and node.ctx.rejects.counts["unexpected"] == 5


def test_measurement_update_publishes_estimate_and_prior_then_fuses_every_neighbour():
    net = Net()
    net.start()
    net.at(T0 + 0.001)
    net.measure(0)
    net.at(T0 + 0.002)
    node = net.nodes[0]
    assert node.payload.state.phase == "fusing" and node.payload.state.fuse_step == 1
    sent = net.deliver()
    assert sorted((i, ch) for i, ch, _ in sent) == [(i, ch) for i in range(3) for ch in ("est", "prior")]
    assert all(m["warm"] is False for _, ch, m in sent if ch == "prior")
    net.at(T0 + 0.003)  # every live neighbour's pair is in, but the round waits its settle time
    assert node.payload.state.phase == "fusing"
    net.at(T0 + 0.002 + SETTLE + 1e-4)  # then it fuses, long before the deadline
    assert node.payload.state.phase == "await_meas" and node.payload.state.step == 1 and node.payload.state.last_fused == 3
    assert node.payload.counters.misses == 0 and node.payload.counters.steps == 1


def test_missing_measurement_coasts_at_the_deadline_and_a_missing_neighbour_is_left_out():
    net = Net()
    net.start()
    log = run_steps(net, 0, 3, measured=lambda k, i: not (i == 1 and k == 2))
    coasted = {(i, m["k"]): m["coasted"] for i, m in ests(log)}
    assert coasted[(1, 2)] is True and coasted[(0, 2)] is False
    # node 2 dies (its token goes away): node 0 fuses its own and node 1's pair only, at once
    for node in net.nodes[:2]:
        node.handle(net.msg("alive", net.keys.alive(2), b"delete"))
    log = run_steps(net, 4, 5, measured=lambda k, i: i != 2)
    assert net.nodes[0].payload.state.last_fused == 2 and net.nodes[0].payload.counters.misses == 0


def test_late_prior_is_counted_not_fused():
    net = Net()
    net.start()
    run_steps(net, 0, 0)
    node = net.nodes[0]
    assert node.payload.state.fused_upto == 1
    late = RoundMessage(1, 0.1, 1, 1, {"state": (np.eye(12), np.zeros(12))}, net.now).encode()
    node.handle(net.msg("prior", net.keys.prior(1), late))
    assert node.payload.counters.late == 1


@pytest.mark.parametrize("after_deadline", [False, None], ids=["round-1-at-once", "fusion-after-deadline"])
def test_every_node_warming_at_once_recovers_at_the_first_deadline(after_deadline):
    """A truth stall: nobody gets a measurement for more than MAX_COAST_STEPS steps, so every node is stale
    when measurements return. Under the old rule (a warming node publishes nothing) nobody ever fused again."""
    net = Net(fusion_after_deadline=after_deadline)
    net.start()
    run_steps(net, 0, 9)
    stall = range(10, 10 + MAX_COAST_STEPS + 3)
    log = run_steps(net, 10, stall[-1], measured=lambda k, i: k not in stall)
    assert all(node.payload.stale for node in net.nodes)
    assert all(m["coasted"] for _, m in ests(log))
    back = stall[-1] + 1
    log = run_steps(net, back, back + 5)
    warm_priors = [(i, m["k"]) for i, ch, m in log if ch == "prior" and m["warm"]]
    assert {i for i, _ in warm_priors} == {0, 1, 2}, "a warming node shares its own prediction, flagged warm"
    for node in net.nodes:
        assert node.payload.counters.warm_self == 1 and node.payload.state.phase in ("await_meas", "fusing")
        assert not node.payload.stale
    # everybody publishes estimates again within two steps of the stall's end, and fresh (non-warm) priors
    for k in range(back + 2, back + 6):
        assert sorted(i for i, _ in ests(log, k)) == [0, 1, 2], f"step {k}"
    assert not [m for _, ch, m in log if ch == "prior" and m["k"] > back + 2 and m["warm"]]
    truth = net.scn.truth[0]
    for _i, m in ests(log, back + 5):
        assert np.linalg.norm(wire.unpack_array(m["x"], (6,), "x")[:3] - truth[back + 5, :3]) < 200


@pytest.mark.parametrize("after_deadline", [False, None], ids=["round-1-at-once", "fusion-after-deadline"])
def test_restarted_node_warm_starts_from_fresh_neighbours_not_from_its_cold_prior(after_deadline):
    """With fusion after the deadline the neighbours share their fresh pairs at the deadline, so a warming node
    must wait for them to the window's end (deciding at the deadline it found none, every step, and cold
    started after 20: the soak's restarted trackers took 22 steps to come back)."""
    net = Net(fusion_after_deadline=after_deadline)
    net.start()
    run_steps(net, 0, 29)
    net.nodes[2] = net._make(2, 20, after_deadline)  # a restart: a new process with no state
    net.start([2])
    assert net.nodes[2].payload.state.phase == "warming"
    log = run_steps(net, 30, 34)
    node = net.nodes[2]
    assert node.payload.counters.warm_starts == 1 and node.payload.counters.warm_self == 0
    assert not [m for i, ch, m in log if i == 2 and ch == "prior" and m["warm"]], "no state: nothing to share"
    first = min(m["k"] for _, m in ests(log) if _ == 2)
    assert first <= 32 and [m["warm"] for i, m in ests(log, first) if i == 2] == [True]


@pytest.mark.parametrize("after_deadline", [False, None], ids=["round-1-at-once", "fusion-after-deadline"])
def test_frozen_node_catches_up_then_rejoins_through_its_neighbours(after_deadline):
    net = Net(fusion_after_deadline=after_deadline)
    net.start()
    run_steps(net, 0, 9)
    frozen = range(10, 20)
    net.frozen = {0}
    run_steps(net, 10, 19)
    net.frozen = set()
    log = run_steps(net, 20, 24)
    node = net.nodes[0]
    assert node.payload.counters.misses >= len(frozen) - 1
    assert node.payload.counters.warm_starts == 1
    assert sorted(i for i, _ in ests(log, 24)) == [0, 1, 2]


def test_node_without_state_and_without_neighbour_states_cold_starts_after_the_limit():
    net = Net(cold_after=4)
    net.start()
    net.nodes = net.nodes[:1]  # node 0 alone; its neighbours are configured but silent
    node = net.nodes[0]
    node.payload.tracker.prior, node.payload.tracker.prior_step = None, None
    net.at(T0 + 3 * TS)
    node.payload.warm.start_warming(net.now)
    log = run_steps(net, 3, 12)
    assert node.payload.counters.cold_restarts == 1 and node.payload.state.phase in ("await_meas", "fusing")
    assert ests(log), "it estimates again after the cold start"


def test_fresh_node_leaves_warm_pairs_out_of_its_fusion():
    net = Net()
    tracker = net.nodes[0].payload.tracker
    tracker.set_initial(net.scn.x0_estimate[0])
    tracker.cold_start(5)
    own = tracker.predict_pair(tracker.prior, 6)
    fresh = tracker.predict_pair(tracker.prior, 6)
    stale = tracker.predict_pair(tracker.prior, 6)
    stale.warm = True
    assert tracker.fuse(6, own, {1: fresh, 2: stale})[0] == 2
    own.warm = True
    assert tracker.fuse(6, own, {1: fresh, 2: stale})[0] == 3


@pytest.mark.parametrize("value", [1, "yes", None])
def test_warm_flag_must_be_a_boolean_on_the_wire(value):
    import msgpack

    good = RoundMessage(3, 0.3, 1, 1, {"state": (np.eye(12), np.zeros(12))}, 0.0, warm=True).encode()
    assert RoundMessage.decode(good, 1, 12).warm is True
    msg = msgpack.unpackb(good)
    msg["warm"] = value
    with pytest.raises(wire.WireError, match="warm"):
        RoundMessage.decode(msgpack.packb(msg, use_bin_type=True), 1, 12)


def test_stop_only_from_truth():
    net = Net()
    net.start()
    node = net.nodes[0]
    forged = wire.encode("stop", 0, 0.0, 3)
    node.handle(net.msg("stop", net.keys.stop, forged))
    assert not node.done() and node.ctx.rejects.counts["kind"] == 1
    node.handle(net.msg("stop", net.keys.stop, Stop(5).encode()))
    assert not node.done(), "a stop before the run's end waits for the truth to leave"
    node.handle(net.msg("alive", net.keys.alive("truth"), b"delete"))
    node.advance()
    assert node.done()


def test_a_stop_before_the_end_while_the_truth_stays_is_refused_and_one_after_the_end_is_taken():
    from zentrack.node.run_control import STOP_CONFIRM_S

    net = Net(steps=60)
    net.start()
    run_steps(net, 0, 3)
    node = net.nodes[0]
    node.handle(net.msg("stop", net.keys.stop, Stop(60).encode()))  # forged: the truth is still publishing
    run_steps(net, 4, 4 + int(STOP_CONFIRM_S / TS) + 2)
    assert not node.done() and node.ctx.rejects.counts == {"conflict": 1}
    assert node.payload.state.step == 4 + int(STOP_CONFIRM_S / TS) + 3
    run_steps(net, node.payload.state.step, 59)
    net.at(deadline(59) + 0.01)
    node.handle(net.msg("stop", net.keys.stop, Stop(60).encode()))  # the truth's, after the last step
    assert node.done()



def test_a_long_period_is_not_silence_but_a_missing_measurement_past_it_is():
    """With T = 10 s a measurement message comes every 10 s: only time past the expected one counts."""
    import argparse

    from zentrack.node.process import NodeProcess

    net = Net()
    net.start()
    node = net.nodes[0]
    node.ctx.timing.ts = 10.0
    proc = NodeProcess(argparse.Namespace(reconnect_s=2.0, truth_timeout=30.0), node, net.keys, stop=None)
    proc.last_meas = T0 + 20.0
    assert proc.truth_silence(T0 + 25.0) is None  # 5 s into a 10 s period
    gone, why = proc.truth_silence(T0 + 33.0)
    assert gone == pytest.approx(3.0) and "no measurement" in why

