"""Association of one scan (fusion/multitarget): GNN and JPDA against brute-force enumeration of joint events.

The brute force here is written from the definition (Fortmann, Bar-Shalom & Scheffe 1983): every way of giving
each track at most one gated return, no return to two tracks, weighed by
``prod_{pairs} P_D l_tj / lambda * prod_{missed} (1 - P_D P_G)`` -- the unnormalised textbook form, not the
likelihood ratios the implementation uses.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from zentrack.fusion.filters import make_local_filter
from zentrack.fusion.filters.pdaf_ekf import PdafExtendedKalmanFilter
from zentrack.fusion.linalg import GaussianState
from zentrack.fusion.models import make_measurement, make_plant
from zentrack.fusion.multitarget import ASSOCIATOR_REGISTRY, ScanLikelihood, make_associator
from zentrack.fusion.multitarget.combine import associated_update, mixture_moments
from zentrack.fusion.multitarget.gating import gate_gamma, log_likelihood_ratio, scan_likelihood, track_clusters
from zentrack.fusion.multitarget.gnn import GlobalNearestNeighbour, best_assignment
from zentrack.fusion.multitarget.jpda import JointProbabilisticDataAssociation, enumerate_events
from zentrack.fusion.multitarget.murty import k_best_events
from zentrack.fusion.scan import Scan

P_D, LAM, P_G = 0.85, 0.02, 0.99


def brute_events(gated: np.ndarray) -> list[tuple[int, ...]]:
    """Every joint event (return per track, -1 missed) by itertools."""
    options = [[-1] + list(np.flatnonzero(row)) for row in gated]
    return [e for e in itertools.product(*options) if len([j for j in e if j >= 0]) == len({j for j in e if j >= 0})]


def brute_weight(event, log_lik) -> float:
    """log P(theta) up to a constant, in the textbook form (module docstring)."""
    w = 0.0
    for t, j in enumerate(event):
        w += math.log(P_D) + log_lik[t, j] - math.log(LAM) if j >= 0 else math.log(1.0 - P_D * P_G)
    return w


def brute_marginals(log_lik, gated):
    events = brute_events(gated)
    w = np.array([brute_weight(e, log_lik) for e in events])
    p = np.exp(w - w.max())
    p /= p.sum()
    t, j = gated.shape
    beta, beta0 = np.zeros((t, j)), np.zeros(t)
    for e, pe in zip(events, p):
        for track, ret in enumerate(e):
            if ret >= 0:
                beta[track, ret] += pe
            else:
                beta0[track] += pe
    return beta, beta0, events, p


def random_problem(rng, t, j, density=0.7):
    log_lik = rng.normal(-3.0, 2.0, size=(t, j))
    gated = rng.random((t, j)) < density
    return ScanLikelihood(log_lik, -2.0 * log_lik, gated, 9.0)


@pytest.mark.parametrize("seed", range(40))
def test_gnn_is_the_best_event_of_the_brute_force(seed):
    rng = np.random.default_rng(seed)
    lik = random_problem(rng, int(rng.integers(1, 5)), int(rng.integers(0, 6)))
    event = best_assignment(log_likelihood_ratio(lik.log_lik, P_D, LAM, P_G), lik.gated)
    best = max(brute_weight(e, lik.log_lik) for e in brute_events(lik.gated))
    assert tuple(event) in brute_events(lik.gated)  # a feasible event: gated pairs, no return twice
    assert brute_weight(event, lik.log_lik) == pytest.approx(best, abs=1e-9)
    assoc = GlobalNearestNeighbour(P_D, LAM, P_G).associate(lik)
    want = np.zeros(lik.gated.shape)
    for t, j in enumerate(event):
        if j >= 0:
            want[t, j] = 1.0
    np.testing.assert_array_equal(assoc.beta, want)
    np.testing.assert_array_equal(assoc.beta0, (event < 0).astype(float))


@pytest.mark.parametrize("seed", range(30))
@pytest.mark.parametrize("shape", [(1, 3), (2, 3), (2, 4), (3, 3), (3, 4)])
def test_jpda_marginals_equal_the_brute_force(seed, shape):
    rng = np.random.default_rng(seed)
    lik = random_problem(rng, *shape)
    assoc = JointProbabilisticDataAssociation(P_D, LAM, P_G).associate(lik)
    beta, beta0, _, _ = brute_marginals(lik.log_lik, lik.gated)
    np.testing.assert_allclose(assoc.beta, beta, atol=1e-12)
    np.testing.assert_allclose(assoc.beta0, beta0, atol=1e-12)
    np.testing.assert_allclose(assoc.beta.sum(axis=1) + assoc.beta0, 1.0, atol=1e-12)
    assert np.all(assoc.beta[~lik.gated] == 0.0)


def test_clusters_split_the_tracks_that_share_no_return():
    gated = np.array([[1, 1, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, 0, 1, 0], [0, 0, 0, 0, 0]], dtype=bool)
    lone, clusters = track_clusters(gated)
    np.testing.assert_array_equal(lone, [False, False, True, True])
    assert [(tuple(t), tuple(r)) for t, r in clusters] == [((0, 1), (0, 1))]
    rng = np.random.default_rng(3)
    lik = ScanLikelihood(rng.normal(-3, 2, gated.shape), np.zeros(gated.shape), gated, 9.0)
    assoc = JointProbabilisticDataAssociation(P_D, LAM, P_G).associate(lik)
    beta, beta0, _, _ = brute_marginals(lik.log_lik, gated)  # over all tracks at once: no clustering
    np.testing.assert_allclose(assoc.beta, beta, atol=1e-12)
    np.testing.assert_allclose(assoc.beta0, beta0, atol=1e-12)


@pytest.mark.parametrize("seed", range(20))
def test_clusters_are_the_connected_components_of_the_gate(seed):
    """Against scipy's connected components of the bipartite graph, on random masks and on a chain (track i gates
    returns i and i + 1: one cluster whose least label has to travel its whole length)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(400 + seed)
    t, j = int(rng.integers(1, 30)), int(rng.integers(0, 30))
    gated = rng.random((t, j)) < rng.uniform(0.01, 0.2)
    if seed == 0:
        t, j = 25, 26
        gated = np.zeros((t, j), dtype=bool)
        gated[np.arange(t), np.arange(t)] = gated[np.arange(t)[::-1], np.arange(t)[::-1] + 1] = True
    rows, cols = np.nonzero(gated)
    _, label = connected_components(coo_matrix((np.ones(rows.size), (rows, t + cols)), shape=(t + j, t + j)),
                                    directed=False)
    lone, clusters = track_clusters(gated)
    sizes = np.bincount(label[:t], minlength=label.max() + 1)
    np.testing.assert_array_equal(lone, sizes[label[:t]] == 1)
    expected = sorted((tuple(np.flatnonzero(label[:t] == c)), tuple(np.flatnonzero(label[t:] == c)))
                      for c in np.flatnonzero(sizes >= 2))
    assert [(tuple(a), tuple(b)) for a, b in clusters] == expected  # (in the order of their first track)
    if seed == 0:
        assert len(clusters) == 1 and len(clusters[0][0]) == t


