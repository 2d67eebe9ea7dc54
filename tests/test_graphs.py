"""Graphs and diffusion weights (paper 0 Assumption 4)."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.graphs import (
    check_weights,
    is_connected,
    metropolis_weights,
    radius_adjacency,
    random_geometric_graph,
    ring_adjacency,
    self_weighted,
)


def is_primitive(w: np.ndarray) -> bool:
    return bool(np.all(np.linalg.matrix_power(w, len(w)) > 0))


def test_ring_weights_are_the_papers():
    adj = ring_adjacency(10)
    assert adj.sum(axis=1).tolist() == [2] * 10 and np.array_equal(adj, adj.T)
    w = self_weighted(adj)
    np.testing.assert_allclose(np.diag(w), 0.5)
    assert w[0, 1] == w[0, 9] == 0.25 and w[0, 5] == 0.0
    check_weights(w, adj)
    assert is_primitive(w)


def test_small_rings():
    assert ring_adjacency(1).sum() == 0
    np.testing.assert_allclose(self_weighted(ring_adjacency(1)), [[1.0]])
    np.testing.assert_allclose(self_weighted(ring_adjacency(2)), [[0.5, 0.5], [0.5, 0.5]])


def test_metropolis_weights_are_doubly_stochastic(rng):
    pos, adj = random_geometric_graph(15, 0.45, rng)
    assert is_connected(adj)
    np.testing.assert_array_equal(adj, radius_adjacency(pos, 0.45))
    w = metropolis_weights(adj)
    check_weights(w, adj)
    np.testing.assert_allclose(w, w.T)
    np.testing.assert_allclose(w.sum(axis=0), 1.0)
    assert is_primitive(w)


def test_disconnected_graph_detected():
    adj = np.zeros((4, 4), dtype=bool)
    adj[0, 1] = adj[1, 0] = adj[2, 3] = adj[3, 2] = True
    assert not is_connected(adj)
    with pytest.raises(ValueError, match="no connected"):
        random_geometric_graph(20, 0.01, np.random.default_rng(0), tries=5)


@pytest.mark.parametrize(
    "w, message",
    [
        (np.array([[0.5, 0.6], [0.5, 0.5]]), "row-stochastic"),
        (np.array([[1.2, -0.2], [0.5, 0.5]]), "non-negative"),
        (np.array([[0.0, 1.0], [0.5, 0.5]]), "w_ii > 0"),
        (np.ones((2, 3)) / 3, "square"),
        (np.array([[0.5, 0.5], [np.nan, 0.5]]), "finite"),
    ],
)
def test_check_weights_rejects_bad_weights(w, message):
    with pytest.raises(ValueError, match=message):
        check_weights(w)


def test_check_weights_rejects_weight_on_non_edge():
    w = np.full((3, 3), 1 / 3)
    adj = ring_adjacency(3)
    adj[0, 2] = adj[2, 0] = False
    with pytest.raises(ValueError, match="not neighbours"):
        check_weights(w, adj)
