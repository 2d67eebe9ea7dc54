"""Trackers on their own clocks (issue 52, item 3), below the process: each neighbour's clock offset estimated from
its round messages (``node/diffusion/neighbour_clocks.py``), the step its messages are mapped to and their
prediction to the tracker's time, the plant over a negative interval, a three-tracker network with one tracker's
clock 0.3 s ahead stepped by hand on the in-memory bus of ``tests/schedule_net.py``, and the recorder that judges
each estimate at its time of validity."""
from __future__ import annotations

import numpy as np
import pytest
from schedule_net import FRAC, T0, TS, Net
from test_detections import LAG, det

from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.fusion.models import INTERVAL_PLANTS, plant_over
from zentrack.node.clock_offset import QUANTILE, WINDOW, OffsetEstimator
from zentrack.node.diffusion.neighbour_clocks import (
    ALLOWANCE_S,
    SHIFT_HYSTERESIS,
    NeighbourClocks,
    predicted_blocks,
    prior_valid_at,
)
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.schedule import NodeSchedule
from zentrack.transport import wire
from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, RoundMessage
from zentrack.truth.simulation.sensor_stream import state_at

#: the least one-way delay of the hand-driven bus below (s)
DELAY = 0.0005
#: steps of the hand-driven networks, and the first step their errors are taken from
STEPS, FIRST = 60, 15
#: how often the hand-driven networks' trackers are woken (s)
TICK = 0.002


def delays(n: int, seed: int = 1) -> np.ndarray:
    """One-way delays as a loaded host sees them: at least DELAY, a long tail."""
    return DELAY + np.random.default_rng(seed).exponential(0.004, n)


def observed(o: float, n: int = 100, clocks: NeighbourClocks | None = None, j: int = 1) -> NeighbourClocks:
    """Tracker 0's clocks after ``n`` messages of neighbour ``j``, whose clock is ``o`` ahead of its own."""
    clocks = clocks or NeighbourClocks(0, [j], TS)
    for k, d in enumerate(delays(n)):
        t_pub = T0 + (k + FRAC) * TS + o  # on j's clock
        clocks.observe(j, t_pub - o + d, t_pub, (k, 1))
    return clocks


# ---------------------------------------------------------------- the offset
@pytest.mark.parametrize("o", [0.3, -0.3, 0.25, -0.05, 2.0])
def test_a_neighbours_offset_is_its_clock_less_this_trackers_less_the_least_delay(o):
    clocks = observed(o)
    offset = clocks.offset(1)
    assert o - 0.005 < offset <= o - DELAY  # biased low by the low quantile of the delays, never high
    assert clocks.report() == {"1": round(offset, 6)}


def test_synchronised_neighbours_are_left_alone_and_configured_clocks_are_not_estimated():
    near = observed(0.004)  # within the dead band (10 ms): as before, to the bit
    assert near.offset(1) == 0.0 and near.shift(1) == 0 and near.lead(1, 7, prior_valid_at(7, TS)) == 0.0
    configured = observed(0.3, clocks=NeighbourClocks(0, [1], TS, estimated=False))
    assert configured.clocks[1].samples == 0 and configured.offset(1) == 0.0 and configured.report() == {"1": 0.0}
    assert NeighbourClocks(0, [1], TS).report() == {"1": None}  # nothing heard yet


def test_a_few_forged_stamps_and_replays_do_not_move_it():
    """A fifth of the window (less one) from the future does not move the low quantile; a copy of a (step, round)
    already taken, whatever its stamp, is no sample."""
    clocks = observed(0.3, n=WINDOW)
    before = clocks.offset(1)
    forged = int(QUANTILE * (WINDOW - 1))
    for n in range(forged):  # stamps 5 s in the future: a message received before it was sent
        clocks.observe(1, T0 + 200.0 + n, T0 + 205.3 + n, (1000 + n, 1))
    for k in range(WINDOW - 2 * forged, WINDOW):  # replays with stamps as forged: keys already in the window
        clocks.observe(1, T0 + k * TS, T0 + k * TS + 9.0, (k, 1))
    assert clocks.offset(1) == pytest.approx(before, abs=0.005)


