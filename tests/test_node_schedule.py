"""The tracker's schedule as a pure state machine: phase by phase, with an injected clock and an in-memory bus.

No Zenoh and no processes: messages are encoded with the real wire codec and delivered by hand, so every
transition (start, measurement, coasting, deadline fusion, warm-up, recovery when every node warms at once)
is checked deterministically."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.node.fusion_policy import CONFLICT_SETTLE_S as SETTLE
from zentrack.node.schedule import COAST_MARGIN_S, FUSION_MARGIN_S, NodeSchedule
from zentrack.node.tracker import MAX_COAST_STEPS, Tracker
from zentrack.transport import wire
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Start, Stop
from zentrack.transport.wire import Message
from zentrack.truth.simulation.simulate import simulate

TS, FRAC, T0 = 0.1, 0.5, 1000.0


class Net:
    """Three realtime nodes on a ring (everyone neighbours everyone), a shared clock and a hand-driven bus.

    ``fusion_after_deadline``: False (the default here) pins the schedule in which round 1 goes out with the
    estimate, which most phase tests below step through; None lets the node decide from the timing, as a
    tracker process does (the tests of fusion after the deadline)."""

    def __init__(self, nodes: int = 3, steps: int = 200, cold_after: int = 20,
                 fusion_after_deadline: bool | None = False, **more) -> None:
        self.scn = simulate(builtin_spec("exp2", nodes=nodes, steps=steps), runs=1, seed=3)
        self.setup = RunSetup.from_data(self.scn, "teskf", 1e-6, None, "realtime", FRAC, "test", **more)
        self.keys = Keys("unit")
        self.now = T0 - 1.0
        self.sent: list[tuple[int, str, bytes]] = []
        self.nodes = [self._make(i, cold_after, fusion_after_deadline) for i in range(nodes)]
        self.frozen: set[int] = set()  # SIGSTOPped nodes: they neither receive nor act

    def _make(self, i: int, cold_after: int, fusion_after_deadline: bool | None = False) -> NodeSchedule:
        cfg = self.setup.node_config(i)
        return NodeSchedule(self.keys, cfg, Tracker(cfg), clock=lambda: self.now,
                            send=lambda ch, data, i=i: self.sent.append((i, ch, data)), cold_after=cold_after,
                            incarnation=100 + i, fusion_after_deadline=fusion_after_deadline)

    def msg(self, tag: str, key: str, payload: bytes) -> Message:
        return Message(tag, key, payload, self.now)

    def start(self, who=None) -> None:
        start = Start(T0, TS, self.scn.steps, "realtime", tuple(list(range(len(self.nodes)))), FRAC,
                                  self.scn.x0_estimate[0]).encode()
        for i in who if who is not None else range(len(self.nodes)):
            node = self.nodes[i]
            for j in range(len(self.nodes)):
                node.handle(self.msg("alive", self.keys.alive(j), b"put"))
            node.handle(self.msg("alive", self.keys.alive("truth"), b"put"))
            node.handle(self.msg("start", self.keys.start, start))

    def measure(self, k: int, who=None) -> None:
        for i in who if who is not None else range(len(self.nodes)):
            if i in self.frozen:
                continue
            z = self.scn.measurements[0, k, i]
            self.nodes[i].handle(self.msg("meas", self.keys.meas(i), Measurement(k, k * TS, i, z, None, self.now).encode()))

    def deliver(self) -> list[tuple[int, str, dict]]:
        """Hand every prior sent so far to the sender's neighbours; return what was sent (decoded)."""
        out, sent, self.sent = [], self.sent, []
        for i, ch, data in sent:
            out.append((i, ch, wire.unpack(data)))
            if ch in ("prior", "scan"):
                key = self.keys.prior(i) if ch == "prior" else self.keys.scan(i)
                for j, node in enumerate(self.nodes):
                    if i in node.tracker.neighbours and j not in self.frozen:
                        node.handle(self.msg(ch, key, data))
        return out

    def at(self, t: float) -> None:
        self.now = t
        for j, node in enumerate(self.nodes):
            if j not in self.frozen:
                node.advance()


