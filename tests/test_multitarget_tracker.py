"""The multi-target tracker (fusion/multitarget): life cycle, initiation, and a simulated 2-D run with GNN and JPDA.

The simulator is here, small on purpose: constant-velocity targets in a plane (the model's own A and Q, so the
filter is matched), a Cartesian x-y sensor with detection probability P_D, and Poisson clutter uniform over the
surveillance square.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from zentrack.fusion.filters import FilterContext
from zentrack.fusion.models import make_measurement, make_plant
from zentrack.fusion.multitarget import TRANSITIONS, Track, TrackStatus, make_associator
from zentrack.fusion.multitarget.gating import gate_gamma
from zentrack.fusion.multitarget.initiator import PriorInitiator, TwoPointInitiator
from zentrack.fusion.multitarget.lifecycle import MissesCovarianceDeleter, MOfNConfirmer
from zentrack.fusion.multitarget.tracker import MultiTargetTracker
from zentrack.fusion.scan import Scan

TS, SIGMA, Q, P_D, GATE_PROB = 1.0, 5.0, 0.05, 0.9, 0.999
H_XY = np.array([[1.0, 0, 0, 0, 0, 0], [0, 1.0, 0, 0, 0, 0]])
P0 = np.diag([100.0, 100.0, 1.0, 25.0, 25.0, 0.01])


def make_tracker(associator: str, clutter_density: float, filter_name: str = "ekf",
                 deleter: MissesCovarianceDeleter | None = None) -> MultiTargetTracker:
    motion = make_plant("cv3d-cd", TS, {"q": Q})
    context = FilterContext(motion, make_measurement("linear", H_XY), P0)
    assoc = make_associator(associator, {"detection_prob": P_D, "clutter_density": clutter_density,
                                         "gate_prob": GATE_PROB})
    init = TwoPointInitiator(TS, 30.0, P0, (0, 1), (3, 4), gate_prob=GATE_PROB)
    # K = 5: a confirmed target's track is lost by chance (five misses in a row) with probability 0.1^5 per step
    deleter = deleter or MissesCovarianceDeleter(5, 1e4, (0, 1))
    return MultiTargetTracker.from_registry(filter_name, context, assoc, init, deleter, MOfNConfirmer(4, 5))


def simulate(x0: np.ndarray, steps: int, clutter_per_scan: float, half: float, rng: np.random.Generator):
    """Truth ``(K, N, 6)`` by the model's ``x+ = A x + w``, and one scan per step (detections and clutter)."""
    motion = make_plant("cv3d-cd", TS, {"q": Q})
    chol = np.linalg.cholesky(motion.Q)
    truth = [x0]
    for _ in range(steps - 1):
        truth.append(truth[-1] @ motion.A.T + rng.standard_normal(x0.shape) @ chol.T)
    scans = []
    for k, x in enumerate(truth):
        seen = rng.random(len(x)) < P_D
        z = x[seen][:, :2] + rng.normal(scale=SIGMA, size=(int(seen.sum()), 2))
        clutter = rng.uniform(-half, half, size=(rng.poisson(clutter_per_scan), 2))
        returns = np.concatenate([z, clutter])
        rng.shuffle(returns)
        scans.append(Scan(k, 0, returns, np.zeros(3), SIGMA**2 * np.eye(2)))
    return np.array(truth), scans


# ------------------------------------------------------------------------------------------------ life cycle
def test_status_transitions_follow_the_table():
    expected = {("tentative", "confirmed"), ("tentative", "deleted"), ("confirmed", "deleted")}
    for a in TrackStatus:
        for b in TrackStatus:
            track = Track(0, np.zeros(2), np.eye(2), 0, 0, a)
            if a is b or (a.value, b.value) in expected:
                track.move_to(b)
                assert track.status is b
            else:
                with pytest.raises(ValueError, match=f"{a.value} cannot become {b.value}"):
                    track.move_to(b)
    assert {(a.value, b.value) for a, bs in TRANSITIONS.items() for b in bs} == expected


