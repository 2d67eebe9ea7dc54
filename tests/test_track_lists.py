"""A receiver's track lists fused (``zentrack.fusion.track_to_track.lists``): the consistency of fused estimates in
Monte Carlo, one identity per target after one exchange, takeover of the targets a node does not hold, and bad
tracks and lists refused."""
from __future__ import annotations

import numpy as np
import pytest
from track_lists import P4, TARGETS, random_spd, track

from zentrack.fusion.consistency import anees_band
from zentrack.fusion.track_to_track import (
    TrackCluster,
    TrackEstimate,
    TrackId,
    TrackIdIssuer,
    cluster_tracks,
    fuse_track_lists,
    fuse_tracks,
    network_ids,
)


def test_fusing_with_a_rule_computes_that_rules_formula():
    rng = np.random.default_rng(1)
    tracks = [track(0, s, 0, rng.normal(size=4), random_spd(rng, 4)) for s in range(3)]
    infos = [np.linalg.inv(t.cov) for t in tracks]
    mean, cov = fuse_tracks(tracks, "independent")  # the information sum
    np.testing.assert_allclose(cov, np.linalg.inv(sum(infos)), rtol=1e-10)
    np.testing.assert_allclose(mean, cov @ sum(y @ t.mean for y, t in zip(infos, tracks)), rtol=1e-9, atol=1e-12)
    mean, cov = fuse_tracks(tracks, "ci")  # CI with uniform weights
    np.testing.assert_allclose(cov, np.linalg.inv(sum(infos) / 3), rtol=1e-10)
    fast = np.array([1.0 / np.trace(t.cov) for t in tracks])
    fast /= fast.sum()
    mean, cov = fuse_tracks(tracks, "ci-fast")  # Niehsen's weights
    np.testing.assert_allclose(cov, np.linalg.inv(sum(w * y for w, y in zip(fast, infos))), rtol=1e-10)
    _, trace_cov = fuse_tracks(tracks, "ci-trace")
    assert np.trace(trace_cov) <= min(np.trace(cov), *(np.trace(t.cov) for t in tracks)) * (1 + 1e-3)
    mean, cov = fuse_tracks(tracks[:1])
    np.testing.assert_array_equal(mean, tracks[0].mean)
    with pytest.raises(ValueError, match="no track"):
        fuse_tracks([])


@pytest.mark.parametrize("rule", ["ci-fast", "ci-trace", "ci"])
def test_two_nodes_fuse_three_targets_consistently_in_monte_carlo(rule):
    """Each draw: nodes 0 and 1 see the same three targets with independent errors of covariances P_a, P_b
    (different shapes), associate their lists and fuse. The fused estimates are consistent (CI: mean NEES
    below the chi-square band's upper end), better than either node's alone, and every target is associated."""
    rng = np.random.default_rng(7)
    p_a, p_b = np.diag([4.0, 1.0, 0.5, 0.1]), np.diag([1.0, 4.0, 0.1, 0.5])
    nees, sq_fused, sq_a, sq_b = [], 0.0, 0.0, 0.0
    for _ in range(300):
        own = [track(0, 0, i, x + rng.multivariate_normal(np.zeros(4), p_a), p_a) for i, x in enumerate(TARGETS)]
        theirs = [track(0, 1, i, x + rng.multivariate_normal(np.zeros(4), p_b), p_b) for i, x in enumerate(TARGETS)]
        order = rng.permutation(3)  # the neighbour lists its tracks in another order
        result = fuse_track_lists(own, {1: [theirs[j] for j in order]}, rule=rule)
        assert not result.takeovers and not result.renamed
        for i, fused in enumerate(result.tracks):
            err = fused.mean - TARGETS[i]
            nees.append(err @ np.linalg.solve(fused.cov, err))
            sq_fused += err @ err
            sq_a += np.sum((own[i].mean - TARGETS[i]) ** 2)
            sq_b += np.sum((theirs[i].mean - TARGETS[i]) ** 2)
    _, high = anees_band(4, len(nees))
    assert np.mean(nees) <= high
    assert sq_fused < 0.8 * min(sq_a, sq_b)


def test_ci_stays_consistent_where_independent_fusion_does_not():
    """The same test has the power to fail: with errors correlated by a common part, the information sum is
    over-confident (mean NEES past the band), CI is not."""
    rng = np.random.default_rng(8)
    common, own_part = 0.8 * P4, 0.2 * P4
    nees: dict[str, list[float]] = {"independent": [], "ci-fast": []}
    for _ in range(300):
        shared = rng.multivariate_normal(np.zeros(4), common)
        a = track(0, 0, 0, TARGETS[0] + shared + rng.multivariate_normal(np.zeros(4), own_part))
        b = track(0, 1, 0, TARGETS[0] + shared + rng.multivariate_normal(np.zeros(4), own_part))
        for rule in nees:
            mean, cov = fuse_tracks([a, b], rule)
            err = mean - TARGETS[0]
            nees[rule].append(err @ np.linalg.solve(cov, err))
    _, high = anees_band(4, 300)
    assert np.mean(nees["ci-fast"]) <= high < np.mean(nees["independent"])