def deadline(k: int) -> float:
    return T0 + (k + FRAC) * TS


def run_steps(net: Net, first: int, last: int, measured=lambda k, i: True) -> list[tuple[int, str, dict]]:
    """Steps first..last at realtime: measurements at t_k (where ``measured``), priors delivered, deadlines."""
    log = []
    for k in range(first, last + 1):
        net.at(T0 + k * TS + 0.001)
        net.measure(k, [i for i in range(len(net.nodes)) if measured(k, i)])
        net.at(T0 + k * TS + 0.002)
        log += net.deliver()
        net.at(deadline(k) - COAST_MARGIN_S)  # coasting nodes act here
        log += net.deliver()
        net.at(deadline(k))  # fusion after the deadline shares round 1 here
        log += net.deliver()
        net.at(deadline(k) + 0.001)
        log += net.deliver()
    return log


def ests(log, k=None):
    return [(i, m) for i, ch, m in log if ch == "est" and (k is None or m["k"] == k)]


def test_idle_until_start_then_cold_start_at_step_zero():
    net = Net()
    node = net.nodes[0]
    assert node.phase == "idle" and node.timeout() == 0.2
    net.at(T0 + 0.001)
    net.measure(0, [0])  # a measurement before the start is kept, not rejected ...
    assert node.phase == "idle" and len(node.early) == 1 and not node.rejects.counts
    net.start([0])  # ... and used once the start comes: step 0 is updated at once
    assert node.rejects.counts == {} and node.early == []
    net.at(T0 + 0.002)
    assert node.phase == "fusing" and node.fuse_step == 1 and node.counters.meas_rx == 1
    sent = net.deliver()
    assert [(i, ch) for i, ch, _ in sent] == [(0, "est"), (0, "prior")] and sent[0][2]["coasted"] is False


def test_messages_before_the_start_are_bounded():
    from zentrack.node.schedule import EARLY_KEPT

    net = Net()
    node = net.nodes[0]
    for _ in range(EARLY_KEPT + 5):
        net.measure(0, [0])
    assert len(node.early) == EARLY_KEPT and node.rejects.counts["unexpected"] == 5


def test_measurement_update_publishes_estimate_and_prior_then_fuses_every_neighbour():
    net = Net()
    net.start()
    net.at(T0 + 0.001)
    net.measure(0)
    net.at(T0 + 0.002)
    node = net.nodes[0]
    assert node.phase == "fusing" and node.fuse_step == 1
    sent = net.deliver()
    assert sorted((i, ch) for i, ch, _ in sent) == [(i, ch) for i in range(3) for ch in ("est", "prior")]
    assert all(m["warm"] is False for _, ch, m in sent if ch == "prior")
    net.at(T0 + 0.003)  # every live neighbour's pair is in, but the round waits its settle time
    assert node.phase == "fusing"
    net.at(T0 + 0.002 + SETTLE + 1e-4)  # then it fuses, long before the deadline
    assert node.phase == "await_meas" and node.step == 1 and node.last_fused == 3
    assert node.counters.misses == 0 and node.counters.steps == 1


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
    assert net.nodes[0].last_fused == 2 and net.nodes[0].counters.misses == 0


def test_late_prior_is_counted_not_fused():
    net = Net()
    net.start()
    run_steps(net, 0, 0)
    node = net.nodes[0]
    assert node.fused_upto == 1
    late = RoundMessage(1, 0.1, 1, 1, {"state": (np.eye(12), np.zeros(12))}, net.now).encode()
    node.handle(net.msg("prior", net.keys.prior(1), late))
    assert node.counters.late == 1


