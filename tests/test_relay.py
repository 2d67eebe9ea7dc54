"""Relayed scans (``relay_scans``): each node relays its neighbours' scans, and the prior it shares is updated
with every scan within two hops; the estimate keeps the one-hop update.

The runtime (tracker schedules in lockstep, real wire messages, in-process bus) equals the batched simulator,
the relay message is validated like a scan, and a realtime node waits for its neighbours' relays only until
its step's deadline."""
from __future__ import annotations

import numpy as np
import pytest
from test_node_schedule import SETTLE, T0, TS, Net, deadline

from zentrack.bench.step import LockstepNetwork
from zentrack.fusion.graphs import ring_adjacency, within_hops
from zentrack.fusion.rules import make_rule
from zentrack.study.simulator import run_filter
from zentrack.transport import wire
from zentrack.transport.codec import Message
from zentrack.transport.messages import EstimateMessage
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan, decode_scan_key

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
    assert all(not node.ctx.rejects.counts for node in net.nodes)
    got = np.full((steps, nodes, 6), np.nan)
    for data in net.estimates:
        e = EstimateMessage.decode(data, wire.unpack(data)["sender"])
        got[e.k, e.sender] = e.x
    ref = run_filter(net.scn, "deskf", fusion=make_rule(rule, params)).mean[0]
    assert np.isfinite(got).all()
    assert np.max(np.abs(got - ref)) < 1e-9
    # and the relays made a difference: without them the estimates differ
    plain = run_filter(net.scn, "deskf", fusion=make_rule(rule, {k: v for k, v in params.items() if k != "relay_scans"})).mean[0]
    assert np.max(np.abs(plain[5:] - ref[5:])) > 1e-3


def relay(k: int, sender: int, scans, t_pub: float = 1.0) -> bytes:
    """A relay's bytes: ``scans`` as (origin, returns, pose, noise) tuples."""
    return Relay(k, 0.1 * k, sender, tuple(RelayedScan(*s) for s in scans), t_pub).encode_capped()[0]


def test_a_relay_message_is_validated_like_a_scan():
    pose, noise = np.arange(3.0), np.diag([1e-4, 2e-4])
    good = relay(3, 1, [(2, np.array([0.1, 0.2]), pose, noise), (5, np.array([[0.3, 0.4]]), pose, noise)])
    r = decode_scan_key(good, 1, 2, 0, 10)
    assert isinstance(r, Relay) and [s.origin for s in r.scans] == [2, 5]
    assert np.array_equal(r.scans[1].returns, [[0.3, 0.4]]) and np.array_equal(r.scans[0].noise_cov, noise)

    def reason(payload: bytes) -> str:
        with pytest.raises(wire.WireError) as err:
            decode_scan_key(payload, 1, 2, 0, 10)
        return err.value.reason

    twice = relay(3, 1, [(2, np.array([0.1, 0.2]), pose, noise)] * 2)
    assert reason(twice) == "schema"
    assert reason(relay(3, 1, [(2, np.array([np.nan, 0.2]), pose, noise)])) == "nonfinite"
    assert reason(relay(3, 1, [(2, np.array([0.1, 0.2]), pose, -noise)])) == "not_pd"
    many = relay(3, 1, [(j, np.array([0.1, 0.2]), pose, noise) for j in range(wire.MAX_RELAYED + 1)])
    assert reason(many) == "schema"
    assert reason(relay(3, 2, [])) == "sender_mismatch"


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
    assert all(node.payload.state.phase == "fusing" for node in net.nodes)  # every relay in: shared at once (held to the deadline)
    net.at(deadline(0))  # round 1 goes out at the deadline, and is fused once its settle time is over
    net.deliver()
    net.at(deadline(0) + SETTLE + 0.001)
    net.deliver()
    assert all(node.payload.state.phase == "await_meas" and node.payload.state.step == 1 for node in net.nodes)
    # step 1: node 1 publishes nothing; its neighbours 0 and 2 wait for its relay until the deadline
    step_until_relays(net, 1, silent={1})  # node 1's scan is missing too: 0 and 2 update at the scan deadline
    net.at(T0 + TS + 0.03)
    net.deliver()
    net.at(T0 + TS + 0.031)
    assert net.nodes[0].payload.state.phase == "await_relays" and net.nodes[2].payload.state.phase == "await_relays"
    assert net.nodes[3].payload.state.phase == "fusing"  # not a neighbour of node 1
    net.at(deadline(1) - 0.001)
    assert net.nodes[0].payload.state.phase == "await_relays" and net.nodes[0].timeout() <= 0.0011
    net.at(deadline(1))
    assert net.nodes[0].payload.state.phase == "fusing" and net.nodes[2].payload.state.phase == "fusing"
    # counted: each step's relays received, and the step that went without node 1's
    assert net.nodes[0].payload.counters.partial_relays == 1 and net.nodes[0].payload.counters.relays_rx == 3
    assert net.nodes[3].payload.counters.partial_relays == 0 and net.nodes[3].payload.counters.relays_rx == 4


