"""Communication graphs and diffusion weights (row-stochastic, w_ii > 0; paper 0 Assumption 4)."""
from __future__ import annotations

import numpy as np

Array = np.ndarray


def ring_adjacency(m: int) -> Array:
    """Undirected ring: node i talks to i-1 and i+1 (mod m). No self loops."""
    if m < 1:
        raise ValueError("a graph needs at least one node")
    adj = np.zeros((m, m), dtype=bool)
    for i in range(m):
        for j in ((i - 1) % m, (i + 1) % m):
            if j != i:
                adj[i, j] = True
    return adj


def radius_adjacency(positions: Array, radius: float) -> Array:
    """Link nodes whose positions ``(m, d)`` are at most ``radius`` apart."""
    pos = np.asarray(positions, dtype=float)
    dist = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
    return (dist <= radius) & ~np.eye(len(pos), dtype=bool)


def random_geometric_graph(m: int, radius: float, rng: np.random.Generator, dim: int = 2, tries: int = 1000):
    """Draw ``m`` points uniformly in the unit cube until the radius graph is connected.

    Returns ``(positions, adjacency)``.
    """
    for _ in range(tries):
        pos = rng.uniform(size=(m, dim))
        adj = radius_adjacency(pos, radius)
        if is_connected(adj):
            return pos, adj
    raise ValueError(f"no connected random geometric graph with m={m}, radius={radius} in {tries} draws")


def is_connected(adj: Array) -> bool:
    """Breadth-first reachability from node 0 over the undirected graph."""
    m = adj.shape[0]
    seen = np.zeros(m, dtype=bool)
    seen[0] = True
    frontier = [0]
    while frontier:
        i = frontier.pop()
        for j in np.flatnonzero(adj[i] | adj[:, i]):
            if not seen[j]:
                seen[j] = True
                frontier.append(int(j))
    return bool(seen.all())


def self_weighted(adj: Array, self_weight: float = 0.5) -> Array:
    """w_ii = ``self_weight``, the rest split equally over neighbours (the paper's ring: 0.5 / 0.25 / 0.25)."""
    adj = np.asarray(adj, dtype=bool)
    deg = adj.sum(axis=1)
    w = np.where(adj, (1.0 - self_weight) / np.maximum(deg, 1)[:, None], 0.0)
    np.fill_diagonal(w, np.where(deg > 0, self_weight, 1.0))
    return w


def metropolis_weights(adj: Array) -> Array:
    """Metropolis-Hastings weights: w_ij = 1 / (1 + max(d_i, d_j)) on edges, w_ii = 1 - sum_j w_ij."""
    adj = np.asarray(adj, dtype=bool)
    adj = adj | adj.T
    deg = adj.sum(axis=1)
    w = np.where(adj, 1.0 / (1.0 + np.maximum(deg[:, None], deg[None, :])), 0.0)
    np.fill_diagonal(w, 1.0 - w.sum(axis=1))
    return w


def check_weights(weights: Array, adj: Array | None = None) -> None:
    """Raise ValueError unless weights are row-stochastic, non-negative, w_ii > 0 and respect ``adj``."""
    w = np.asarray(weights, dtype=float)
    if w.ndim != 2 or w.shape[0] != w.shape[1]:
        raise ValueError(f"weights must be square, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    if not np.allclose(w.sum(axis=1), 1.0, atol=1e-9):
        raise ValueError("weights must be row-stochastic (each row sums to 1)")
    if np.any(np.diag(w) <= 0):
        raise ValueError("every node must give itself a positive weight (w_ii > 0)")
    if adj is not None:
        off = w.copy()
        np.fill_diagonal(off, 0.0)
        if np.any((off > 0) & ~np.asarray(adj, dtype=bool)):
            raise ValueError("a positive weight sits on a pair of nodes that are not neighbours")
    unreached = unreachable(w > 0)
    if unreached:
        raise ValueError(f"the weights' graph is not strongly connected (node(s) {unreached} and node 0 cannot "
                         "both reach each other), so the weights are not primitive: diffusion needs every node's "
                         "information to reach every other node")


def unreachable(links: Array) -> list[int]:
    """The nodes that node 0 cannot reach or that cannot reach node 0 along the directed ``links`` ``(M, M)``
    (``links[i, j]``: i hears j); empty for a strongly connected graph. With positive self weights, weights on a
    strongly connected graph are primitive (irreducible and aperiodic), as diffusion and consensus need."""
    links = np.asarray(links, dtype=bool)

    def reach(adj: Array) -> Array:
        seen = np.zeros(adj.shape[0], dtype=bool)
        seen[0], frontier = True, [0]
        while frontier:
            for j in np.flatnonzero(adj[frontier.pop()]):
                if not seen[j]:
                    seen[j] = True
                    frontier.append(int(j))
        return seen

    if links.shape[0] == 0:
        return []
    return [int(i) for i in np.flatnonzero(~(reach(links) & reach(links.T)))]


def within_hops(adj: Array, hops: int) -> Array:
    """The nodes each node reaches in 1..``hops`` links (itself excluded), as a boolean adjacency."""
    a = np.asarray(adj) != 0
    reach = a.copy()
    for _ in range(hops - 1):
        reach = reach | ((reach.astype(int) @ a.astype(int)) > 0)
    np.fill_diagonal(reach, False)
    return reach
