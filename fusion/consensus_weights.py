"""Graphs and weights for L-round average consensus (paper 2 Section 3, "parallel consensus iteration"): the
mathematics the consensus rules of :mod:`zentrack.fusion.rules.consensus` (and the scenarios' graphs) are built on.

Every node holds a variable ``v_i``; one round replaces it by ``sum_j pi_ij v_j`` over itself and its neighbours,
so after L rounds node i holds ``sum_j (Pi^L)_ij v_j`` (paper 2 eqs. 52-53). With a symmetric, doubly stochastic
``Pi`` with positive diagonal on a connected graph, ``Pi^L -> 1 1^T / N`` (Xiao & Boyd, "Fast linear iterations
for distributed averaging", 2003; paper 2 Lemma 1) at the rate of the second largest eigenvalue modulus (SLEM).

This module holds:

- random connected graphs with a prescribed diameter (the paper's setting: N = 8, link probability 0.3,
  diameter 4), hop distances and the diameter;
- node centralities: degree, betweenness (Brandes 2001) and closeness;
- consensus weights: Metropolis (Xiao, Boyd & Lall 2005) and the paper's centrality-based weights (whose formula
  was lost in the text dump; :func:`centrality_weights` documents the construction used here);
- the number of rounds: ``L* = ln(N - 1) / ln(1 / lambda_2)`` (paper 2 Lemma 3), at least the diameter
  (paper 2 Remark 5), and a per-row check that ``Pi^L`` gives valid ICI weights (see :mod:`zentrack.fusion.ici`).

All graphs are undirected adjacency matrices ``(n, n)`` of bools without self loops.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from .graphs import metropolis_weights
from .ici import ici_weights_valid

Array = np.ndarray

#: hop count :func:`shortest_paths` reports for a pair of nodes that are not connected
UNREACHABLE = -1

__all__ = [
    "UNREACHABLE", "betweenness_centrality", "centrality_scores", "centrality_weights", "closeness_centrality",
    "consensus_matrix", "consensus_rounds", "degree_centrality", "graph_diameter", "metropolis",
    "optimal_rounds", "random_graph", "rounds_for", "second_eigenvalue", "shortest_paths", "valid_ici_rows",
]


def _adjacency(adj: Array) -> Array:
    """Validate and return an undirected adjacency matrix as bools (symmetric, no self loops)."""
    a = np.asarray(adj)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] < 1:
        raise ValueError(f"an adjacency matrix must be square with at least one node, got shape {a.shape}")
    if a.dtype != bool:
        if not np.all(np.isfinite(a)):
            raise ValueError("the adjacency matrix has non-finite entries")
        a = a != 0
    if np.any(a != a.T):
        raise ValueError("the adjacency matrix must be symmetric (undirected graph)")
    if np.any(np.diag(a)):
        raise ValueError("the adjacency matrix must not have self loops")
    return a


# --------------------------------------------------------------------------------------------------- graphs


def shortest_paths(adj: Array) -> Array:
    """Hop counts ``d(i, j)`` of the undirected graph ``(n, n)`` (ints), ``UNREACHABLE`` (-1) between components.

    All sources at once by level-synchronous breadth-first search: level k adds the nodes one edge away from
    level k - 1 that were not reached before.
    """
    a = _adjacency(adj)
    n = a.shape[0]
    dist = np.full((n, n), UNREACHABLE, dtype=int)
    np.fill_diagonal(dist, 0)
    seen = np.eye(n, dtype=bool)
    frontier = np.eye(n, dtype=bool)
    a_int = a.astype(np.int64)
    for level in range(1, n):
        frontier = ((frontier.astype(np.int64) @ a_int) > 0) & ~seen
        if not frontier.any():
            break
        dist[frontier] = level
        seen |= frontier
    return dist


def graph_diameter(adj: Array) -> int:
    """The largest hop count between two nodes; ValueError if the graph is not connected (infinite diameter)."""
    dist = shortest_paths(adj)
    if np.any(dist == UNREACHABLE):
        raise ValueError("the graph is not connected: its diameter is infinite")
    return int(dist.max())


def random_graph(n: int, link_prob: float, rng: np.random.Generator, diameter: int | None = None,
                 tries: int = 10000) -> Array:
    """A random undirected graph G(n, p) that is connected and, if ``diameter`` is given, has exactly it.

    Each of the ``n (n - 1) / 2`` node pairs is linked independently with probability ``link_prob``; graphs are
    drawn until one qualifies (the paper: n = 8, p = 0.3, diameter 4). ValueError when the request is
    impossible (``diameter`` outside ``[1, n - 1]`` for n > 1, or not 0 for n = 1; ``link_prob`` 0 with n > 1)
    or nothing qualified in ``tries`` draws. Returns an ``(n, n)`` bool matrix, symmetric, no self loops.
    """
    if n < 1:
        raise ValueError(f"a graph needs at least one node, got n = {n}")
    if not (0.0 <= link_prob <= 1.0) or not math.isfinite(link_prob):
        raise ValueError(f"link_prob must be in [0, 1], got {link_prob}")
    if tries < 1:
        raise ValueError(f"tries must be at least 1, got {tries}")
    if diameter is not None:
        lo, hi = (0, 0) if n == 1 else (1, n - 1)
        if not (lo <= diameter <= hi):
            raise ValueError(f"no graph on {n} nodes has diameter {diameter} (possible: {lo} to {hi})")
        if n > 1 and link_prob == 1.0 and diameter != 1:
            raise ValueError(f"with link_prob = 1 every graph is complete (diameter 1), not {diameter}")
    if n > 1 and link_prob == 0.0:
        raise ValueError("with link_prob = 0 no graph on more than one node is connected")
    upper = np.triu(np.ones((n, n), dtype=bool), k=1)
    for _ in range(tries):
        a = (rng.uniform(size=(n, n)) < link_prob) & upper
        a = a | a.T
        dist = shortest_paths(a)
        if np.any(dist == UNREACHABLE):
            continue
        if diameter is None or int(dist.max()) == diameter:
            return a
    what = "connected" + ("" if diameter is None else f" with diameter {diameter}")
    raise ValueError(f"no {what} random graph with n = {n}, link_prob = {link_prob} in {tries} draws")


# ---------------------------------------------------------------------------------------------- centralities


def degree_centrality(adj: Array) -> Array:
    """``d_i / (n - 1)``: the share of the other nodes a node is linked to (zeros for a single node)."""
    a = _adjacency(adj)
    n = a.shape[0]
    return a.sum(axis=1) / (n - 1) if n > 1 else np.zeros(1)


def betweenness_centrality(adj: Array) -> Array:
    """Betweenness of each node, ``sum_{s < t, s, t != v} sigma_st(v) / sigma_st`` over unordered pairs, divided
    by the number of such pairs ``(n - 1)(n - 2) / 2`` (so it lies in [0, 1]; zeros when n < 3).

    ``sigma_st`` counts the shortest s-t paths and ``sigma_st(v)`` those through v. Brandes' algorithm
    (U. Brandes, "A faster algorithm for betweenness centrality", J. Math. Sociology 25(2), 2001): a breadth-first
    search from every source s counts shortest paths, then dependencies
    ``delta_s(v) = sum_{w: v in pred(w)} sigma_sv / sigma_sw (1 + delta_s(w))`` are accumulated in order of
    decreasing distance; the sum over sources counts each unordered pair twice, hence the halving.
    """
    a = _adjacency(adj)
    n = a.shape[0]
    neighbours = [np.flatnonzero(a[i]) for i in range(n)]
    bc = np.zeros(n)
    for s in range(n):
        order: list[int] = []
        preds: list[list[int]] = [[] for _ in range(n)]
        sigma = np.zeros(n)
        sigma[s] = 1.0
        dist = np.full(n, -1)
        dist[s] = 0
        queue = deque([s])
        while queue:
            v = queue.popleft()
            order.append(v)
            for u in neighbours[v]:
                if dist[u] < 0:
                    dist[u] = dist[v] + 1
                    queue.append(int(u))
                if dist[u] == dist[v] + 1:
                    sigma[u] += sigma[v]
                    preds[u].append(v)
        delta = np.zeros(n)
        for w in reversed(order):
            for v in preds[w]:
                delta[v] += sigma[v] / sigma[w] * (1.0 + delta[w])
            if w != s:
                bc[w] += delta[w]
    bc /= 2.0  # undirected: every unordered pair {s, t} was counted from s and from t
    pairs = (n - 1) * (n - 2) / 2.0
    return bc / pairs if pairs > 0 else np.zeros(n)


def closeness_centrality(adj: Array) -> Array:
    """``(n - 1) / sum_j d(i, j)``: the inverse mean hop distance to the other nodes (ValueError if the graph is
    not connected; zeros for a single node)."""
    dist = shortest_paths(adj)
    n = dist.shape[0]
    if np.any(dist == UNREACHABLE):
        raise ValueError("closeness centrality needs a connected graph")
    if n == 1:
        return np.zeros(1)
    return (n - 1) / dist.sum(axis=1)


def centrality_scores(adj: Array, mix: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)) -> Array:
    """The per-node score ``c_i = mix . (D_i / max D, B_i / max B, C_i / max C)`` in [0, 1].

    Degree, betweenness and closeness centrality are each brought to [0, 1] by dividing by their largest value
    over the graph (a centrality that is zero everywhere, e.g. betweenness of a complete graph, stays zero), then
    combined with the non-negative ``mix`` coefficients, which must sum to one (paper 2 Section 3.1: "transforming
    the above centrality to the same interval", weight coefficients summing to one).
    """
    m = np.asarray(mix, dtype=float)
    if m.shape != (3,) or not np.all(np.isfinite(m)) or np.any(m < 0) or abs(m.sum() - 1.0) > 1e-9:
        raise ValueError(f"mix must be three non-negative coefficients summing to 1, got {mix}")
    parts = np.stack([degree_centrality(adj), betweenness_centrality(adj), closeness_centrality(adj)])
    top = parts.max(axis=1, keepdims=True)
    scaled = np.divide(parts, top, out=np.zeros_like(parts), where=top > 0)
    return m @ scaled


# ------------------------------------------------------------------------------------------------- weights


def metropolis(adj: Array) -> Array:
    """Metropolis weights ``pi_ij = 1 / (1 + max(d_i, d_j))`` (re-export of :func:`graphs.metropolis_weights`)."""
    return metropolis_weights(_adjacency(adj))


#: default constants of :func:`centrality_weights` (chosen by the SLEM measurements in its docstring)
CENTRALITY_GAIN = 2.0
CENTRALITY_EPS = 0.5


def centrality_weights(adj: Array, mix: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3),
                       gain: float = CENTRALITY_GAIN, eps: float = CENTRALITY_EPS) -> Array:
    """Consensus weights from node centralities (paper 2 Section 3.1; its formula was lost, this is a design).

    Metropolis weights ``1 / (1 + max(d_i, d_j))`` only use the degree; the paper replaces it by a combination of
    degree, betweenness and closeness centrality. Construction:

    1. per-node score ``c_i`` in [0, 1] (:func:`centrality_scores` with ``mix``);
    2. edge strength ``e_ij = 1 + gain (c_i + c_j) / 2`` on every edge (1 between two nodes of score 0, up to
       ``1 + gain`` between two nodes of score 1): edges between central nodes, the bottlenecks that carry the
       traffic between the parts of the graph, get more weight;
    3. node strength ``s_i = sum_k e_ik`` (the degree when ``gain = 0``);
    4. ``pi_ij = e_ij / (eps + max(s_i, s_j))`` on edges, ``pi_ii = 1 - sum_j pi_ij``, zero elsewhere.

    With ``gain = 0`` and ``eps = 1`` this is Metropolis. The matrix is symmetric (``e_ij = e_ji``) with rows summing
    to one, so doubly stochastic, supported on the graph, and its diagonal is strictly positive for every
    ``eps > 0``: ``sum_j pi_ij <= sum_j e_ij / (eps + s_i) = s_i / (eps + s_i) < 1``.

    The defaults (``gain = 2``, ``eps = 0.5``) were chosen by the second largest eigenvalue modulus (SLEM) over
    connected G(8, 0.3) graphs (the paper's setting; the seeded draws of ``tests/test_consensus_weights.py``): on 200
    graphs mean SLEM 0.854 against 0.874 for Metropolis, smaller on all 200 (largest ratio 0.991), mean rounds
    ``max(ceil(L*), diameter)`` 15.5 against 18.7; on 100 graphs of diameter 4, 0.872 against 0.892 (100 of 100). Most of the gain comes from
    ``eps < 1`` (``gain = 0, eps = 0.5``: 0.859), the centrality strength adds the rest; a numerically optimised
    symmetric weight matrix (fastest distributed averaging, Xiao & Boyd 2003) reaches about 0.825 on such graphs.
    Smaller ``eps`` speeds up a little more but lets diagonals approach 0 (and the SLEM approach 1 on bipartite
    graphs).
    """
    a = _adjacency(adj)
    if not (math.isfinite(gain) and gain >= 0):
        raise ValueError(f"gain must be finite and non-negative, got {gain}")
    if not (math.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be finite and positive (it keeps the diagonal positive), got {eps}")
    c = centrality_scores(a, mix)
    strength = np.where(a, 1.0 + gain * 0.5 * (c[:, None] + c[None, :]), 0.0)
    s = strength.sum(axis=1)
    w = strength / (eps + np.maximum(s[:, None], s[None, :]))
    np.fill_diagonal(w, 0.0)
    np.fill_diagonal(w, 1.0 - w.sum(axis=1))
    return w


# --------------------------------------------------------------------------------------------------- rounds


def second_eigenvalue(weights: Array) -> float:
    """Second largest eigenvalue modulus (SLEM) of a stochastic weight matrix: the largest ``|lambda|`` after
    removing one eigenvalue 1 (the consensus rate, Xiao & Boyd 2003). Symmetric matrices use ``eigvalsh``;
    general ones ``eigvals`` (sorted by modulus, the largest, i.e. the eigenvalue 1, dropped)."""
    w = np.asarray(weights, dtype=float)
    if w.ndim != 2 or w.shape[0] != w.shape[1]:
        raise ValueError(f"weights must be a square matrix, got shape {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ValueError("weights have non-finite entries")
    if w.shape[0] == 1:
        return 0.0
    if np.allclose(w, w.T, rtol=0.0, atol=1e-12):
        lam = np.linalg.eigvalsh(0.5 * (w + w.T))  # ascending; lam[-1] = 1 for a stochastic matrix
        return float(max(abs(lam[0]), abs(lam[-2])))
    mod = np.sort(np.abs(np.linalg.eigvals(w)))
    return float(mod[-2])


def rounds_for(lambda2: float, n: int) -> float:
    """``L* = ln(N - 1) / ln(1 / lambda_2)`` (paper 2 Lemma 3): after ``L >= L*`` rounds every row of ``Pi^L``
    satisfies ``sum alpha^2 <= 1 / (N - 1)`` (the paper: lambda = 0.8343, N = 8 gives 10.74).

    The rows of ``Pi^L`` approach ``1 / N`` as ``||alpha - 1/N|| <= lambda^L ||e_i - 1/N||``, and
    ``sum alpha^2 = 1/N + ||alpha - 1/N||^2``. Returns 0 for N <= 2 (every convex weight is valid) or
    lambda_2 = 0, ``inf`` for lambda_2 >= 1 (no consensus).
    """
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    if not (math.isfinite(lambda2) and lambda2 >= 0):
        raise ValueError(f"lambda2 must be finite and non-negative, got {lambda2}")
    if n <= 2 or lambda2 == 0.0:
        return 0.0
    if lambda2 >= 1.0:
        return math.inf
    return math.log(n - 1) / math.log(1.0 / lambda2)


def optimal_rounds(weights: Array) -> float:
    """:func:`rounds_for` of the weights' SLEM and size."""
    w = np.asarray(weights, dtype=float)
    return rounds_for(second_eigenvalue(w), w.shape[0])


def consensus_rounds(weights: Array, adj: Array, mode: str = "lstar") -> int:
    """Rounds to run: ``ceil(L*)`` and at least the graph's diameter (paper 2 Remark 5 and Lemma 3).

    ``mode``: ``"lstar"`` (the paper: ``L* = ln(N - 1) / ln(1 / lambda_2)``), ``"box"`` (``2 L*``, enough for
    every row of ``Pi^L`` to satisfy ``alpha_i <= 1 / (N - 1)``, the condition under which multi-estimate ICI is
    consistent for every common-information correlation, see :mod:`zentrack.fusion.ici`), ``"diameter"`` (the
    diameter only). ValueError if the graph is disconnected or ``lambda_2 >= 1`` (no finite number suffices).
    """
    diam = graph_diameter(adj)
    if mode == "diameter":
        return diam
    if mode not in ("lstar", "box"):
        raise ValueError(f"mode must be 'lstar', 'box' or 'diameter', got {mode!r}")
    lstar = optimal_rounds(weights)
    if not math.isfinite(lstar):
        raise ValueError("the weights do not converge (second eigenvalue modulus >= 1): no finite round count")
    if mode == "box":
        lstar *= 2.0
    return max(int(math.ceil(lstar - 1e-12)), diam)


def consensus_matrix(weights: Array, rounds: int) -> Array:
    """``Pi^L``: row i holds the weights node i's consensus variable gives every node's initial value."""
    w = np.asarray(weights, dtype=float)
    if rounds < 0:
        raise ValueError(f"rounds must be non-negative, got {rounds}")
    return np.linalg.matrix_power(w, int(rounds))


def valid_ici_rows(weights: Array, rounds: int, condition: str = "ball", tol: float = 1e-9) -> Array:
    """Per row of ``Pi^L``: whether it is a valid multi-estimate ICI weight vector.

    ``condition="ball"``: the paper's ``sum alpha = 1, alpha >= 0, sum alpha^2 <= 1 / (N - 1)``;
    ``"box"``: also ``alpha_i <= 1 / (N - 1)`` (see :func:`zentrack.fusion.ici.check_ici_weights`).
    """
    return ici_weights_valid(consensus_matrix(weights, rounds), condition=condition, tol=tol)