def test_a_relay_in_a_run_whose_rule_relays_nothing_is_refused():
    net = Net(nodes=3)
    net.start()
    net.at(T0 + 0.001)
    net.nodes[0].handle(net.msg("scan", net.keys.scan(1), relay(0, 1, [], T0)))
    assert net.nodes[0].ctx.rejects.counts["unexpected"] == 1


@pytest.mark.parametrize("rule,params", RELAY_RULES)
def test_relayed_scans_keep_the_network_consistent_and_cut_its_error(rule, params):
    """The shared prior counts every scan within two hops once, on a prior that holds only earlier scans, so
    the estimates stay consistent (ANEES at or below its upper 95 % band) and are more accurate than
    without the relays (Experiment 2, 10 runs)."""
    from zentrack.config.scenario_config import builtin_spec
    from zentrack.study.pcrlb import scenario_bound
    from zentrack.study.simulator import evaluate
    from zentrack.truth.simulation.simulate import simulate

    scn = simulate(builtin_spec("exp2", steps=400), runs=10, seed=5)
    bound = scenario_bound(scn)
    relayed = evaluate(scn, run_filter(scn, "deskf", fusion=make_rule(rule, params)), bound)
    plain = evaluate(scn, run_filter(scn, "deskf", fusion=make_rule(rule, {k: v for k, v in params.items() if k != "relay_scans"})), bound)
    assert relayed["diverged_runs"] == 0 and relayed["anees"] <= relayed["anees_band"][1]
    assert np.median(relayed["bound_ratio"]["p"]) < np.median(plain["bound_ratio"]["p"])


def lockstep_estimates(net: LockstepNetwork) -> dict[tuple[int, int], np.ndarray]:
    out = {}
    for data in net.estimates:
        e = EstimateMessage.decode(data, wire.unpack(data)["sender"])
        out[(e.k, e.sender)] = e.x
    return out