@pytest.mark.parametrize(("m", "n", "outcomes", "want"), [
    (2, 3, [True], "confirmed"),  # birth + one hit = 2 of the first 3
    (3, 4, [False, True], "tentative"),  # 2 hits in 3 steps: may still make 3 of 4
    (3, 4, [False, True, True], "confirmed"),
    (3, 4, [False], "tentative"),  # 1 of 2 so far, two steps left: 3 of 4 is still possible
    (3, 4, [False, False], "deleted"),  # 1 of 3, one step left: 3 of 4 is out of reach
    (2, 4, [False, False, True], "confirmed"),
    (2, 4, [False, False, False], "deleted"),
    (4, 5, [True, True, True], "confirmed"),
])
def test_m_of_n_confirmation(m, n, outcomes, want):
    confirmer = MOfNConfirmer(m, n)
    track = Track(0, np.zeros(2), np.eye(2), 0, 0)
    for hit in outcomes:
        track.record(hit)
        track.move_to(confirmer.decide(track))
    assert track.status.value == want


def test_deleted_after_k_consecutive_misses_only():
    deleter = MissesCovarianceDeleter(max_misses=3)
    track = Track(0, np.zeros(6), np.eye(6), 0, 0, TrackStatus.CONFIRMED)
    for hit in (False, False, True, False, False):
        track.record(hit)
        assert not deleter.should_delete(track)  # never three misses in a row
    track.record(False)
    assert deleter.should_delete(track)


def test_a_coasting_track_is_deleted_when_its_position_covariance_passes_the_bound():
    """The step of deletion is where the predicted covariance P_k = A P_{k-1} A^T + Q, computed here from the
    model, first has a position trace above the bound."""
    bound = 2000.0
    tracker = make_tracker("gnn", 1e-5, deleter=MissesCovarianceDeleter(1000, bound, (0, 1)))
    tracker.initiator.from_prior(np.zeros(6), P0, TrackStatus.CONFIRMED)
    tracker.step(0)
    motion = make_plant("cv3d-cd", TS, {"q": Q})
    p, want = P0.copy(), None
    for k in range(1, 200):
        p = motion.A @ p @ motion.A.T + motion.Q
        if p[0, 0] + p[1, 1] > bound:
            want = k
            break
    assert want is not None and want > 2
    for k in range(1, want):
        assert len(tracker.step(k)) == 1
    assert tracker.step(want) == [] and tracker.deleted[0].status is TrackStatus.DELETED


# ------------------------------------------------------------------------------------------------ initiation
def test_two_point_initiation_gives_position_velocity_and_their_covariance():
    init = TwoPointInitiator(TS, 30.0, P0, (0, 1), (3, 4))
    r = SIGMA**2 * np.eye(2)
    scan = Scan(0, 0, np.zeros((0, 2)), np.zeros(3), r)
    assert init.births(np.array([[0.0, 0.0], [500.0, 500.0]]), scan, 0) == []
    (birth,) = init.births(np.array([[20.0, -10.0], [900.0, 0.0]]), scan, 1)  # only the first is within reach
    np.testing.assert_allclose(birth.mean[[0, 1, 3, 4]], [20.0, -10.0, 20.0, -10.0])
    # the covariance of (z2, (z2 - z1) / T) for independent errors of covariance R, by sampling
    rng = np.random.default_rng(0)
    w1, w2 = rng.multivariate_normal(np.zeros(2), r, size=(2, 200_000))
    err = np.concatenate([w2, (w2 - w1) / TS], axis=1)
    np.testing.assert_allclose(birth.cov[np.ix_([0, 1, 3, 4], [0, 1, 3, 4])], np.cov(err.T), atol=0.5)
    assert birth.cov[2, 2] == P0[2, 2] and birth.cov[0, 2] == 0.0  # an unmeasured component keeps its prior
    # the velocity gate: a return just beyond max_speed T + sqrt(gamma lambda_max(2R)) from every candidate
    reach = 30.0 * TS + math.sqrt(gate_gamma(2, 0.999) * 2 * SIGMA**2)
    assert init.births(np.array([[900.0 + reach * 0.99, 0.0]]), scan, 2) != []
    init.births(np.array([[0.0, 0.0]]), scan, 3)
    assert init.births(np.array([[reach * 1.01, 0.0]]), scan, 4) == []
    assert init.births(np.array([[reach * 1.01, 1.0]]), scan, 6) == []  # a scan apart: candidates dropped


