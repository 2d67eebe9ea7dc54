"""Consensus graphs and weights (zentrack.fusion.consensus_weights): random graphs, centralities against hand-computed
values, Metropolis and centrality weights, SLEM, round counts, Pi^L and the distributed ICI it feeds."""
from __future__ import annotations

import math

import numpy as np
import pytest

from zentrack.fusion.consensus_weights import (
    UNREACHABLE,
    betweenness_centrality,
    centrality_scores,
    centrality_weights,
    closeness_centrality,
    consensus_matrix,
    consensus_rounds,
    degree_centrality,
    graph_diameter,
    metropolis,
    optimal_rounds,
    random_graph,
    rounds_for,
    second_eigenvalue,
    shortest_paths,
    valid_ici_rows,
)
from zentrack.fusion.graphs import check_weights, is_connected, metropolis_weights
from zentrack.fusion.ici import effective_count, ici_from_averages, ici_fuse

inv = np.linalg.inv


def graph(n, edges):
    a = np.zeros((n, n), dtype=bool)
    for i, j in edges:
        a[i, j] = a[j, i] = True
    return a


PATH5 = graph(5, [(0, 1), (1, 2), (2, 3), (3, 4)])
STAR5 = graph(5, [(0, 1), (0, 2), (0, 3), (0, 4)])
CYCLE4 = graph(4, [(0, 1), (1, 2), (2, 3), (3, 0)])


def paper_graphs(count, seed, diameter=None):
    rng = np.random.default_rng(seed)
    return [random_graph(8, 0.3, rng, diameter=diameter) for _ in range(count)]


# ------------------------------------------------------------------------------------------------ graphs


def test_random_graph_is_connected_undirected_with_the_requested_diameter():
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = random_graph(8, 0.3, rng, diameter=4)
        assert a.dtype == bool and a.shape == (8, 8)
        assert np.array_equal(a, a.T) and not np.any(np.diag(a))
        assert is_connected(a) and graph_diameter(a) == 4
    a1 = random_graph(8, 0.3, np.random.default_rng(5))
    a2 = random_graph(8, 0.3, np.random.default_rng(5))
    assert np.array_equal(a1, a2) and is_connected(a1)


def test_random_graph_rejects_impossible_requests():
    rng = np.random.default_rng(2)
    with pytest.raises(ValueError, match="diameter 8"):
        random_graph(8, 0.3, rng, diameter=8)
    with pytest.raises(ValueError, match="complete"):
        random_graph(5, 1.0, rng, diameter=2)
    with pytest.raises(ValueError, match="in 3 draws"):
        random_graph(8, 0.01, rng, tries=3)
    with pytest.raises(ValueError, match="link_prob"):
        random_graph(8, 1.5, rng)
    assert random_graph(1, 0.3, rng).shape == (1, 1)


def test_shortest_paths_and_diameter():
    d = shortest_paths(PATH5)
    np.testing.assert_array_equal(d, np.abs(np.arange(5)[:, None] - np.arange(5)[None, :]))
    assert graph_diameter(PATH5) == 4 and graph_diameter(STAR5) == 2 and graph_diameter(CYCLE4) == 2
    split = graph(4, [(0, 1), (2, 3)])
    assert shortest_paths(split)[0, 2] == UNREACHABLE and shortest_paths(split)[0, 1] == 1
    with pytest.raises(ValueError, match="not connected"):
        graph_diameter(split)
    with pytest.raises(ValueError, match="symmetric"):
        shortest_paths(np.triu(PATH5))


# ------------------------------------------------------------------------------------------ centralities


def test_centralities_of_a_path():
    np.testing.assert_allclose(degree_centrality(PATH5), [1 / 4, 2 / 4, 2 / 4, 2 / 4, 1 / 4])
    # node 1 lies on the shortest paths of {0,2}, {0,3}, {0,4}: 3 of the (4*3)/2 = 6 pairs without it
    np.testing.assert_allclose(betweenness_centrality(PATH5), [0, 3 / 6, 4 / 6, 3 / 6, 0])
    np.testing.assert_allclose(closeness_centrality(PATH5), [4 / 10, 4 / 7, 4 / 6, 4 / 7, 4 / 10])


def test_centralities_of_a_star():
    np.testing.assert_allclose(degree_centrality(STAR5), [1, 1 / 4, 1 / 4, 1 / 4, 1 / 4])
    np.testing.assert_allclose(betweenness_centrality(STAR5), [1, 0, 0, 0, 0])
    np.testing.assert_allclose(closeness_centrality(STAR5), [1, 4 / 7, 4 / 7, 4 / 7, 4 / 7])


