"""The k best joint events of a scan by Murty's ranking of assignments.

Murty (1968, "An algorithm for ranking all the assignments in order of increasing cost") partitions the
solutions left after the best one ``a* = (c_0, ..., c_{T-1})`` into ``T`` disjoint sub-problems: the ``i``-th
forces rows ``0..i-1`` to ``a*``'s columns and forbids ``(i, c_i)``. The best solution of each sub-problem
goes into a priority queue; the next best assignment overall is the cheapest in the queue, and it is
partitioned the same way (Cox & Miller 1995 for its use in multi-target tracking). On the cost matrix of
:func:`~zentrack.fusion.multitarget.gnn.assignment_cost` every assignment is one joint event (a track's miss is
its own dummy column), so the ``k`` cheapest assignments are the ``k`` most likely events.

Tracks that share no gated return are independent: an event is one choice per cluster of the gate mask
(:func:`~zentrack.fusion.multitarget.gating.track_clusters`) and its weight the sum of theirs, so the ``k`` best
events are the ``k`` best sums of the clusters' ``k`` best (each cluster ranked by Murty on its own small matrix, a
lone track by its returns' ratios; merged one cluster at a time, keeping the ``k`` best partial sums, which holds
every prefix of the ``k`` best). Fifty well-apart targets are fifty small problems instead of one with fifty rows
partitioned ``k`` times.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from .gating import track_clusters
from .gnn import assignment_cost, event_of_columns

Array = np.ndarray


def _solve(cost: Array) -> tuple[float, Array] | None:
    """The cheapest complete assignment of rows (total, column per row), None if every one costs inf."""
    try:
        rows, cols = linear_sum_assignment(cost)
    except ValueError:  # "cost matrix is infeasible"
        return None
    total = float(cost[rows, cols].sum())
    return (total, cols) if np.isfinite(total) else None


def k_best_events(log_ratio: Array, gated: Array, k: int) -> tuple[Array, Array]:
    """The ``k`` most likely joint events (fewer if there are fewer), best first: ``events`` ``(E, T)``
    (return per track, -1 missed) and their log weights ``sum log a`` ``(E,)``; cluster by cluster (module
    docstring)."""
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    t = gated.shape[0]
    lone, clusters = track_clusters(gated)
    parts: list[tuple[Array, Array, Array]] = []  # (tracks, their events in the scan's columns, log weights)
    for i in np.flatnonzero(lone & gated.any(axis=1)):
        cols = np.flatnonzero(gated[i])
        weights = np.concatenate([[0.0], log_ratio[i, cols]])
        order = np.argsort(-weights, kind="stable")[:k]
        parts.append((np.array([i]), np.concatenate([[-1], cols])[order][:, None], weights[order]))
    for tracks, rets in clusters:
        events, weights = _murty(log_ratio[np.ix_(tracks, rets)], gated[np.ix_(tracks, rets)], k)
        parts.append((tracks, np.where(events >= 0, rets[np.maximum(events, 0)], -1), weights))
    scores, picks = np.zeros(1), np.zeros((1, 0), dtype=int)
    for _, _, weights in parts:  # the k best partial sums, one cluster more each time
        total = (scores[:, None] + weights[None, :]).ravel()
        best = np.argsort(-total, kind="stable")[:k]
        scores = total[best]
        picks = np.column_stack([picks[best // weights.size], best % weights.size])
    events = np.full((scores.size, t), -1)
    for p, (tracks, chosen, _) in enumerate(parts):
        events[:, tracks] = chosen[picks[:, p]]
    return events, scores


def _murty(log_ratio: Array, gated: Array, k: int) -> tuple[Array, Array]:
    """:func:`k_best_events` of one cluster, by Murty's ranking on its whole matrix (module docstring)."""
    t, j = gated.shape
    cost = assignment_cost(log_ratio, gated)
    first = _solve(cost)
    if first is None:  # cannot happen: the all-missed event is always finite
        raise ValueError("no finite assignment")
    # the queue of sub-problems: their best cost, and (columns, cost matrix, first row still free) apart
    costs: list[float] = [first[0]]
    nodes: list[tuple[Array, Array, int]] = [(first[1], cost, 0)]
    events: list[Array] = []
    log_w: list[float] = []
    while costs and len(events) < k:
        best = int(np.argmin(costs))  # pop the cheapest (swap with the last, then drop it)
        total, (cols, node, fixed) = costs[best], nodes[best]
        costs[best], nodes[best] = costs[-1], nodes[-1]
        costs.pop()
        nodes.pop()
        events.append(event_of_columns(cols, j))
        log_w.append(-total)
        forced = node.copy()
        for i in range(fixed, t):
            child = forced.copy()
            child[i, cols[i]] = np.inf
            solved = _solve(child)
            if solved is not None:
                costs.append(solved[0])
                nodes.append((solved[1], child, i))
            keep = forced[i, cols[i]]  # force row i onto cols[i] for the next sub-problems (which
            forced[i, :] = np.inf  # keeps every other row off that column)
            forced[i, cols[i]] = keep
    return np.array(events, dtype=int).reshape(-1, t), np.array(log_w)