@pytest.mark.parametrize("after_deadline", [False, None], ids=["round-1-at-once", "fusion-after-deadline"])
def test_every_node_warming_at_once_recovers_at_the_first_deadline(after_deadline):
    """A truth stall: nobody gets a measurement for more than MAX_COAST_STEPS steps, so every node is stale
    when measurements return. Under the old rule (a warming node publishes nothing) nobody ever fused again."""
    net = Net(fusion_after_deadline=after_deadline)
    net.start()
    run_steps(net, 0, 9)
    stall = range(10, 10 + MAX_COAST_STEPS + 3)
    log = run_steps(net, 10, stall[-1], measured=lambda k, i: k not in stall)
    assert all(node.stale for node in net.nodes)
    assert all(m["coasted"] for _, m in ests(log))
    back = stall[-1] + 1
    log = run_steps(net, back, back + 5)
    warm_priors = [(i, m["k"]) for i, ch, m in log if ch == "prior" and m["warm"]]
    assert {i for i, _ in warm_priors} == {0, 1, 2}, "a warming node shares its own prediction, flagged warm"
    for node in net.nodes:
        assert node.counters.warm_self == 1 and node.phase in ("await_meas", "fusing")
        assert not node.stale
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
    assert net.nodes[2].phase == "warming"
    log = run_steps(net, 30, 34)
    node = net.nodes[2]
    assert node.counters.warm_starts == 1 and node.counters.warm_self == 0
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
    assert node.counters.misses >= len(frozen) - 1
    assert node.counters.warm_starts == 1
    assert sorted(i for i, _ in ests(log, 24)) == [0, 1, 2]


def test_node_without_state_and_without_neighbour_states_cold_starts_after_the_limit():
    net = Net(cold_after=4)
    net.start()
    net.nodes = net.nodes[:1]  # node 0 alone; its neighbours are configured but silent
    node = net.nodes[0]
    node.tracker.prior, node.tracker.prior_step = None, None
    net.at(T0 + 3 * TS)
    node._start_warming(net.now)
    log = run_steps(net, 3, 12)
    assert node.counters.cold_restarts == 1 and node.phase in ("await_meas", "fusing")
    assert ests(log), "it estimates again after the cold start"


def test_fresh_node_leaves_warm_pairs_out_of_its_fusion():
    net = Net()
    tracker = net.nodes[0].tracker
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
    assert not node.done() and node.rejects.counts["kind"] == 1
    node.handle(net.msg("stop", net.keys.stop, Stop(5).encode()))
    assert not node.done(), "a stop before the run's end waits for the truth to leave"
    node.handle(net.msg("alive", net.keys.alive("truth"), b"delete"))
    node.advance()
    assert node.done()