def test_betweenness_splits_over_equal_shortest_paths():
    # in a 4-cycle, 0-2 has two shortest paths (via 1 and via 3): each carries half; 3 pairs without the node
    np.testing.assert_allclose(betweenness_centrality(CYCLE4), np.full(4, 0.5 / 3))
    np.testing.assert_allclose(centrality_scores(STAR5), [1, (1 / 4 + 0 + 4 / 7) / 3, ] + [(1 / 4 + 4 / 7) / 3] * 3)
    with pytest.raises(ValueError, match="mix"):
        centrality_scores(STAR5, mix=(0.5, 0.5, 0.5))


# ----------------------------------------------------------------------------------------------- weights


def test_metropolis_is_the_graphs_module_rule():
    a = random_graph(8, 0.3, np.random.default_rng(3))
    np.testing.assert_array_equal(metropolis(a), metropolis_weights(a))


def test_centrality_weights_are_symmetric_doubly_stochastic_on_the_graph():
    for a in paper_graphs(30, seed=4) + [PATH5, STAR5, CYCLE4]:
        w = centrality_weights(a)
        check_weights(w, a)  # row-stochastic, non-negative, w_ii > 0, supported on the graph
        np.testing.assert_allclose(w, w.T, atol=1e-15)
        np.testing.assert_allclose(w.sum(axis=0), 1.0, atol=1e-12)
        assert np.all(np.diag(w) > 0.01)
    a = paper_graphs(1, seed=5)[0]
    np.testing.assert_allclose(centrality_weights(a, gain=0.0, eps=1.0), metropolis_weights(a), atol=1e-15)
    with pytest.raises(ValueError, match="eps"):
        centrality_weights(a, eps=0.0)


def test_centrality_weights_converge_faster_than_metropolis():
    """SLEM over 200 connected G(8, 0.3) graphs (the paper's setting), and over 60 of diameter 4."""
    for graphs, mean_gain in ((paper_graphs(200, seed=2024), 0.015), (paper_graphs(60, seed=7, diameter=4), 0.015)):
        metro = np.array([second_eigenvalue(metropolis(a)) for a in graphs])
        cent = np.array([second_eigenvalue(centrality_weights(a)) for a in graphs])
        assert np.mean(cent < metro) >= 0.95
        assert cent.mean() <= metro.mean() - mean_gain


# ---------------------------------------------------------------------------------------- rounds and SLEM


