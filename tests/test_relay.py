"""Relayed scans (``relay_scans``): each node relays its neighbours' scans, and the prior it shares is updated
with every scan within two hops; the estimate keeps the one-hop update.

The runtime (tracker schedules in lockstep, real wire messages, in-process bus) equals the batched simulator,
the relay message is validated like a scan, and a realtime node waits for its neighbours' relays only until
its step's deadline."""
from __future__ import annotations

import numpy as np
import pytest
from test_node_schedule import T0, TS, Net, deadline

from zentrack.bench.step import LockstepNetwork
from zentrack.fusion.graphs import ring_adjacency, within_hops
from zentrack.fusion.rules import make_rule
from zentrack.fusion.simulator import run_filter
from zentrack.transport import wire

RELAY_RULES = [("diff-ici", {"relay_scans": True}), ("ci", {"share_scans": True, "relay_scans": True})]


def test_two_hop_reach_on_a_ring():
    reach = within_hops(ring_adjacency(6), 2)
    assert sorted(np.flatnonzero(reach[0]).tolist()) == [1, 2, 4, 5] and not reach.diagonal().any()
    assert np.array_equal(within_hops(ring_adjacency(6), 1), ring_adjacency(6) != 0)


def test_a_rule_relays_only_what_it_shares():
    with pytest.raises(ValueError, match="set share_scans too"):
        make_rule("ci", {"relay_scans": True})
    assert make_rule("diff-ici", {"relay_scans": True}).relays_scans
    assert not make_rule("diff-ici", {}).relays_scans


@pytest.mark.parametrize("nodes", [4, 6])  # on a ring of 4 both neighbours relay the opposite node's scan
@pytest.mark.parametrize("rule,params", RELAY_RULES)
def test_lockstep_trackers_with_relays_equal_the_batched_simulator(rule, params, nodes):
    steps = 40
    net = LockstepNetwork(nodes, steps, "eskf", fusion=rule, fusion_params=params)
    for k in range(steps):
        net.step(k)
    assert all(not node.rejects.counts for node in net.nodes)
    got = np.full((steps, nodes, 6), np.nan)
    for data in net.estimates:
        e = wire.decode_est(data, wire.unpack(data)["sender"])
        got[e["k"], e["sender"]] = e["x"]
    ref = run_filter(net.scn, "deskf", fusion=make_rule(rule, params)).mean[0]
    assert np.isfinite(got).all()
    assert np.max(np.abs(got - ref)) < 1e-9
    # and the relays made a difference: without them the estimates differ
    plain = run_filter(net.scn, "deskf", fusion=make_rule(rule, {k: v for k, v in params.items() if k != "relay_scans"})).mean[0]
    assert np.max(np.abs(plain[5:] - ref[5:])) > 1e-3


def test_a_relay_message_is_validated_like_a_scan():
    pose, noise = np.arange(3.0), np.diag([1e-4, 2e-4])
    good = wire.encode_relay(3, 0.3, 1, [(2, np.array([0.1, 0.2]), pose, noise), (5, np.array([[0.3, 0.4]]), pose, noise)], 1.0)
    r = wire.decode_scan(good, 1, 2, 0, 10)
    assert r["kind"] == "relay" and [s["origin"] for s in r["scans"]] == [2, 5]
    assert np.array_equal(r["scans"][1]["returns"], [[0.3, 0.4]]) and np.array_equal(r["scans"][0]["noise_cov"], noise)

    def reason(payload: bytes) -> str:
        with pytest.raises(wire.WireError) as err:
            wire.decode_scan(payload, 1, 2, 0, 10)
        return err.value.reason

    twice = wire.encode_relay(3, 0.3, 1, [(2, np.array([0.1, 0.2]), pose, noise)] * 2, 1.0)
    assert reason(twice) == "schema"
    assert reason(wire.encode_relay(3, 0.3, 1, [(2, np.array([np.nan, 0.2]), pose, noise)], 1.0)) == "nonfinite"
    assert reason(wire.encode_relay(3, 0.3, 1, [(2, np.array([0.1, 0.2]), pose, -noise)], 1.0)) == "not_pd"
    many = wire.encode_relay(3, 0.3, 1, [(j, np.array([0.1, 0.2]), pose, noise) for j in range(wire.MAX_RELAYED + 1)], 1.0)
    assert reason(many) == "schema"
    assert reason(wire.encode_relay(3, 0.3, 2, [], 1.0)) == "sender_mismatch"