def test_several_sensors_each_pair_their_own_scans_and_start_a_target_once():
    """A tracker that takes four sensors' scans a step (centralized): a target only sensors 1 and 2 see starts a
    track (each sensor's returns pair with its own of the step before, not with another sensor's of the same
    instant or with sensor 3's, which never sees it), and the two sensors' pairs start it once."""
    init = TwoPointInitiator(TS, 30.0, P0, (0, 1), (3, 4))
    r = SIGMA**2 * np.eye(2)
    scans = [Scan(0, i, np.zeros((0, 2)), np.zeros(3), r) for i in range(4)]
    target = [np.array([[100.0, 50.0]]), np.array([[110.0, 45.0]])]  # at steps 0 and 1
    births = []
    for step in (0, 1):
        for i, scan in enumerate(scans):  # sensors 0 and 3 report clutter far apart from one step to the next
            clutter = np.array([[5000.0 if i == 0 else -5000.0, 3000.0 * step]])
            births += init.births(target[step] if i in (1, 2) else clutter, scan, step)
    assert len(births) == 1
    np.testing.assert_allclose(births[0].mean[[0, 1, 3, 4]], [110.0, 45.0, 10.0, -5.0])


def test_from_prior_starts_a_track_at_the_next_step_and_refuses_bad_priors():
    motion = make_plant("cv3d-cd", TS, {"q": Q})
    tracker = MultiTargetTracker.from_registry(
        "ukf", FilterContext(motion, make_measurement("bearing"), P0), make_associator("jpda"), PriorInitiator(),
        MissesCovarianceDeleter(5))
    scan = Scan(0, 0, np.array([[0.1, 0.0]]), np.zeros(3), 1e-4 * np.eye(2))
    assert tracker.step(0, scan) == []  # a bearing-only return starts nothing
    mean = np.array([100.0, 10.0, 0.0, 1.0, 0.0, 0.0])
    tracker.initiator.from_prior(mean, P0)
    (track,) = tracker.step(1, Scan(1, 0, np.zeros((0, 2)), np.zeros(3), 1e-4 * np.eye(2)))
    np.testing.assert_array_equal(track.mean, mean)
    assert track.birth_step == 1 and track.status is TrackStatus.TENTATIVE
    with pytest.raises(ValueError, match="cov is not finite, symmetric and positive definite"):
        tracker.initiator.from_prior(mean, -P0)
    with pytest.raises(ValueError, match="mean contains NaN"):
        tracker.initiator.from_prior(np.full(6, np.nan), P0)
    with pytest.raises(ValueError, match="expected mean"):
        tracker.initiator.from_prior(mean[:3], P0)
    with pytest.raises(ValueError, match="does not follow"):
        tracker.step(1)


# ------------------------------------------------------------------------------------------- simulated run
CROSSING = (0, 1)


def four_targets() -> np.ndarray:
    """Targets 0 and 1 cross at the origin at step 20; 2 and 3 run apart, far from them."""
    x0 = np.zeros((4, 6))
    x0[0, [0, 1, 3, 4]] = [-300.0, -300.0, 15.0, 15.0]
    x0[1, [0, 1, 3, 4]] = [-300.0, 300.0, 15.0, -15.0]
    x0[2, [0, 1, 3, 4]] = [-400.0, 700.0, 20.0, 0.0]
    x0[3, [0, 1, 3, 4]] = [400.0, -700.0, -10.0, 10.0]
    return x0


