"""The tracker's schedule against faults and forgeries: forged copies of a prior (early, in conflict, a trailing
real copy, exact replays), a start that contradicts the run, and a node the gate shows to be wrong (outvoted,
or the gate lifted between two that refuse each other).

Stepped by hand on the in-memory network of :mod:`schedule_net` (no Zenoh, no processes)."""
from __future__ import annotations

import numpy as np
from schedule_net import FRAC, SETTLE, T0, TS, Net, deadline, run_steps

from zentrack.transport.messages import RoundMessage, Start
from zentrack.transport.wire import Message


def _forged(payload: bytes, shift_m: float, salt: float = 0.0) -> bytes:
    """Node 0's prior with its mean moved ``shift_m`` metres along x (and ``salt`` added to t_pub)."""
    msg = RoundMessage.decode(payload, 0, {"state": 12})
    blocks = {}
    for name, (mat, vec) in msg.blocks.items():
        d = np.zeros(vec.size)
        d[0] = shift_m
        blocks[name] = (mat, vec + mat @ d)
    return RoundMessage(msg.k, msg.t, 0, msg.round, blocks, msg.t_pub + salt).encode()


def _step_with(net: Net, k: int, before_real) -> None:
    """Step k on every node; ``before_real(payload)`` gives messages node 1 gets before node 0's real prior."""
    net.at(T0 + k * TS + 0.001)
    net.measure(k)
    net.at(T0 + k * TS + 0.002)
    real = next(data for i, ch, data in net.sent if i == 0 and ch == "prior")
    for fake in before_real(real):
        net.nodes[1].handle(net.msg("prior", net.keys.prior(0), fake))
    net.at(T0 + k * TS + 0.003)  # a forged copy that fails the gate must not complete the round
    net.deliver()
    net.at(deadline(k))
    net.deliver()


def test_a_forged_copy_sent_before_its_sender_could_have_made_it_is_early_and_the_real_prior_fused():
    """The forger's move: re-issue node 0's prior for step k + 1 as soon as it saw the one for step k (a
    period early), biased by a plausible 5 cm. Node 1 refuses it as early and fuses the real one."""
    probe = Net()  # the real prior node 0 sends in step 3 (for step 4), which the forged copy imitates
    probe.start()
    run_steps(probe, 0, 2)
    captured: list[bytes] = []
    _step_with(probe, 3, lambda real: captured.append(real) or [])
    real = captured[0]
    early = Message("prior", probe.keys.prior(0), _forged(real, 0.05, salt=1.0), T0 + 2 * TS + 0.002)
    clean_net, attacked_net = Net(), Net()
    for net in (clean_net, attacked_net):
        net.start()
        run_steps(net, 0, 2)
    attacked_net.nodes[1].handle(early)  # ... and hands it over while step 3 has not been sampled yet
    _step_with(clean_net, 3, lambda real: [])
    _step_with(attacked_net, 3, lambda real: [])
    node = attacked_net.nodes[1]
    assert node.ctx.rejects.counts == {"early": 1} and node.payload.counters.conflicts == 0
    assert node.payload.state.last_fused == 3 and node.payload.counters.partial_rounds == 0
    np.testing.assert_array_equal(node.payload.tracker.prior.mean, clean_net.nodes[1].payload.tracker.prior.mean)


def test_a_forged_copy_beside_the_real_prior_is_a_conflict_whether_or_not_it_passes_the_gate():
    for shift in (0.01, 1000.0):  # a plausible lie, and a decoy the gate would refuse
        net = Net()
        net.start()
        run_steps(net, 0, 2)
        _step_with(net, 3, lambda real, shift=shift: [_forged(real, shift)])
        node = net.nodes[1]
        assert node.payload.counters.conflicts == 2 and node.payload.counters.gated == 0
        assert node.payload.state.last_fused == 2  # itself and node 2: neither copy of node 0's prior is fused


def test_a_round_waits_the_settle_time_so_a_trailing_real_copy_makes_a_conflict():
    """Realtime: a forged copy in, every neighbour heard, yet the round does not fuse before SETTLE;
    the real copy that trails the forged one by less than that makes a conflict instead of losing the race."""
    net = Net()
    net.start()
    run_steps(net, 0, 2)
    k = 3
    net.at(T0 + k * TS + 0.001)
    net.measure(k)
    node = net.nodes[1]
    net.at(T0 + k * TS + 0.002)
    real = next(data for i, ch, data in net.sent if i == 0 and ch == "prior")
    net.sent[:] = [m for m in net.sent if not (m[0] == 0 and m[1] == "prior")]  # node 0's real prior: held back
    node.handle(net.msg("prior", net.keys.prior(0), _forged(real, 0.01)))
    net.deliver()  # node 2's prior and the rest: every neighbour of node 1 is now heard
    assert node.payload.state.fuse_step == k + 1  # not fused yet: inside the settle time
    assert node.timeout() <= SETTLE + 1e-9
    net.at(T0 + k * TS + 0.002 + 0.5 * SETTLE)
    node.handle(net.msg("prior", net.keys.prior(0), real))  # the real copy, a few ms behind
    node.advance()
    assert node.payload.state.fuse_step == k + 1
    net.at(T0 + k * TS + 0.003 + SETTLE)
    node.advance()
    assert node.payload.state.fuse_step is None and node.payload.counters.conflicts == 2 and node.payload.state.last_fused == 2