def relay_net() -> Net:
    return Net(nodes=6, fusion="diff-ici", fusion_params={"relay_scans": True}, fusion_after_deadline=None)


def step_until_relays(net: Net, k: int, silent: set[int]) -> None:
    """Step k up to the point where every node has published its estimate and relay (nodes in ``silent``
    publish nothing: their messages are dropped)."""
    net.at(T0 + k * TS + 0.001)
    net.measure(k)
    for _ in range(3):
        net.at(T0 + k * TS + 0.002)
        net.sent = [(i, ch, d) for i, ch, d in net.sent if i not in silent]
        net.deliver()


def test_a_realtime_node_waits_for_its_neighbours_relays_until_the_deadline():
    net = relay_net()
    net.start()
    step_until_relays(net, 0, silent=set())
    assert all(node.phase == "fusing" for node in net.nodes)  # every relay in: shared at once (held to the deadline)
    net.at(deadline(0))  # round 1 goes out at the deadline, and is fused
    net.deliver()
    net.at(deadline(0) + 0.001)
    net.deliver()
    assert all(node.phase == "await_meas" and node.step == 1 for node in net.nodes)
    # step 1: node 1 publishes nothing; its neighbours 0 and 2 wait for its relay until the deadline
    step_until_relays(net, 1, silent={1})  # node 1's scan is missing too: 0 and 2 update at the scan deadline
    net.at(T0 + TS + 0.03)
    net.deliver()
    net.at(T0 + TS + 0.031)
    assert net.nodes[0].phase == "await_relays" and net.nodes[2].phase == "await_relays"
    assert net.nodes[3].phase == "fusing"  # not a neighbour of node 1
    net.at(deadline(1) - 0.001)
    assert net.nodes[0].phase == "await_relays" and net.nodes[0].timeout() <= 0.0011
    net.at(deadline(1))
    assert net.nodes[0].phase == "fusing" and net.nodes[2].phase == "fusing"
    # counted: each step's relays received, and the step that went without node 1's
    assert net.nodes[0].counters["partial_relays"] == 1 and net.nodes[0].counters["relays_rx"] == 3
    assert net.nodes[3].counters["partial_relays"] == 0 and net.nodes[3].counters["relays_rx"] == 4


def test_a_relay_in_a_run_whose_rule_relays_nothing_is_refused():
    net = Net(nodes=3)
    net.start()
    net.at(T0 + 0.001)
    relay = wire.encode_relay(0, 0.0, 1, [], T0)
    net.nodes[0].handle(net.msg("scan", net.keys.scan(1), relay))
    assert net.nodes[0].rejects.counts["unexpected"] == 1


@pytest.mark.parametrize("rule,params", RELAY_RULES)
def test_relayed_scans_keep_the_network_consistent_and_cut_its_error(rule, params):
    """The shared prior counts every scan within two hops once, on a prior that holds only earlier scans, so
    the estimates stay consistent (ANEES at or below its upper 95 % band) and are more accurate than
    without the relays (Experiment 2, 10 runs)."""
    from zentrack.fusion.pcrlb import scenario_bound
    from zentrack.fusion.scenario import builtin_spec, simulate
    from zentrack.fusion.simulator import evaluate

    scn = simulate(builtin_spec("exp2", steps=400), runs=10, seed=5)
    bound = scenario_bound(scn)
    relayed = evaluate(scn, run_filter(scn, "deskf", fusion=make_rule(rule, params)), bound)
    plain = evaluate(scn, run_filter(scn, "deskf", fusion=make_rule(rule, {k: v for k, v in params.items() if k != "relay_scans"})), bound)
    assert relayed["diverged_runs"] == 0 and relayed["anees"] <= relayed["anees_band"][1]
    assert np.median(relayed["bound_ratio"]["p"]) < np.median(plain["bound_ratio"]["p"])