@pytest.mark.parametrize("associator", ["gnn", "jpda"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_target_gets_a_confirmed_track_that_keeps_its_identity(associator, seed):
    check_simulated_run(associator, seed, "ekf")


@pytest.mark.parametrize("filter_name", ["ukf", "teskf"])
def test_other_registered_filters_serve_as_the_per_track_filter(filter_name):
    check_simulated_run("jpda", 0, filter_name)


def check_simulated_run(associator: str, seed: int, filter_name: str) -> None:
    """A 40-step run of :func:`four_targets` in clutter, checked against the truth.

    Thresholds from the noise: a return is the target's if within the 99.9 % gate of the measurement noise
    (``sqrt(chi2_2(0.999)) sigma``); the tracks must locate the targets better than one measurement does
    (RMS error below ``sigma sqrt(2)``, the 2-D measurement error). False confirmed tracks: a clutter-born
    two-point track has about 0.13 clutter returns in its gate per scan (lambda times the gate area
    pi gamma sqrt(det S), S about 6 R), so confirming 4 of 5 takes about 4 * 0.13^3 ~ 1 % of them: well under
    one false confirmed track per scan on average from the ~3 clutter births of a scan."""
    rng = np.random.default_rng(seed)
    half, clutter = 1000.0, 20.0
    truth, scans = simulate(four_targets(), 40, clutter, half, rng)
    tracker = make_tracker(associator, clutter / (2 * half) ** 2, filter_name)
    near = math.sqrt(gate_gamma(2, 0.999)) * SIGMA
    ids, errors, false_tracks = {}, [], []
    for k, scan in enumerate(scans):
        tracker.step(k, scan)
        confirmed = tracker.confirmed()
        pos = np.array([tracker.kinematic(t)[0][:2] for t in confirmed]).reshape(-1, 2)
        dist = np.linalg.norm(truth[k][:, None, :2] - pos[None], axis=-1)  # (targets, tracks)
        if k < 8:
            continue  # two-point initiation and 4 of 5: confirmed from step 4 on with no miss
        ok = dist.min(axis=1, initial=np.inf) <= near
        nearest = dist.argmin(axis=1) if len(confirmed) else np.zeros(4, dtype=int)
        for target in range(4):
            if ok[target]:
                errors.append(dist[target, nearest[target]])
                ids.setdefault(target, []).append(confirmed[nearest[target]].id)
            else:
                ids.setdefault(target, []).append(None)
        false_tracks.append(int(np.sum(dist.min(axis=0, initial=np.inf) > near)) if len(confirmed) else 0)
    for target in range(4):
        # confirmed within 10 steps of the first (a target may miss early returns), then held >= 90 % of the time
        first = next(k for k, i in enumerate(ids[target]) if i is not None)
        assert first <= 10, f"target {target} confirmed late: {ids[target]}"
        seen = [i for i in ids[target][first:] if i is not None]
        assert len(seen) >= 0.9 * len(ids[target][first:]), f"target {target} lacks a confirmed track: {ids[target]}"
        if target not in CROSSING:
            assert len(set(seen)) == 1, f"target {target} changed track: {ids[target]}"
    for target in CROSSING:  # the crossing pair keeps its two tracks, perhaps swapped
        before, after = ids[target][8], ids[target][-1]  # step 16, before the crossing at 20; the last step
        assert before is not None and after is not None
        assert {before, ids[1 - target][8]} == {after, ids[1 - target][-1]}
    rmse = math.sqrt(np.mean(np.square(errors)))
    assert rmse < SIGMA * math.sqrt(2)
    assert np.mean(false_tracks) < 0.5
    assert len(tracker.confirmed()) >= 4


def test_bad_input_is_refused_with_the_reason():
    tracker = make_tracker("gnn", 1e-5)
    with pytest.raises(ValueError, match="returns: contains NaN"):
        tracker.step(0, Scan(0, 0, np.array([[np.nan, 0.0]]), np.zeros(3), np.eye(2)))
    with pytest.raises(ValueError, match="returns have 3 components"):
        tracker.initiator.from_prior(np.zeros(6), P0, TrackStatus.CONFIRMED)
        tracker.step(0, Scan(0, 0, np.zeros((1, 3)), np.zeros(3), np.eye(3)))
    with pytest.raises(TypeError, match="batched LocalFilter"):
        MultiTargetTracker(object(), make_measurement("point"), make_associator("gnn"), PriorInitiator(),  # type: ignore[arg-type]
                           MissesCovarianceDeleter())
    with pytest.raises(ValueError, match="1 <= M <= N"):
        MOfNConfirmer(4, 3)
    with pytest.raises(ValueError, match="max_misses"):
        MissesCovarianceDeleter(0)
    with pytest.raises(ValueError, match="born deleted"):
        PriorInitiator().from_prior(np.zeros(2), np.eye(2), TrackStatus.DELETED)
    with pytest.raises(ValueError, match="position and velocity indices"):
        TwoPointInitiator(TS, 30.0, P0, (0, 1), (1, 4))