# ---------------------------------------------------------------- the step and the lead
@pytest.mark.parametrize("o, n", [(0.2995, 3), (-0.3005, -3), (0.25, 2), (-0.25, -3), (0.0, 0), (0.085, 0),
                                  (0.097, 1), (1.2, 12)])
def test_the_newest_message_due_by_the_settle_time_is_taken_and_predicted_over_the_rest(o, n):
    """Step s fuses the neighbour's message of s + n, n = floor((o + ALLOWANCE_S) / ts): the newest published by
    the time the round's settle time is over; predicted over dt = o - n ts, -ALLOWANCE_S <= dt < ts - ALLOWANCE_S."""
    clocks = NeighbourClocks(0, [1], TS)
    clocks.clocks[1].add(0.0, o, key=0)  # one sample: -o exactly
    assert clocks.shift(1) == n and clocks.own_step(1, 40 + n) == 40
    dt = clocks.lead(1, 40, prior_valid_at(40 + n, TS))
    assert dt == pytest.approx(o - n * TS) and -ALLOWANCE_S - 1e-12 <= dt < TS - ALLOWANCE_S


def test_the_shift_holds_at_a_periods_edge_until_the_offset_leaves_it_by_the_hysteresis():
    clocks = NeighbourClocks(0, [1], TS)
    path = [(0.285, 2), (0.2915, 2), (0.2945, 2), (0.2955, 3), (0.2855, 3), (0.2845, 2)]
    edge = 3 * TS - ALLOWANCE_S
    assert path[2][0] < edge + SHIFT_HYSTERESIS * TS < path[3][0]  # (the band's edges, as the path assumes)
    for key, (o, n) in enumerate(path):
        clocks.clocks[1] = OffsetEstimator(tolerance=5.0)
        clocks.clocks[1].add(0.0, o, key=key)
        assert clocks.shift(1) == n, (o, clocks.shift(1))


# ---------------------------------------------------------------- the prediction
@pytest.fixture(scope="module")
def tracker() -> Tracker:
    net = Net()
    net.start()
    tr = net.nodes[0].payload.tracker
    assert tr.prior is not None
    return tr


def test_a_neighbours_message_is_predicted_over_its_lead_by_the_trackers_filter_either_way(tracker):
    """The message's estimate is carried over dt (position + v dt, the plant's transition), losing information
    forward and back (the process noise of |dt|); dt of zero is the message itself."""
    est = tracker.kinematic(tracker.prior)
    blocks = tracker.message_blocks(tracker.prior)
    assert predicted_blocks(tracker, blocks, 0.0) is blocks
    n = tracker.kinematic_dim
    for dt in (0.0995, -0.004):
        (y_mat, y_vec), = predicted_blocks(tracker, blocks, dt).values()
        cov = np.linalg.inv(y_mat)
        mean = cov @ y_vec
        np.testing.assert_allclose(mean[:3], est.mean[:3] + dt * est.mean[3:6], atol=1e-9)
        assert np.trace(cov[:n, :n]) > np.trace(est.cov) + 0.9 * abs(dt) / TS * n  # + sigma_w^2 |dt| / ts per state
    back = predicted_blocks(tracker, predicted_blocks(tracker, blocks, 0.03), -0.03)
    np.testing.assert_allclose(np.linalg.solve(back["state"][0], back["state"][1])[:n], est.mean, atol=1e-9)


@pytest.mark.parametrize("plant", sorted(INTERVAL_PLANTS))
def test_the_plant_over_a_negative_interval_undoes_the_transition_with_the_noise_of_its_length(plant):
    back, forward = plant_over(plant, TS, -0.004, {}), plant_over(plant, TS, 0.004, {})
    np.testing.assert_allclose(back.A @ forward.A, np.eye(back.A.shape[0]), atol=1e-12)
    np.testing.assert_array_equal(back.Q, forward.Q)
    assert np.all(np.linalg.eigvalsh(back.Q) >= -1e-15)
    with pytest.raises(ValueError, match="not zero"):
        plant_over(plant, TS, 0.0, {})