# ------------------------------------------------------------------------------------------------ identity

def noisy_list(rng, node: int, ids: list[TrackId], targets=TARGETS) -> list[TrackEstimate]:
    return [TrackEstimate(i, x + rng.multivariate_normal(np.zeros(4), P4), P4, "confirmed", 10)
            for i, x in zip(ids, targets)]


def test_three_nodes_agree_on_one_id_per_target_after_one_exchange():
    rng = np.random.default_rng(3)
    ids = {0: [TrackId(4, 0, 0), TrackId(2, 0, 1), TrackId(9, 0, 2)],  # per node, per target
           1: [TrackId(3, 1, 5), TrackId(2, 1, 0), TrackId(1, 1, 7)],
           2: [TrackId(3, 2, 0), TrackId(6, 2, 1), TrackId(1, 2, 0)]}
    lists = {node: noisy_list(rng, node, node_ids) for node, node_ids in ids.items()}
    for node in lists:  # each node lists its tracks in its own order
        lists[node] = [lists[node][j] for j in rng.permutation(3)]
    after = {}
    for node in lists:
        result = fuse_track_lists(lists[node], {j: lists[j] for j in lists if j != node})
        assert not result.takeovers
        after[node] = {t.id: t for t in result.tracks}
        for old, fused in zip(lists[node], result.tracks):
            assert result.renamed.get(old.id, old.id) == fused.id
    for target in range(3):
        oldest = min(ids[node][target] for node in ids)  # born first, then the lower node, then the serial
        for node in ids:
            fused = after[node][oldest]  # every node holds the target under the oldest id
            assert np.linalg.norm(fused.mean[:2] - TARGETS[target, :2]) < 10.0
    assert oldest == TrackId(1, 1, 7)
    # a second exchange changes no id: the network has converged
    for node in after:
        again = fuse_track_lists(list(after[node].values()), {j: list(after[j].values()) for j in after if j != node})
        assert not again.renamed


def test_takeover_gives_a_prior_only_for_the_targets_the_node_does_not_hold():
    rng = np.random.default_rng(4)
    own = noisy_list(rng, 0, [TrackId(5, 0, 0), TrackId(5, 0, 1)], TARGETS[:2])
    b = noisy_list(rng, 1, [TrackId(3, 1, 0), TrackId(3, 1, 1), TrackId(7, 1, 2)])
    c = noisy_list(rng, 2, [TrackId(3, 2, 4), TrackId(6, 2, 9)], TARGETS[1:])
    c.append(TrackEstimate(TrackId(0, 2, 11), np.array([-500.0, 0, 0, 0]), P4, "tentative", 10))  # not taken over
    result = fuse_track_lists(own, {2: c, 1: b})
    assert len(result.tracks) == 2 and len(result.takeovers) == 1
    prior = result.takeovers[0]
    assert prior.id == TrackId(6, 2, 9)  # held by nodes 1 (born 7) and 2 (born 6): the older id
    expected_mean, expected_cov = fuse_tracks([b[2], c[1]])  # both holders' tracks fused
    np.testing.assert_allclose(prior.mean, expected_mean)
    np.testing.assert_allclose(prior.cov, expected_cov)
    assert [t.id for t in result.tracks] == [TrackId(3, 1, 0), TrackId(3, 1, 1)]


def test_a_restarted_node_takes_its_targets_back_under_their_network_ids():
    rng = np.random.default_rng(6)
    neighbour = noisy_list(rng, 1, [TrackId(2, 0, 0), TrackId(2, 1, 3), TrackId(4, 0, 1)])
    result = fuse_track_lists([], {1: neighbour})
    assert not result.tracks
    assert [t.id for t in result.takeovers] == [t.id for t in neighbour]
    for prior, theirs in zip(result.takeovers, neighbour):
        np.testing.assert_array_equal(prior.mean, theirs.mean)


def test_a_node_whose_every_id_is_taken_issues_a_new_one():
    """Clusters as inconsistent associations can leave them: the takeover {V, Y} takes the own track's id Y
    (its V went to an older cluster), so the own track gets a new id; without an issuer that is an error."""
    v, y = TrackId(1, 1, 0), TrackId(2, 0, 0)
    own = track(2, 0, 0, TARGETS[0])
    clusters = [TrackCluster(own), TrackCluster(None, [track(1, 1, 0, TARGETS[1])], [1]),
                TrackCluster(None, [track(1, 1, 0, TARGETS[2]), track(2, 0, 0, TARGETS[2])], [2, 3])]
    assert own.id == y and clusters[1].members[0].id == v
    ids = network_ids(clusters, TrackIdIssuer(0, first_serial=50))
    assert ids == [TrackId(10, 0, 50), v, y]
    with pytest.raises(ValueError, match="issuer"):
        network_ids(clusters)


def test_a_target_reported_twice_under_a_held_id_is_not_taken_over():
    held = track(3, 0, 0, TARGETS[0])
    echo = track(3, 0, 0, TARGETS[1])  # a neighbour lists the own id at another target
    clusters = cluster_tracks([held], {1: [echo]})
    assert len(clusters) == 2 and network_ids(clusters) == [held.id, None]