def test_forged_scans_and_relays_are_refused_and_the_node_goes_on_as_if_they_never_came():
    """Each forgery names the check it fails, none reaches the filter (a point-target filter takes one return
    per scan; a node relays only its own neighbours' scans; a forwarded scan is its sender's own), and the
    run's estimates are bit for bit those of the run without them."""
    steps, rule = 4, {"relay_scans": True}
    clean = LockstepNetwork(6, steps, "eskf", fusion="diff-ici", fusion_params=rule)
    net = LockstepNetwork(6, steps, "eskf", fusion="diff-ici", fusion_params=rule)
    pose, noise, two = np.zeros(3), np.diag([1e-4, 1e-4]), np.array([[0.1, 0.2], [0.3, 0.4]])
    forged = [  # all on node 1's scan key, node 0's neighbour on the ring of 6 (node 1's neighbours: 0 and 2)
        (ForwardedScan(0, 0.0, 1, 500, np.array([0.1, 0.2]), pose, noise, T0).encode(), "sender_mismatch"),
        (ForwardedScan(0, 0.0, 1, 2, np.array([0.1, 0.2]), pose, noise, T0).encode(), "sender_mismatch"),
        (ForwardedScan(0, 0.0, 1, 1, two, pose, noise, T0).encode(), "shape"),
        (relay(0, 1, [(3, np.array([0.1, 0.2]), pose, noise)], T0), "sender_mismatch"),
        (relay(0, 1, [(2, two, pose, noise)], T0), "shape"),
        (wire.encode(kind="relay", k=0, t=0.0, sender=1, scans=[{"origin": 2, "present": False}], t_pub=T0), "schema"),
    ]
    node = net.nodes[0]
    for payload, reason in forged:
        before = node.ctx.rejects.counts[reason]
        node.handle(Message("scan", net.keys.scan(1), payload, T0))
        assert node.ctx.rejects.counts[reason] == before + 1, reason
    for k in range(steps):
        clean.step(k)
        net.step(k)
    assert all(n.payload.state.step == steps for n in net.nodes) and not any(n.ctx.rejects.counts for n in net.nodes[1:])
    got, ref = lockstep_estimates(net), lockstep_estimates(clean)
    assert len(got) == 6 * steps and all(np.array_equal(got[key], ref[key]) for key in ref)
    # a copy of a relay that was already used is late, not a second relay
    rx, last = node.payload.counters.relays_rx, steps - 1
    again = relay(last, 1, [(2, np.array([0.1, 0.2]), pose, noise)], T0)
    node.handle(Message("scan", net.keys.scan(1), again, T0))
    assert node.payload.counters.relays_rx == rx and node.payload.counters.late == 1


def test_two_relays_that_disagree_about_a_scan_are_both_left_out():
    """On a ring of 4 node 0 hears node 2's scan from both its neighbours: when they differ, it uses neither."""
    net = LockstepNetwork(4, 2, "eskf", fusion="diff-ici", fusion_params={"relay_scans": True})
    pose, noise = np.array([1.0, 2.0, 3.0]), np.diag([1e-4, 1e-4])
    lie = relay(0, 3, [(2, np.array([0.5, 0.1]), pose, noise)], T0)
    net.nodes[0].handle(Message("scan", net.keys.scan(3), lie, T0))  # first: node 3's real relay is a duplicate
    net.step(0)
    net.step(1)
    counts = net.nodes[0].ctx.rejects.counts
    # node 3's real relay came after the relays were complete (the lie stood in for it): late, unused
    assert counts["conflict"] == 1 and net.nodes[0].payload.counters.late == 1 and net.nodes[0].payload.state.step == 2
    assert np.isfinite(np.stack(list(lockstep_estimates(net).values()))).all()


def test_a_hub_relays_every_neighbours_scan_beyond_64():
    """A star of 70: the hub's relay carries 69 scans (one message), and every leaf uses it."""
    nodes = 70
    star = np.zeros((nodes, nodes), dtype=int)
    star[0, 1:] = star[1:, 0] = 1
    net = LockstepNetwork(nodes, 2, "eskf", fusion="diff-ici", fusion_params={"relay_scans": True}, adjacency=star)
    for k in range(2):
        net.step(k)
    assert all(n.payload.state.step == 2 and not n.ctx.rejects.counts for n in net.nodes)
    assert all(n.payload.counters.relays_rx == 2 and n.payload.counters.relay_left_out == 0 for n in net.nodes[1:])


def test_a_relay_too_big_for_one_message_leaves_scans_out_and_still_decodes():
    rng = np.random.default_rng(0)
    pose, noise = np.zeros(3), np.eye(3)
    scans = tuple(RelayedScan(j, rng.normal(size=(wire.MAX_RETURNS, 3)), pose, noise) for j in range(8))  # ~50 KB each
    payload, left_out = Relay(0, 0.0, 1, scans, T0).encode_capped()
    assert len(payload) <= wire.MAX_MESSAGE_BYTES and 0 < left_out < len(scans)
    kept = Relay.decode(payload, 1, 3, 0, 1).scans
    assert [s.origin for s in kept] == list(range(len(scans) - left_out))
    assert np.array_equal(kept[0].returns, scans[0].returns)