# ---------------------------------------------------------------- a network with one clock ahead
class SkewedNet(Net):
    """The three-tracker network of ``schedule_net.py`` with sensors of their own, tracker i's clock ``skew[i]``
    ahead of the others' (a whole number of periods; its sensor shares its host's clock), every message received
    DELAY after it is sent, on the receiver's clock."""

    def __init__(self, skew: dict[int, float], clock: str = "estimated", filter_kind: str = "teskf") -> None:
        self.skew = skew

        def configure(cfg) -> None:
            cfg.detections = {"lag_ms": LAG * 1e3, "clock": clock, "sensors": [
                {"sensor": cfg.node, "rate_hz": 10.0, "offset_s": 0.0, "min_latency_s": 0.0}]}

        super().__init__(configure=configure, fusion_after_deadline=None, filter_kind=filter_kind)

    def local(self, i: int) -> float:
        return self.now + self.skew.get(i, 0.0)

    def _make(self, i: int, cold_after: int, fusion_after_deadline: bool | None = False) -> NodeSchedule:
        cfg = self.setup.node_config(i)
        assert self.configure is not None
        self.configure(cfg)
        cfg.validate()
        return NodeSchedule.diffusion(self.keys, cfg, Tracker(cfg), clock=lambda: self.local(i),
                                      send=lambda ch, data, i=i: self.sent.append((i, ch, data)),
                                      cold_after=cold_after, incarnation=100 + i,
                                      fusion_after_deadline=fusion_after_deadline)

    def deliver(self) -> list[tuple[int, str, dict]]:
        out, sent, self.sent = [], self.sent, []
        for i, ch, data in sent:
            out.append((i, ch, wire.unpack(data)))
            if ch == "prior":
                for j, node in enumerate(self.nodes):
                    if i in node.payload.tracker.neighbours:
                        node.handle(Message(ch, self.keys.prior(i), data, self.local(j) + DELAY))
        return out


def run_skewed(skew: dict[int, float], steps: int = STEPS, clock: str = "estimated",
               filter_kind: str = "teskf") -> tuple[SkewedNet, dict]:
    """``steps`` steps of the skewed network, every tracker woken every TICK: each sensor's scan of step k (measured
    at its true time, stamped on its tracker's host's clock) arrives 10 ms later; returns the network and node ->
    step -> estimate (mean)."""
    net = SkewedNet(skew, clock, filter_kind)
    net.start()
    scn, estimates = net.scn, {i: {} for i in range(3)}
    ahead = max([0.0, *skew.values()])
    for tick in range(-round(ahead / TICK) - 5, round((steps * TS + LAG) / TICK)):
        k, at = divmod(tick, round(TS / TICK))
        net.at(T0 + tick * TICK)
        if at == 5 and 0 <= k < scn.steps:
            for i in range(3):  # (on a window's start when a whole number of periods ahead, as rounding leaves it)
                stamp = T0 + round(k + skew.get(i, 0.0) / TS, 9) * TS
                d = det(k, stamp, i, scn.measurements[0, k, i][None], scn)
                net.nodes[i].handle(Message("det", net.keys.det(i), d.encode(), net.local(i) + DELAY))
        for i, ch, data in net.sent:
            if ch == "est":
                e = EstimateMessage.decode(data, i)
                estimates[i][e.k] = e.x
        net.deliver()
    return net, estimates


def rmse(net: SkewedNet, estimates: dict, i: int, first: int = FIRST) -> float:
    """Node ``i``'s position RMSE from step ``first`` on, each estimate judged at its time of validity on the true
    clock: ``k ts - skew``."""
    ks = sorted(k for k in estimates[i] if k >= first)
    truth = state_at(net.scn, 0, np.array(ks) * TS - net.skew.get(i, 0.0))
    err = np.array([estimates[i][k][:3] for k in ks]) - truth[:, :3]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=-1))))