def test_a_stop_before_the_end_while_the_truth_stays_is_refused_and_one_after_the_end_is_taken():
    from zentrack.node.schedule import STOP_CONFIRM_S

    net = Net(steps=60)
    net.start()
    run_steps(net, 0, 3)
    node = net.nodes[0]
    node.handle(net.msg("stop", net.keys.stop, Stop(60).encode()))  # forged: the truth is still publishing
    run_steps(net, 4, 4 + int(STOP_CONFIRM_S / TS) + 2)
    assert not node.done() and node.rejects.counts == {"conflict": 1}
    assert node.step == 4 + int(STOP_CONFIRM_S / TS) + 3
    run_steps(net, node.step, 59)
    net.at(deadline(59) + 0.01)
    node.handle(net.msg("stop", net.keys.stop, Stop(60).encode()))  # the truth's, after the last step
    assert node.done()


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
    assert all(node.phase == "await_scans" for node in net.nodes)
    sent = net.deliver()
    assert sorted((i, ch) for i, ch, _ in sent) == [(i, "scan") for i in range(3)]
    net.at(T0 + 0.003)  # every neighbour's scan is in: update with three scans, publish, fuse
    assert all(node.phase == "fusing" for node in net.nodes)
    net.deliver()
    net.at(T0 + 0.004 + SETTLE)
    assert all(node.phase == "await_meas" and node.step == 1 for node in net.nodes)
    # step 1: node 2 is silent; nodes 0 and 1 wait for its scan until the scan deadline, then go on
    net.at(T0 + TS + 0.001)
    net.measure(1, [0, 1])
    net.at(T0 + TS + 0.002)
    net.deliver()
    net.at(T0 + TS + 0.003)
    assert net.nodes[0].phase == "await_scans"
    scan_deadline = T0 + TS + FRAC * TS / 2
    net.at(scan_deadline - 0.001)
    assert net.nodes[0].phase == "await_scans" and 0 < net.nodes[0].timeout() <= 0.001 + 1e-9
    net.at(scan_deadline + 0.0001)
    assert net.nodes[0].phase == "fusing" and net.nodes[1].phase == "fusing"


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
    assert node.phase == "fusing" and node.fuse_round == 1
    assert node.round_deadline == pytest.approx(round_deadline(T0 + 0.010, window_end, 4, 4))
    assert node.round_deadline == pytest.approx(window_end - 3 * FRAC * TS / 16)  # the reserve rules here
    net.deliver()
    net.at(T0 + 0.012)  # round 1 complete at once, but it waits its settle time
    assert node.fuse_round == 1
    net.at(T0 + 0.010 + SETTLE)  # then round 2 starts with a share of the rest over 3 rounds
    assert node.fuse_round == 2 and node.counters.partial_rounds == 0
    assert node.round_deadline == pytest.approx(round_deadline(T0 + 0.010 + SETTLE, window_end, 3, 4))
    net.now = window_end - 0.001  # a round that starts late gets an equal share of what is left instead
    node._start_round()
    assert node.round_deadline == pytest.approx(window_end - 0.001 + 0.001 / 3)
    net.now = T0 + 0.010 + SETTLE
    node._start_round()
    net.frozen.add(2)  # node 2 stalls after sending round 2: rounds 3-4 of nodes 0 and 1 wait to their deadlines
    net.deliver()
    for _ in range(4):
        if node.phase == "fusing":
            net.at(max(node.round_deadline, net.now + 1e-4))
            net.deliver()
    assert node.phase == "await_meas" and node.step == 1
    assert node.counters.partial_rounds == 2 and net.nodes[1].counters.partial_rounds == 2
    assert node.clock() <= window_end + 1e-9 and node.counters.misses == 0
    assert len(node.last_round_ms) == 4 and node.last_round_ms[0] == pytest.approx(SETTLE * 1e3)
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
    assert node.fusion_after_deadline()
    net.start()
    net.at(T0 + 0.001)
    net.measure(0, [0])  # node 0 measured; nodes 1 and 2 later
    net.at(T0 + 0.002)
    sent = net.deliver()
    assert [(i, ch) for i, ch, _ in sent] == [(0, "est")]  # no round-1 message yet
    assert node.phase == "fusing" and node.hold_until == pytest.approx(deadline(0))
    assert node.timeout() == pytest.approx(deadline(0) - (T0 + 0.002))
    net.measure(0, [1, 2])
    net.at(T0 + 0.010)
    assert [(i, ch) for i, ch, _ in net.deliver()] == [(1, "est"), (2, "est")]
    net.at(deadline(0) - 1e-4)
    assert net.deliver() == [] and node.hold_until is not None
    net.at(deadline(0))  # the deadline: every node shares round 1; the neighbours' messages are kept
    sent = net.deliver()
    assert sorted((i, ch) for i, ch, _ in sent) == [(0, "prior"), (1, "prior"), (2, "prior")]
    assert node.round_deadline == pytest.approx(T0 + TS - FUSION_MARGIN_S)  # one round: the window's end
    net.at(deadline(0) + SETTLE + 0.001)
    assert node.phase == "await_meas" and node.step == 1 and node.last_fused == 3
    assert node.counters.misses == 0 and node.counters.partial_rounds == 0
    # a silent neighbour: the round waits for it to the window's end, not past the next sample
    log = run_steps(net, 1, 1, measured=lambda k, i: True)
    assert len(ests(log, 1)) == 3
    net.at(deadline(1) + SETTLE + 0.001)  # the round-1 messages shared at the deadline are in: fused then
    assert node.phase == "await_meas" and node.step == 2 and node.counters.misses == 0
    net.frozen.add(2)
    net.at(T0 + 2 * TS + 0.001)
    net.measure(2)
    net.at(T0 + 2 * TS + 0.002)
    net.at(deadline(2))
    net.deliver()
    assert node.phase == "fusing" and node.hold_until is None
    net.at(T0 + 3 * TS - FUSION_MARGIN_S - 1e-4)
    assert node.phase == "fusing"
    net.at(T0 + 3 * TS - FUSION_MARGIN_S)
    assert node.phase == "await_meas" and node.step == 3 and node.counters.partial_rounds == 1
    assert node.counters.misses == 0