@pytest.mark.parametrize("seed", range(10))
def test_the_k_best_of_separate_clusters_are_the_brute_forces_k_best(seed):
    """A sparse gate (clusters, lone tracks, tracks with no return): the events ranked cluster by cluster and merged
    keeping the k best partial sums are the brute force's k best, best first, each a feasible event."""
    rng = np.random.default_rng(300 + seed)
    lik = random_problem(rng, 6, 7, density=0.25)
    log_ratio = log_likelihood_ratio(lik.log_lik, P_D, LAM, P_G)
    _, _, brute, p = brute_marginals(lik.log_lik, lik.gated)
    k = min(15, len(brute) - 1) if len(brute) > 1 else 1
    events, log_w = k_best_events(log_ratio, lik.gated, k)
    assert len(events) == k and len({tuple(e) for e in events}) == k
    assert all(tuple(e) in set(map(tuple, brute)) for e in events)
    assert np.all(np.diff(log_w) <= 1e-12)
    top = np.sort(p)[::-1][:k]
    np.testing.assert_allclose(np.exp(log_w - log_w[0]), top / top[0], rtol=1e-9)
    for e, w in zip(events, log_w):  # each weight is its event's
        assert w == pytest.approx(sum(log_ratio[i, r] for i, r in enumerate(e) if r >= 0))


@pytest.mark.parametrize("seed", range(10))
def test_murty_ranks_the_events_like_the_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    lik = random_problem(rng, 3, 4, density=0.8)
    log_ratio = log_likelihood_ratio(lik.log_lik, P_D, LAM, P_G)
    events, log_w = k_best_events(log_ratio, lik.gated, 10_000)
    _, _, brute, p = brute_marginals(lik.log_lik, lik.gated)
    assert len(events) == len(brute) and len({tuple(e) for e in events}) == len(brute)
    assert np.all(np.diff(log_w) <= 1e-12)  # best first
    np.testing.assert_allclose(np.exp(log_w - log_w[0]), np.sort(p)[::-1] / p.max(), rtol=1e-9)
    exact = enumerate_events(log_ratio, lik.gated, 10_000)
    assert exact is not None and len(exact[0]) == len(brute)
    assert enumerate_events(log_ratio, lik.gated, len(brute) - 1) is None  # the cap stops the enumeration


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("k", [3, 8, 20])
def test_k_best_marginals_stay_within_the_mass_left_out(seed, k):
    rng = np.random.default_rng(200 + seed)
    lik = random_problem(rng, 3, 4, density=0.9)
    beta, beta0, _, p = brute_marginals(lik.log_lik, lik.gated)
    jpda = JointProbabilisticDataAssociation(P_D, LAM, P_G, max_events=1, k_best=k)
    assoc = jpda.associate(lik)
    assert not jpda.last_exact
    left_out = max(0.0, 1.0 - np.sort(p)[::-1][:k].sum())  # the posterior mass of the events not kept
    assert np.abs(assoc.beta - beta).max() <= left_out + 1e-12
    assert np.abs(assoc.beta0 - beta0).max() <= left_out + 1e-12
    if k >= len(p):
        np.testing.assert_allclose(assoc.beta, beta, atol=1e-12)