@pytest.mark.slow
@pytest.mark.cpu_only  # (a few seconds of hand-driven networks, no process)
def test_a_tracker_whose_clock_is_300_ms_ahead_fuses_with_its_neighbours_at_its_time_and_they_with_it():
    """Node 1's clock is 0.3 s ahead. Each of its neighbours estimates its offset within the bus's least delay,
    fuses its message of step s + 3 at step s (predicted back over that delay) and it theirs of s - 3: every round
    complete but node 1's first three (its neighbours have no message that early), nothing refused, no deadline
    missed, every tracker as accurate as in the network without the skew (measured: 0.96-0.98 of it). With the
    clocks configured as synchronised, node 1 refuses every prior as stale and tracks on its own bearings alone
    (measured: 2.3 times the error, what an isolated tracker's Schmidt update of the unobservable leaves)."""
    clean_net, clean = run_skewed({})
    net, skewed = run_skewed({1: 0.3})
    for i in (0, 2):
        clocks = net.nodes[i].payload.clocks
        assert clocks.offset(1) == pytest.approx(0.3 - DELAY, abs=1e-6) and clocks.shift(1) == 3
        assert clocks.offset(2 - i) == 0.0
    own = net.nodes[1].payload.clocks
    assert all(own.offset(j) == pytest.approx(-0.3 - DELAY, abs=1e-6) and own.shift(j) == -3 for j in (0, 2))
    for i, node in enumerate(net.nodes):
        c = node.payload.counters
        assert c.partial_rounds <= (3 if i == 1 else 0) and c.misses == 0 and not node.ctx.rejects.counts, \
            (i, c, node.ctx.rejects.counts)
        assert c.prior_rx >= 2 * (STEPS - 3), (i, c.prior_rx)
    ratios = [rmse(net, skewed, i) / rmse(clean_net, clean, i) for i in range(3)]
    assert max(ratios) <= 1.05, ratios
    broken_net, broken = run_skewed({1: 0.3}, clock="configured")
    alone = broken_net.nodes[1].payload.counters
    assert broken_net.nodes[1].ctx.rejects.counts.get("stale", 0) >= 2 * (STEPS - 3)
    assert alone.prior_rx == 0 and alone.partial_rounds >= STEPS, alone
    assert rmse(broken_net, broken, 1) >= 1.5 * rmse(clean_net, clean, 1), (rmse(broken_net, broken, 1),
                                                                            rmse(clean_net, clean, 1))


@pytest.mark.slow
@pytest.mark.cpu_only  # (a few seconds of hand-driven networks, no process)
def test_a_neighbours_message_predicted_over_its_lead_keeps_the_network_as_accurate_as_a_synchronised_one():
    """Node 1's clock is 0.315 s behind: its neighbours fuse its message of step s - 4 at step s, valid 0.085 s
    before their time, and it theirs of s + 3, valid 0.015 s before its own; each predicted over that by the
    tracker's filter. With the EKF (whose prediction over an interval is the plant's alone) every tracker stays
    within 5 % of the synchronised network (measured 1.00-1.03); fused as they come, unpredicted, the neighbours'
    messages cost 7-11 % (1.07, 1.11, 1.11). (The TESKF advances its lumped states a whole step per prediction,
    whatever the interval, so there the prediction's mean is right but its lumped states a step's worth too
    uncertain: 1.03-1.10 predicted, 0.98-1.02 unpredicted over 190 steps; docs/sensors.md, "Clocks".)"""
    steps = 100
    clean_net, clean = run_skewed({}, steps=steps, filter_kind="ekf")
    net, skewed = run_skewed({1: -0.315}, steps=steps, filter_kind="ekf")
    assert [net.nodes[i].payload.clocks.shift(1) for i in (0, 2)] == [-4, -4]
    assert net.nodes[0].payload.clocks.lead_s(1) == pytest.approx(0.085 - DELAY, abs=1e-6)
    assert net.nodes[1].payload.clocks.shift(0) == 3
    assert net.nodes[1].payload.clocks.lead_s(0) == pytest.approx(0.015 - DELAY, abs=1e-6)
    ratios = [rmse(net, skewed, i) / rmse(clean_net, clean, i) for i in range(3)]
    assert max(ratios) <= 1.05, ratios


