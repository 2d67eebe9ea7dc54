"""The parts of the tracker's schedule, each on its own: no Zenoh, no clock, no schedule around them.

Phases and their table, the timing rules, admission of messages, the fusion policy with a stand-in gate,
relay merging, the warm-start choice, membership, start conflicts and the stop confirmation, counters.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.scan import Scan
from zentrack.node.context import Membership
from zentrack.node.counters import Counters, RejectLog, snapshot
from zentrack.node.diffusion.admission import (
    EARLY_TOLERANCE_STEPS,
    MAX_COPIES,
    Admission,
    Buffers,
    earliest_round_message,
)
from zentrack.node.diffusion.fusion_policy import OUTVOTED_STREAK, FusionPolicy
from zentrack.node.diffusion.relays import merge_relays, relayable, with_relayed
from zentrack.node.diffusion.tracker import Pair, Tracker
from zentrack.node.diffusion.warm_start import WarmChoice, warm_choice
from zentrack.node.phases import TRANSITIONS, Phase, TransitionError, check_transition
from zentrack.node.run_control import STOP_CONFIRM_S, StopConfirm, start_conflicts
from zentrack.node.timing import COAST_MARGIN_S, FUSION_MARGIN_S, REALTIME_FUTURE_STEPS, StepTiming
from zentrack.transport.messages import Measurement, RoundMessage, Start
from zentrack.transport.wire import Message, WireError
from zentrack.truth.simulation.simulate import simulate

T0, TS = 100.0, 0.1


# ---------------------------------------------------------------- phases
def test_every_phase_has_a_row_and_the_table_allows_only_its_moves():
    assert set(TRANSITIONS) == set(Phase)
    for a in Phase:
        assert check_transition(a, a) is a  # staying is always allowed
        for b in Phase:
            if b is a:
                continue
            if b in TRANSITIONS[a]:
                assert check_transition(a, b) is b
            else:
                with pytest.raises(TransitionError, match=f"{a.value} to {b.value}"):
                    check_transition(a, b)


def test_a_step_goes_round_the_table_and_nothing_jumps_into_fusion_from_idle():
    path = [Phase.IDLE, Phase.AWAIT_MEAS, Phase.AWAIT_SCANS, Phase.AWAIT_RELAYS, Phase.FUSING, Phase.AWAIT_MEAS,
            Phase.WARMING, Phase.AWAIT_MEAS]
    for a, b in zip(path, path[1:], strict=False):
        check_transition(a, b)
    for bad in [(Phase.IDLE, Phase.FUSING), (Phase.FUSING, Phase.AWAIT_SCANS), (Phase.WARMING, Phase.FUSING),
                (Phase.AWAIT_RELAYS, Phase.AWAIT_MEAS)]:
        with pytest.raises(TransitionError):
            check_transition(*bad)
    assert Phase.FUSING == "fusing"  # phases compare equal to the names logged


# ---------------------------------------------------------------- timing
def realtime(frac: float = 0.5, after: bool | None = None) -> StepTiming:
    return StepTiming("realtime", frac, TS, T0, after_deadline=after)


def test_deadlines_and_the_step_of_a_time():
    t = realtime()
    assert t.deadline(0) == pytest.approx(T0 + 0.05) and t.deadline(7) == pytest.approx(T0 + 0.75)
    assert t.k_now(T0) == 0 and t.k_now(T0 + 0.0999) == 0 and t.k_now(T0 + 0.1) == 1 and t.k_now(T0 - 0.01) == -1
    with pytest.raises(AssertionError):
        StepTiming("realtime", 0.5, TS).deadline(0)  # no start yet


def test_fusion_follows_the_deadline_only_when_the_period_leaves_room():
    assert realtime(0.5).fusion_after_deadline()  # 45 ms after the deadline >= 25 ms
    assert not realtime(0.8).fusion_after_deadline()  # 15 ms < 40 ms
    assert not StepTiming("lockstep", 0.5, TS, T0).fusion_after_deadline()
    assert not realtime(0.5, after=False).fusion_after_deadline() and realtime(0.8, after=True).fusion_after_deadline()
    assert realtime(0.5).fusion_window_end(3) == pytest.approx(T0 + 0.3 - FUSION_MARGIN_S)
    assert realtime(0.8).fusion_window_end(3) == pytest.approx(T0 + 0.28)


def test_round_deadlines_keep_a_reserve_per_round_but_at_least_an_equal_share():
    t = realtime(0.5, after=False)
    end = t.fusion_window_end(1)  # T0 + 0.05
    reserve = 0.5 * TS / (4 * 4)
    # early in the window: the reserve rules (three rounds still to go after this one)
    assert t.round_deadline(T0 + 0.01, 1, 1, 4) == pytest.approx(end - 3 * reserve)
    # late in the window: an equal share of what is left
    now = end - 0.003
    assert t.round_deadline(now, 1, 2, 4) == pytest.approx(now + 0.003 / 3)
    assert t.round_deadline(T0, 1, 4, 4) == pytest.approx(end)  # the last round ends with the window
    assert t.round_deadline(end + 1.0, 1, 1, 4) == pytest.approx(end)  # never after the window


def test_scan_and_relay_deadlines_and_the_message_windows():
    t = realtime(0.5, after=False)
    assert t.scan_deadline(2, 1) == pytest.approx(T0 + (2 + 0.25) * TS)
    assert t.relay_deadline(2, 1) == pytest.approx(0.5 * (T0 + 0.225 + T0 + 0.25))
    assert realtime(0.5).relay_deadline(2, 1) == pytest.approx(T0 + 0.25)  # fusion after the deadline
    now = T0 + 0.55  # step 5
    assert t.meas_window(3, now) == (4, 5 + REALTIME_FUTURE_STEPS)
    assert t.meas_window(6, now) == (6, 5 + REALTIME_FUTURE_STEPS)
    assert t.prior_window(2, now) == (4, 5 + REALTIME_FUTURE_STEPS + 1)
    lock = StepTiming("lockstep", 0.5, TS, T0)
    assert lock.meas_window(3, now) == (3, 4) and lock.prior_window(2, now) == (3, 4)
    assert COAST_MARGIN_S < 0.5 * TS


# ---------------------------------------------------------------- admission
@pytest.fixture(scope="module")
def setup():
    scn = simulate(builtin_spec("exp2", nodes=3, steps=20), runs=1, seed=3)
    return scn, RunSetup.from_data(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")


def admission(setup) -> tuple[Admission, Counters, Buffers]:
    counters, buffers = Counters(), Buffers()
    tracker = Tracker(setup[1].node_config(0))
    return Admission(tracker, counters, buffers), counters, buffers


def prior_bytes(k: int, sender: int, shift: float = 0.0, rnd: int = 1) -> bytes:
    y = np.eye(12) * 1e-2  # exp2's TESKF state
    return RoundMessage(k, k * TS, sender, rnd, {"state": (y, np.full(12, shift))}, 0.0).encode()


def test_measurements_are_taken_once_per_step_within_the_window(setup):
    adm, counters, buffers = admission(setup)
    z = setup[0].measurements[0, 3, 0]
    msg = Message("meas", "k", Measurement(3, 0.3, 0, z, None, 1.0).encode(), 2.0)
    adm.measurement(msg, 2, 5)
    assert counters.meas_rx == 1 and buffers.meas[3].t_recv == 2.0 and buffers.meas[3].meas.k == 3
    with pytest.raises(WireError) as err:
        adm.measurement(msg, 2, 5)
    assert err.value.reason == "duplicate"
    with pytest.raises(WireError) as err:
        adm.measurement(Message("meas", "k", Measurement(9, 0.9, 0, z, None, 1.0).encode(), 2.0), 2, 5)
    assert err.value.reason == "future"
    with pytest.raises(WireError) as err:  # a point-target filter takes one return per scan
        adm.measurement(Message("meas", "k", Measurement(4, 0.4, 0, np.stack([z, z]), None, 1.0).encode(), 2.0), 2, 5)
    assert err.value.reason == "shape" and counters.meas_rx == 1


LOCKSTEP = StepTiming("lockstep", 0.5, TS)


def test_round_messages_late_duplicate_and_conflict(setup):
    adm, counters, buffers = admission(setup)
    adm.prior(Message("prior", "k", prior_bytes(2, 1), 0.0), 1, 1, 5, fused_upto=2, fusing=None, timing=LOCKSTEP)
    assert counters.late == 1 and not buffers.priors  # step 2 was fused already
    for i in range(MAX_COPIES):
        adm.prior(Message("prior", "k", prior_bytes(4, 1, shift=i), 0.0), 1, 1, 5, fused_upto=2, fusing=None,
                  timing=LOCKSTEP)
    assert len(buffers.priors[(4, 1)][1]) == MAX_COPIES == 2 and counters.prior_rx == MAX_COPIES
    # two different copies are already a conflict: a third is refused at once, and nothing evicts the first two
    for payload, reason in [(prior_bytes(4, 1, shift=0), "duplicate"), (prior_bytes(4, 1, shift=9), "conflict"),
                            (prior_bytes(4, 1, rnd=2), "schema"), (prior_bytes(9, 1), "future")]:
        with pytest.raises(WireError) as err:
            adm.prior(Message("prior", "k", payload, 0.0), 1, 1, 5, fused_upto=2, fusing=None, timing=LOCKSTEP)
        assert err.value.reason == reason
    assert [c.raw for c in buffers.priors[(4, 1)][1]] == [prior_bytes(4, 1, shift=i) for i in range(2)]
    with pytest.raises(WireError) as err:  # the key says node 1, the message node 2
        adm.prior(Message("prior", "k", prior_bytes(4, 2), 0.0), 1, 1, 5, fused_upto=2, fusing=None, timing=LOCKSTEP)
    assert err.value.reason == "sender_mismatch"


def test_a_round_message_before_its_sender_could_have_made_it_is_early(setup):
    """Realtime: a prior for step s needs the measurement of step s - 1 (sampled at t0 + (s - 1) ts), so one
    that arrives more than EARLY_TOLERANCE_STEPS periods before that is refused; lockstep has no clock."""
    adm, counters, buffers = admission(setup)
    timing = StepTiming("realtime", 0.5, TS, t0=T0)
    earliest = earliest_round_message(timing, 4)
    assert earliest == pytest.approx(T0 + (3 - EARLY_TOLERANCE_STEPS) * TS)
    assert earliest_round_message(LOCKSTEP, 4) is None
    # a forger's copy re-issued for step 4 as soon as it saw step 3's prior (sent at step 2's deadline)
    with pytest.raises(WireError) as err:
        adm.prior(Message("prior", "k", prior_bytes(4, 1, shift=5), T0 + 2.5 * TS), 1, 1, 5, 2, None, timing)
    assert err.value.reason == "early" and not buffers.priors
    adm.prior(Message("prior", "k", prior_bytes(4, 1), earliest + 1e-6), 1, 1, 5, 2, None, timing)
    adm.prior(Message("prior", "k", prior_bytes(4, 1, shift=1), T0 + 3.5 * TS), 1, 1, 5, 2, None, timing)
    assert len(buffers.priors[(4, 1)][1]) == 2 and counters.prior_rx == 2


# ---------------------------------------------------------------- fusion policy
def pair(value: float, warm: bool = False) -> Pair:
    return Pair(1, {"state": (np.eye(1), np.array([value]))}, warm=warm)


def close(a: Pair, b: Pair) -> bool:
    return abs(a.blocks["state"][1][0] - b.blocks["state"][1][0]) < 1.0


def policy(lockstep: bool = False) -> tuple[FusionPolicy, Counters]:
    counters = Counters()
    return FusionPolicy(0, lockstep, close, counters), counters


def test_one_copy_is_gated_and_two_are_a_conflict_whichever_passes():
    pol, counters = policy()
    received = {1: [pair(0.2), pair(50.0)], 2: [pair(70.0)], 3: [pair(0.1), pair(-0.3)], 4: [pair(0.3)]}
    chosen, outvoted = pol.chosen((1, 1), received, pair(0.0))
    # node 1: one copy passes, one does not: still a conflict (the gate does not pick between copies)
    assert not outvoted and set(chosen) == {4} and chosen[4] is received[4][0]
    assert counters.gated == 1 and counters.conflicts == 4 and counters.outvoted == 0
    assert pol.heard(received, pair(0.0)) == {1, 3, 4}  # a conflict is decided: nothing more to wait for
    assert policy(lockstep=True)[0].heard(received, pair(0.0)) == {1, 2, 3, 4}  # lockstep: any copy


def test_a_majority_that_agrees_outvotes_the_node_and_a_lone_refusal_streak_lifts_the_gate():
    pol, counters = policy()
    received = {1: [pair(40.0)], 2: [pair(40.5)], 3: [pair(0.2)]}
    chosen, outvoted = pol.chosen((1, 1), received, pair(0.0))
    assert outvoted and set(chosen) == {1, 2} and counters.outvoted == 1
    disagree = {1: [pair(40.0)], 2: [pair(80.0)], 3: [pair(0.2)]}
    assert pol.chosen((1, 1), disagree, pair(0.0)) == ({3: disagree[3][0]}, False)
    pol, counters = policy()
    for r in range(OUTVOTED_STREAK):
        chosen, outvoted = pol.chosen((1, r), {1: [pair(40.0)]}, pair(0.0))
        assert not outvoted
        assert (set(chosen) == {1}) == (r == OUTVOTED_STREAK - 1)  # lifted on the streak's last round only
    assert counters.gate_lifted == 1 and pol.refused_streak == 0


def test_a_warm_own_pair_or_none_never_outvotes():
    pol, counters = policy()
    received = {1: [pair(40.0)], 2: [pair(40.5)]}
    assert pol.chosen((1, 1), received, pair(0.0, warm=True)) == ({}, False)
    chosen, _ = pol.chosen((1, 1), received, None)  # a warm start: nothing to gate against
    assert set(chosen) == {1, 2} and counters.outvoted == 0


# ---------------------------------------------------------------- relays
def scan(origin: int, value: float) -> Scan:
    return Scan(4, origin, np.array([[value, 0.0]]), np.zeros(3), np.eye(2))


def test_relays_give_each_missing_origin_once_and_disputed_origins_never():
    relays = {2: [scan(5, 1.0), scan(6, 2.0), scan(0, 9.0)], 1: [scan(5, 1.0), scan(6, 3.0), scan(7, 4.0)]}
    merged = merge_relays(relays, have={0, 1, 2})
    assert sorted(merged.extra) == [5, 7] and merged.disputed == [6]
    assert merged.extra[7].returns[0, 0] == 4.0
    order = with_relayed([scan(3, 0.0), scan(0, 0.0), scan(1, 0.0)], merged.extra, own=0)
    assert [s.sensor for s in order] == [0, 1, 3, 5, 7]
    empty = Scan(4, 3, np.zeros((0, 2)), np.zeros(3), np.eye(2))
    assert [s.sensor for s in relayable([empty, scan(2, 1.0)])] == [2]


# ---------------------------------------------------------------- warm start, run control, counters
def test_the_warm_start_choice_in_its_order():
    assert warm_choice(1, True, 3, 2, 0, 20) is WarmChoice.WARM_START
    assert warm_choice(0, True, 3, 2, 0, 20) is WarmChoice.RESUME_OWN
    assert warm_choice(0, False, 2, 2, 0, 20) is WarmChoice.WARM_START_FROM_WARMING
    assert warm_choice(0, False, 0, 2, 19, 20) is WarmChoice.WAIT
    assert warm_choice(0, False, 0, 2, 20, 20) is WarmChoice.COLD_START
    assert warm_choice(0, False, 0, 0, 0, 20) is WarmChoice.COLD_START  # alone: at once


def test_membership_waits_for_live_neighbours_in_realtime_and_participants_in_lockstep():
    m = Membership()
    m.node_token(1, True)
    m.node_token(3, True)
    m.node_token(3, False)
    assert m.expected([1, 2, 3], {0, 1, 2, 3}, lockstep=False) == {1}
    assert m.expected([1, 2, 3], {0, 1, 2, 3}, lockstep=True) == {1, 2}  # 3 left; 2's token not seen yet
    m.truth_token(False, 5.0)
    assert not m.truth_alive and m.truth_gone_since == 5.0
    m.truth_token(True, 6.0)
    assert m.truth_alive and m.truth_gone_since is None


def test_a_start_may_only_repeat_the_run_and_a_stop_waits_for_the_truth_to_leave():
    run = Start(1.0, 0.1, 9, "realtime", (0, 1), 0.5, np.zeros(3))
    assert start_conflicts(replace(run, participants=(1, 0)), run) == []
    assert start_conflicts(replace(run, t0=2.0, x0=np.ones(3), participants=(0,)), run) == ["t0", "participants", "x0"]
    stop = StopConfirm()
    assert stop.decide(False, True, 0.0) == "none"
    stop.pending_since = 10.0
    assert stop.decide(False, True, 10.0 + STOP_CONFIRM_S - 0.1) == "wait"
    assert stop.decide(True, True, 10.5) == "stop" and stop.decide(False, False, 10.5) == "stop"
    assert stop.decide(False, True, 10.0 + STOP_CONFIRM_S + 0.1) == "refuse" and stop.pending_since is None


def test_counters_snapshot_and_the_reject_log():
    counters = Counters(late=2, steps=7)
    counters.misses += 1
    log = RejectLog(0, clock=lambda: 0.0)
    log.add("prior", WireError("flood", "x"))
    log.add("prior", WireError("flood", "y"))
    snap = snapshot(counters, log.counts, {"meas/rate": 1}, {"update": 0}, incarnation=42)
    assert snap["late"] == 2 and snap["steps"] == 7 and snap["misses"] == 1 and snap["incarnation"] == 42
    assert snap["rejected"] == {"flood": 2} and snap["dropped"] == {"meas/rate": 1}
    assert set(Counters.__dataclass_fields__) <= set(snap)