def test_second_eigenvalue():
    assert second_eigenvalue(np.full((4, 4), 0.25)) == pytest.approx(0.0, abs=1e-12)
    assert second_eigenvalue(np.array([[0.0, 1.0], [1.0, 0.0]])) == pytest.approx(1.0)  # periodic: no consensus
    # the Metropolis weights of a 3-path: eigenvalues 1, 1/2, -1/6 ... SLEM 1/2
    w = metropolis(graph(3, [(0, 1), (1, 2)]))
    assert second_eigenvalue(w) == pytest.approx(max(abs(np.linalg.eigvalsh(w)[:2])))
    general = np.array([[0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])  # circulant, not symmetric
    assert second_eigenvalue(general) == pytest.approx(abs(0.5 + 0.5 * np.exp(2j * np.pi / 3)))


def test_lstar_of_the_paper():
    assert round(rounds_for(0.8343, 8), 2) == 10.74
    assert rounds_for(0.5, 2) == 0.0 and math.isinf(rounds_for(1.0, 8))
    w = metropolis(PATH5)
    assert optimal_rounds(w) == pytest.approx(math.log(4) / math.log(1 / second_eigenvalue(w)))


def test_consensus_rounds_is_ceil_lstar_and_at_least_the_diameter():
    for a in paper_graphs(20, seed=8, diameter=4):
        w = centrality_weights(a)
        lstar = optimal_rounds(w)
        assert consensus_rounds(w, a) == max(math.ceil(lstar), 4)
        assert consensus_rounds(w, a, "box") == max(math.ceil(2 * lstar), 4)
        assert consensus_rounds(w, a, "diameter") == 4
    fast = np.full((5, 5), 0.2)  # one round averages exactly, but information needs 4 hops on the path
    assert consensus_rounds(fast, PATH5) == 4
    with pytest.raises(ValueError, match="mode"):
        consensus_rounds(fast, PATH5, "fastest")


def test_consensus_rows_become_valid_ici_weights_after_lstar_rounds():
    for a in paper_graphs(30, seed=9, diameter=4):
        for w in (metropolis(a), centrality_weights(a)):
            assert valid_ici_rows(w, consensus_rounds(w, a)).all()
            assert valid_ici_rows(w, consensus_rounds(w, a, "box"), condition="box").all()
            assert not valid_ici_rows(w, 1).all()  # one round: weights only on the neighbourhood


@pytest.mark.parametrize("weights", [metropolis, centrality_weights])
def test_consensus_reaches_the_network_average(weights):
    rng = np.random.default_rng(10)
    a = random_graph(8, 0.3, rng, diameter=4)
    w = weights(a)
    values = rng.normal(size=(8, 3))
    np.testing.assert_allclose(consensus_matrix(w, 600) @ values, np.broadcast_to(values.mean(axis=0), (8, 3)),
                               atol=1e-12)
    errors = [np.abs(consensus_matrix(w, rounds) - 1 / 8).max() for rounds in (5, 20, 80)]
    assert errors[0] > errors[1] > errors[2]
    # the error decays at the SLEM rate: ||Pi^L - J||_2 = lambda_2^L for a symmetric Pi
    assert np.linalg.norm(consensus_matrix(w, 20) - 1 / 8, 2) == pytest.approx(second_eigenvalue(w) ** 20)


@pytest.mark.parametrize("weights", [metropolis, centrality_weights])
def test_distributed_ici_at_large_rounds_equals_centralised_uniform_ici(weights):
    """Four consensus variables (Y, y, P, x), Pi^L with large L, then Y_F = N Ybar - (N - 1) Pbar^-1 at every node."""
    rng = np.random.default_rng(11)
    a = random_graph(8, 0.3, rng, diameter=4)
    pi = consensus_matrix(weights(a), 800)
    covs = np.array([(lambda g: g @ g.T + 0.1 * np.eye(4))(rng.normal(size=(4, 4))) for _ in range(8)])
    means = rng.normal(size=(8, 4))
    infos = inv(covs)
    avg = [np.einsum("ij,j...->i...", pi, v) for v in (infos, np.einsum("kij,kj->ki", infos, means), covs, means)]
    pair = ici_from_averages(*avg, 8)
    central = ici_fuse(means, covs)
    for i in range(8):
        np.testing.assert_allclose(inv(pair.matrix[i]), central.cov, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(inv(pair.matrix[i]) @ pair.vector[i], central.mean, rtol=1e-9, atol=1e-10)


def _common_information(rng, n, count):
    c = inv((lambda g: g @ g.T + 1e-3 * np.eye(n))(rng.normal(size=(n, n)) * rng.uniform(0.1, 3.0, size=n)))
    covs = []
    for _ in range(count):
        g = rng.normal(size=(n, int(rng.integers(0, n + 1)))) * 10.0 ** rng.uniform(-2, 1)
        covs.append(inv(g @ g.T + c))
    joint = np.block([[covs[i] if i == j else covs[i] @ c @ covs[j] for j in range(count)] for i in range(count)])
    return np.array(covs), joint


def test_distributed_form_after_finite_rounds_measured_under_common_information():
    """After L = ceil(L*) rounds node i's averages weight estimate j by alpha_ij (row i of Pi^L), and
    Y_F = m sum_j alpha_ij Y_j - (m - 1)(sum_j alpha_ij P_j)^-1 has gains K_j = alpha_ij P_F (m Y_j - (m - 1) Pbar^-1).
    With m = N (the paper) it can underestimate the error covariance; with m = 1 / max_j alpha_ij it did not in
    these (seeded) trials. Documents a measurement, not a theorem."""
    rng = np.random.default_rng(12)
    gaps = {"N": [], "effective": []}
    for _ in range(40):
        a = random_graph(8, 0.3, rng, diameter=4)
        w = centrality_weights(a)
        pi = consensus_matrix(w, consensus_rounds(w, a))
        covs, joint = _common_information(rng, int(rng.integers(1, 4)), 8)
        infos = inv(covs)
        i = int(rng.integers(8))
        alpha = pi[i]
        pbar_inv = inv(np.einsum("j,jkl->kl", alpha, covs))
        for label, m in (("N", 8.0), ("effective", float(effective_count(alpha)))):
            y_f = ici_from_averages(np.einsum("j,jkl->kl", alpha, infos), np.zeros(len(covs[0])),
                                    np.einsum("j,jkl->kl", alpha, covs), np.zeros(len(covs[0])), m).matrix
            p_f = inv(y_f)
            gains = np.hstack([alpha[j] * p_f @ (m * infos[j] - (m - 1) * pbar_inv) for j in range(8)])
            np.testing.assert_allclose(sum(np.split(gains, 8, axis=1)), np.eye(len(p_f)), atol=1e-8)
            gaps[label].append(np.linalg.eigvalsh(p_f - gains @ joint @ gains.T).min() / np.abs(p_f).max())
    assert min(gaps["N"]) < -1e-3 and sum(g < -1e-9 for g in gaps["N"]) >= 5
    assert min(gaps["effective"]) >= -1e-9