def test_a_prior_whose_time_of_validity_does_not_fit_its_step_is_refused():
    net, _ = run_skewed({}, steps=5)
    own = net.nodes[0].payload
    blocks = own.tracker.message_blocks(own.tracker.prior)
    bad = RoundMessage(7, 7 * TS, 1, 1, blocks, net.local(1)).encode()  # a synchronous t: (k - 1) ts expected
    net.nodes[0].handle(Message("prior", net.keys.prior(1), bad, net.local(0)))
    assert net.nodes[0].ctx.rejects.counts.get("schema") == 1


def test_a_message_remapped_by_a_better_estimate_of_its_senders_clock_takes_the_place_of_the_first():
    """Node 1 (0.3 s ahead) hears node 0's first prior 100 ms late: its estimate of node 0's clock is then 0.4 s
    behind, and that message (step 6) is mapped to its step 10. The next (step 7) comes at once: the estimate is
    now -0.3005 s, and step 7 maps to step 10 too. It takes the first one's place: a remap, not a conflict (which
    would leave node 0 out of that round, and log a forger)."""
    net = SkewedNet({1: 0.3})
    net.start()
    node = net.nodes[1]
    blocks = node.payload.tracker.message_blocks(node.payload.tracker.prior)
    for k, delay in ((6, 0.1), (7, DELAY)):
        t_pub = T0 + LAG + (k - 1 + FRAC) * TS  # node 0's held round 1 (its clock: the true one)
        net.now = t_pub + delay
        node.handle(Message("prior", net.keys.prior(0), RoundMessage(k, prior_valid_at(k, TS), 0, 1, blocks,
                                                                     t_pub).encode(), net.local(1)))
    assert node.payload.clocks.shift(0) == -3
    assert [c.sent_step for c in node.payload.buffers.priors[(10, 1)][0]] == [7]
    assert not node.ctx.rejects.counts and node.payload.counters.prior_rx == 2


# ---------------------------------------------------------------- the recorder
class _Session:
    """Just enough of a Zenoh session for a recorder fed by hand."""

    def declare_subscriber(self, key, handler):
        return self

    def liveliness(self):
        return self

    def declare_token(self, key):
        return self

    def undeclare(self):
        pass


@pytest.mark.parametrize("at_validity", [True, False])
def test_the_recorder_judges_a_tracker_on_its_own_clock_at_its_estimates_time_of_validity(exp2_small, at_validity):
    """Node 2's clock is 0.3 s ahead: its estimate of step k, the true state at k ts - 0.3, is exact when judged at
    its time of validity; judged at step k it is off by the target's motion over 0.3 s. The others are exact."""
    keys, scn = Keys("t"), exp2_small
    rec = Recorder(_Session(), keys, Estimates(scn, at_validity=at_validity))  # type: ignore[arg-type]
    for k in range(scn.steps):
        for i in range(scn.nodes):
            o = 0.3 if i == 2 else 0.0
            x = state_at(scn, 0, np.array([k * TS - o]))[0] if o else scn.truth[0][k]
            est = EstimateMessage(k, k * TS, i, x, np.eye(x.size), T0 + k * TS + 0.07 + o, update_us=50.0)
            rec._record(Message("est", keys.est(i), est.encode(), T0 + k * TS + 0.07 + 0.002 + 0.001 * (k % 3)))
    nodes = rec.summary()["nodes"]
    assert all(nodes[i]["rmse_p"] < 1e-9 for i in range(scn.nodes) if i != 2)
    seen = [n.get("clock_offset_seen_s") for n in nodes]
    arrays = rec.part.arrays(rec)
    if at_validity:
        assert nodes[2]["rmse_p"] < 0.05, nodes[2]["rmse_p"]  # (the truth between samples: Hermite, cm)
        np.testing.assert_array_equal(np.delete(arrays["truth_judged"], 2, axis=1),
                                      np.repeat(scn.truth[0][:, None], scn.nodes - 1, axis=1))
        assert np.all(arrays["clock_offset"][:, 2] == pytest.approx(0.3 - 0.002, abs=1e-6))
        assert seen[2] == pytest.approx(0.3 - 0.002, abs=1e-6) and seen[:2] + seen[3:] == [0.0] * 5
    else:
        assert nodes[2]["rmse_p"] > 0.3 and set(seen) == {None} and "truth_judged" not in arrays