def test_jpda_of_one_target_is_the_pdaf_ekf():
    """One track in clutter: the tracker's gating, JPDA and mixture update equal the registered PDAF-EKF."""
    motion, meas = make_plant("cv3d-cd", 1.0, {"q": 0.5}), make_measurement("point")
    gamma = gate_gamma(3, P_G)
    pdaf = PdafExtendedKalmanFilter(motion, meas, gate=gamma, detection_prob=P_D, clutter_density=LAM)
    ekf = make_local_filter("ekf", motion, meas, np.eye(6))
    rng = np.random.default_rng(7)
    prior = GaussianState(rng.normal(size=(1, 6)), np.diag([4.0, 4.0, 4.0, 1.0, 1.0, 1.0])[None])
    returns = prior.mean[0, :3] + rng.normal(scale=5.0, size=(6, 3))
    scan = Scan(0, 0, returns, np.zeros(3), np.eye(3))
    want = pdaf.update(prior, returns[None], np.zeros((1, 1, 3)), np.eye(3)[None])
    lik = scan_likelihood(meas, prior, scan, gamma)
    assoc = JointProbabilisticDataAssociation(P_D, LAM, P_G).associate(lik)
    assert 0 < lik.gated.sum() < 6  # some returns in the gate, some out
    np.testing.assert_allclose(assoc.beta[0], pdaf.last_association.beta[0], atol=1e-12)
    got = associated_update(ekf, prior, scan, assoc)
    np.testing.assert_allclose(got.mean, want.mean, atol=1e-10)
    np.testing.assert_allclose(got.cov, want.cov, atol=1e-10)


def test_a_hard_association_is_the_filters_own_update():
    motion, meas = make_plant("cv3d-cd", 1.0, {"q": 0.5}), make_measurement("point")
    ukf = make_local_filter("ukf", motion, meas, np.eye(6))
    ctx_prior = GaussianState(np.arange(12.0).reshape(2, 6), np.stack([np.eye(6), 2 * np.eye(6)]))
    scan = Scan(0, 0, np.array([[0.5, 1.0, 2.0], [6.0, 7.0, 8.5], [40.0, 0.0, 0.0]]), np.zeros(3), np.eye(3))
    lik = scan_likelihood(meas, ctx_prior, scan, gate_gamma(3, P_G))
    assoc = GlobalNearestNeighbour(P_D, LAM, P_G).associate(lik)
    np.testing.assert_array_equal(assoc.beta, [[1, 0, 0], [0, 1, 0]])
    got = associated_update(ukf, ctx_prior, scan, assoc)
    want = ukf.update(ctx_prior, scan.returns[:2], np.zeros((2, 1, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)))
    np.testing.assert_array_equal(got.mean, want.mean)
    np.testing.assert_array_equal(got.cov, want.cov)
    assert not assoc.unassociated()[:2].any() and assoc.unassociated()[2]


def test_mixture_moments_match_the_samples_of_the_mixture():
    rng = np.random.default_rng(11)
    w = np.array([0.2, 0.5, 0.3])
    means = rng.normal(size=(3, 2)) * 3
    covs = np.stack([np.eye(2) * s for s in (0.5, 1.0, 2.0)])
    got = mixture_moments(w, means, covs, np.zeros(3, dtype=int), 1)
    comp = rng.choice(3, size=400_000, p=w)
    x = means[comp] + rng.standard_normal((comp.size, 2)) * np.sqrt(np.array([0.5, 1.0, 2.0]))[comp, None]
    np.testing.assert_allclose(got.mean[0], x.mean(axis=0), atol=0.02)
    np.testing.assert_allclose(got.cov[0], np.cov(x.T), atol=0.05)


def test_registry_and_bad_parameters():
    assert {"gnn", "jpda"} <= set(ASSOCIATOR_REGISTRY.names())
    assert isinstance(make_associator("jpda", {"k_best": 5}), JointProbabilisticDataAssociation)
    with pytest.raises(ValueError, match="no parameter 'pd'"):
        make_associator("gnn", {"pd": 0.5})
    with pytest.raises(ValueError, match="detection_prob"):
        GlobalNearestNeighbour(detection_prob=0.0)
    with pytest.raises(ValueError, match="clutter_density"):
        GlobalNearestNeighbour(clutter_density=0.0)
    with pytest.raises(ValueError, match="gate_prob"):
        JointProbabilisticDataAssociation(gate_prob=1.0)
    with pytest.raises(ValueError, match="max_events"):
        JointProbabilisticDataAssociation(max_events=0)
    with pytest.raises(ValueError, match="k must be"):
        k_best_events(np.zeros((1, 1)), np.ones((1, 1), bool), 0)