def test_an_exact_replay_is_a_duplicate_and_copies_are_bounded():
    from zentrack.node.diffusion.admission import MAX_COPIES

    net = Net()
    net.start()
    run_steps(net, 0, 2)
    fakes = lambda real: [real] + [_forged(real, 1000.0, salt=s) for s in range(MAX_COPIES)]  # noqa: E731
    _step_with(net, 3, fakes)
    node = net.nodes[1]
    # the replay of the real prior was kept (it came first), the real one itself is then the duplicate; the
    # first forged copy makes a conflict, the second is refused as one at once: nothing is fused from node 0
    assert node.ctx.rejects.counts == {"conflict": 1, "duplicate": 1}
    assert node.payload.counters.conflicts == MAX_COPIES and node.payload.state.last_fused == 2


def test_a_start_that_contradicts_the_run_under_way_is_refused_and_counted():
    net = Net()
    net.start()
    run_steps(net, 0, 3)
    node = net.nodes[0]
    x0 = net.scn.x0_estimate[0]
    repeat = Start(T0, TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0).encode()
    node.handle(net.msg("start", net.keys.start, repeat))  # truth re-sends the start when a node joins
    assert node.ctx.rejects.counts == {}
    forged = [Start(T0 - 120.0, TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0).encode(),  # earlier t0
              Start(T0, 2 * TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0).encode(),
              Start(T0, TS, net.scn.steps, "realtime", tuple([0, 1, 2, 9]), FRAC, x0).encode(),
              Start(T0, TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0 + 1000.0).encode()]
    for payload in forged:
        node.handle(net.msg("start", net.keys.start, payload))
    assert node.ctx.rejects.counts == {"conflict": 4}
    assert node.t0 == T0 and node.ts == TS and node.ctx.participants == {0, 1, 2}
    run_steps(net, 4, 5)  # and it goes on stepping as before
    assert node.payload.state.step == 6 and node.payload.counters.misses == 0



def _corrupt(node, metres: float) -> None:
    """Move a node's prior ``metres`` off along x with its covariance unchanged: an estimate gone wrong."""
    node.payload.tracker.prior.mean[0] += metres


def test_a_node_the_gate_shows_to_be_the_odd_one_out_is_outvoted_by_agreeing_neighbours():
    clean, net = Net(), Net()
    for n in (clean, net):
        n.start()
        run_steps(n, 0, 3)
    _corrupt(net.nodes[1], 2000.0)
    run_steps(clean, 4, 4)
    run_steps(net, 4, 4)
    node = net.nodes[1]
    # both neighbours refused by node 1's gate, they agree with each other: node 1 fuses theirs, not its own
    assert node.payload.counters.gated == 2 and node.payload.counters.outvoted == 1 and node.payload.state.last_fused == 2
    assert node.payload.counters.partial_rounds == 1  # nobody passed the gate, so it waited for the deadline
    # the neighbours refuse node 1's message but are one against one: they are not outvoted
    assert [net.nodes[j].payload.counters.outvoted for j in (0, 2)] == [0, 0]
    assert all(net.nodes[j].payload.counters.gated == 1 for j in (0, 2))
    err = abs(node.payload.tracker.prior.mean[0] - clean.nodes[1].payload.tracker.prior.mean[0])
    assert err < 100.0, err  # back with the network in one step (it was 2 km off)
    run_steps(net, 5, 8)
    assert node.payload.counters.outvoted == 1 and node.payload.counters.gated == 2  # and it stays in


def test_a_single_refused_neighbour_lifts_the_gate_after_a_streak_and_the_two_estimates_meet():
    """Two nodes that refuse each other cannot tell who is wrong: after OUTVOTED_STREAK rounds of refusals
    each fuses the other's message with its own (neither is outvoted) and the gap closes."""
    from zentrack.node.diffusion.fusion_policy import OUTVOTED_STREAK

    net = Net(nodes=2)
    net.start()
    run_steps(net, 0, 3)
    _corrupt(net.nodes[1], 2000.0)
    gap = lambda: abs(net.nodes[1].payload.tracker.prior.mean[0] - net.nodes[0].payload.tracker.prior.mean[0])  # noqa: E731
    run_steps(net, 4, 4 + OUTVOTED_STREAK - 2)
    assert [n.payload.counters.gated for n in net.nodes] == [OUTVOTED_STREAK - 1] * 2
    assert [n.payload.counters.gate_lifted for n in net.nodes] == [0, 0] and gap() > 1000.0
    run_steps(net, 4 + OUTVOTED_STREAK - 1, 4 + OUTVOTED_STREAK - 1)
    assert [n.payload.counters.gate_lifted for n in net.nodes] == [1, 1]
    assert [n.payload.counters.outvoted for n in net.nodes] == [0, 0]
    assert gap() < 200.0, gap()