def test_a_deadline_late_in_the_period_or_lockstep_fuses_at_once():
    """With the deadline at 80 % of the period, 20 ms are left after it: less than half the measurement window,
    so round 1 goes out with the estimate, as it does in lockstep."""
    net = Net(fusion_after_deadline=None)
    net.start()
    for node in net.nodes:
        node.frac = 0.8
    assert not net.nodes[0].fusion_after_deadline()
    net.at(T0 + 0.001)
    net.measure(0, [0])
    net.at(T0 + 0.002)
    assert [(i, ch) for i, ch, _ in net.deliver()] == [(0, "est"), (0, "prior")]
    assert net.nodes[0].round_deadline <= T0 + 0.8 * TS + 1e-9
    net.nodes[0].frac, net.nodes[0].mode, net.nodes[0].timing.mode = 0.5, "lockstep", "lockstep"
    assert not net.nodes[0].fusion_after_deadline()


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
    assert node.rejects.counts == {"early": 1} and node.counters.conflicts == 0
    assert node.last_fused == 3 and node.counters.partial_rounds == 0
    np.testing.assert_array_equal(node.tracker.prior.mean, clean_net.nodes[1].tracker.prior.mean)


def test_a_forged_copy_beside_the_real_prior_is_a_conflict_whether_or_not_it_passes_the_gate():
    for shift in (0.01, 1000.0):  # a plausible lie, and a decoy the gate would refuse
        net = Net()
        net.start()
        run_steps(net, 0, 2)
        _step_with(net, 3, lambda real, shift=shift: [_forged(real, shift)])
        node = net.nodes[1]
        assert node.counters.conflicts == 2 and node.counters.gated == 0
        assert node.last_fused == 2  # itself and node 2: neither copy of node 0's prior is fused


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
    assert node.fuse_step == k + 1  # not fused yet: inside the settle time
    assert node.timeout() <= SETTLE + 1e-9
    net.at(T0 + k * TS + 0.002 + 0.5 * SETTLE)
    node.handle(net.msg("prior", net.keys.prior(0), real))  # the real copy, a few ms behind
    node.advance()
    assert node.fuse_step == k + 1
    net.at(T0 + k * TS + 0.003 + SETTLE)
    node.advance()
    assert node.fuse_step is None and node.counters.conflicts == 2 and node.last_fused == 2


def test_an_exact_replay_is_a_duplicate_and_copies_are_bounded():
    from zentrack.node.schedule import MAX_COPIES

    net = Net()
    net.start()
    run_steps(net, 0, 2)
    fakes = lambda real: [real] + [_forged(real, 1000.0, salt=s) for s in range(MAX_COPIES)]  # noqa: E731
    _step_with(net, 3, fakes)
    node = net.nodes[1]
    # the replay of the real prior was kept (it came first), the real one itself is then the duplicate; the
    # first forged copy makes a conflict, the second is refused as one at once: nothing is fused from node 0
    assert node.rejects.counts == {"conflict": 1, "duplicate": 1}
    assert node.counters.conflicts == MAX_COPIES and node.last_fused == 2