def test_issued_ids_are_unique_and_a_restart_at_a_later_step_reuses_none():
    first = TrackIdIssuer(3)
    before = {first.issue(step) for step in (0, 0, 5, 9)}
    restarted = TrackIdIssuer(3)
    after = {restarted.issue(step) for step in (10, 10, 12)}
    assert len(before) == 4 and len(after) == 3 and not before & after
    assert sorted([TrackId(2, 9, 9), TrackId(1, 9, 9), TrackId(2, 1, 9), TrackId(2, 1, 3)]) == [
        TrackId(1, 9, 9), TrackId(2, 1, 3), TrackId(2, 1, 9), TrackId(2, 9, 9)]


# ------------------------------------------------------------------------------------------------ bad input

def test_bad_tracks_and_lists_are_refused_naming_what_is_wrong():
    with pytest.raises(ValueError, match="mean has non-finite"):
        track(0, 0, 0, [np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="cov is not symmetric positive definite"):
        track(0, 0, 0, np.zeros(4), np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match=r"\(n,\) and \(n, n\)"):
        track(0, 0, 0, np.zeros(3))
    with pytest.raises(ValueError, match="status"):
        track(0, 0, 0, np.zeros(4), status="deleted")
    a = track(0, 0, 0, TARGETS[0])
    with pytest.raises(ValueError, match="own tracks: duplicate track ids"):
        fuse_track_lists([a, track(0, 0, 0, TARGETS[1])], {})
    with pytest.raises(ValueError, match="node 4's tracks: tracks not at step 10"):
        fuse_track_lists([a], {4: [track(0, 4, 0, TARGETS[0], step=9)]})


def _track(born: int, node: int, serial: int, x: float, var: float = 1.0, step: int = 3) -> TrackEstimate:
    mean = np.array([x, 0.0, 0.0, 0.0, 0.0, 0.0])
    return TrackEstimate(TrackId(born, node, serial), mean, var * np.eye(6), "confirmed", step)


def test_a_second_track_of_a_target_at_its_sender_is_not_taken_over_but_a_second_target_is():

    own = [_track(0, 0, 0, 0.0, var=100.0)]  # a wide own track: it gates both of the sender's tracks below
    duplicate = fuse_track_lists(own, {1: [_track(0, 1, 0, 0.0), _track(1, 1, 1, 0.3)]})
    assert duplicate.takeovers == ()  # the sender's two tracks agree: one target twice
    pair = fuse_track_lists(own, {1: [_track(0, 1, 0, 0.0), _track(1, 1, 1, 12.0)]})
    assert [t.id for t in pair.takeovers] == [TrackId(1, 1, 1)]  # two targets 12 m apart, each with its track


def test_a_new_network_id_is_never_one_a_neighbour_already_sent():

    issuer = TrackIdIssuer(0, first_serial=5)
    own = [_track(3, 0, 0, 0.0), _track(3, 0, 1, 500.0)]
    # a neighbour's track takes own track 0's place first (older id) and carries the id the issuer would give next
    theirs = [_track(1, 1, 0, 0.0), _track(3, 0, 5, 1e4)]
    result = fuse_track_lists(own, {1: theirs}, issuer=issuer)
    ids = [t.id for t in result.tracks] + [t.id for t in result.takeovers]
    assert len(set(ids)) == len(ids)


def test_the_fused_existence_is_the_clusters_average_and_a_bad_one_is_refused():
    """Arithmetic-average fusion of the Bernoulli existences (Li, Hlawatsch & Djurić 2019): a target held by the
    receiver (0.6) and two neighbours (1 and 0.8) exists with 0.8 after the exchange; a takeover with its
    neighbours' average; M-of-N tracks (existence 1) stay at 1."""
    own = [TrackEstimate(TrackId(0, 0, 0), TARGETS[0], P4, "confirmed", 10, 0, existence=0.6)]
    lists = {1: [TrackEstimate(TrackId(0, 1, 0), TARGETS[0], P4, "confirmed", 10, 0, existence=1.0),
                 TrackEstimate(TrackId(0, 1, 1), TARGETS[1], P4, "confirmed", 10, 0, existence=0.9)],
             2: [TrackEstimate(TrackId(0, 2, 0), TARGETS[0], P4, "confirmed", 10, 0, existence=0.8),
                 TrackEstimate(TrackId(0, 2, 1), TARGETS[1], P4, "confirmed", 10, 0, existence=0.7)]}
    result = fuse_track_lists(own, lists)
    assert result.tracks[0].existence == pytest.approx((0.6 + 1.0 + 0.8) / 3)
    assert [t.existence for t in result.takeovers] == [pytest.approx(0.8)]
    assert fuse_track_lists([track(0, 0, 0, TARGETS[0])], {1: [track(0, 1, 0, TARGETS[0])]}).tracks[0].existence == 1.0
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="existence .* is not a probability in"):
            TrackEstimate(TrackId(0, 0, 0), TARGETS[0], P4, existence=bad)