def test_a_start_that_contradicts_the_run_under_way_is_refused_and_counted():
    net = Net()
    net.start()
    run_steps(net, 0, 3)
    node = net.nodes[0]
    x0 = net.scn.x0_estimate[0]
    repeat = Start(T0, TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0).encode()
    node.handle(net.msg("start", net.keys.start, repeat))  # truth re-sends the start when a node joins
    assert node.rejects.counts == {}
    forged = [Start(T0 - 120.0, TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0).encode(),  # earlier t0
              Start(T0, 2 * TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0).encode(),
              Start(T0, TS, net.scn.steps, "realtime", tuple([0, 1, 2, 9]), FRAC, x0).encode(),
              Start(T0, TS, net.scn.steps, "realtime", tuple([0, 1, 2]), FRAC, x0 + 1000.0).encode()]
    for payload in forged:
        node.handle(net.msg("start", net.keys.start, payload))
    assert node.rejects.counts == {"conflict": 4}
    assert node.t0 == T0 and node.ts == TS and node.participants == {0, 1, 2}
    run_steps(net, 4, 5)  # and it goes on stepping as before
    assert node.step == 6 and node.counters.misses == 0


def test_a_long_period_is_not_silence_but_a_missing_measurement_past_it_is():
    """With T = 10 s a measurement message comes every 10 s: only time past the expected one counts."""
    import argparse

    from zentrack.node.process import NodeProcess

    net = Net()
    net.start()
    node = net.nodes[0]
    node.ts = 10.0
    proc = NodeProcess(argparse.Namespace(reconnect_s=2.0), node, net.keys, stop=None)
    proc.last_meas = T0 + 20.0
    assert proc.truth_silence(T0 + 25.0) is None  # 5 s into a 10 s period
    gone, why = proc.truth_silence(T0 + 33.0)
    assert gone == pytest.approx(3.0) and "no measurement" in why


def _corrupt(node, metres: float) -> None:
    """Move a node's prior ``metres`` off along x with its covariance unchanged: an estimate gone wrong."""
    node.tracker.prior.mean[0] += metres


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
    assert node.counters.gated == 2 and node.counters.outvoted == 1 and node.last_fused == 2
    assert node.counters.partial_rounds == 1  # nobody passed the gate, so it waited for the deadline
    # the neighbours refuse node 1's message but are one against one: they are not outvoted
    assert [net.nodes[j].counters.outvoted for j in (0, 2)] == [0, 0]
    assert all(net.nodes[j].counters.gated == 1 for j in (0, 2))
    err = abs(node.tracker.prior.mean[0] - clean.nodes[1].tracker.prior.mean[0])
    assert err < 100.0, err  # back with the network in one step (it was 2 km off)
    run_steps(net, 5, 8)
    assert node.counters.outvoted == 1 and node.counters.gated == 2  # and it stays in


def test_a_single_refused_neighbour_lifts_the_gate_after_a_streak_and_the_two_estimates_meet():
    """Two nodes that refuse each other cannot tell who is wrong: after OUTVOTED_STREAK rounds of refusals
    each fuses the other's message with its own (neither is outvoted) and the gap closes."""
    from zentrack.node.schedule import OUTVOTED_STREAK

    net = Net(nodes=2)
    net.start()
    run_steps(net, 0, 3)
    _corrupt(net.nodes[1], 2000.0)
    gap = lambda: abs(net.nodes[1].tracker.prior.mean[0] - net.nodes[0].tracker.prior.mean[0])  # noqa: E731
    run_steps(net, 4, 4 + OUTVOTED_STREAK - 2)
    assert [n.counters.gated for n in net.nodes] == [OUTVOTED_STREAK - 1] * 2
    assert [n.counters.gate_lifted for n in net.nodes] == [0, 0] and gap() > 1000.0
    run_steps(net, 4 + OUTVOTED_STREAK - 1, 4 + OUTVOTED_STREAK - 1)
    assert [n.counters.gate_lifted for n in net.nodes] == [1, 1]
    assert [n.counters.outvoted for n in net.nodes] == [0, 0]
    assert gap() < 200.0, gap()
