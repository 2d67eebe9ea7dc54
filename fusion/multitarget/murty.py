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
lone track by its returns' ratios, all lone tracks at once), then combined by their regrets: the best event takes each
cluster's best, and the others deviate from it in a few clusters, the least summed regrets first
(:func:`_least_regrets`). Fifty well-apart targets are fifty small problems instead of one with fifty rows
partitioned ``k`` times.
"""
from __future__ import annotations

import heapq

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
    if (gated.sum(axis=0) > 1).any():
        lone, clusters = track_clusters(gated)
    else:  # (no return in two gates: every track is its own cluster)
        lone, clusters = np.ones(t, dtype=bool), []
    base = np.full(t, -1)
    # every lone track's options at once: missed (weight 0) and each gated return, best first per track
    rows, cols = np.nonzero(gated & lone[:, None])
    anyone = np.flatnonzero(lone & gated.any(axis=1))
    opt_row = np.concatenate([rows, anyone])
    opt_col = np.concatenate([cols, np.full(anyone.size, -1)])
    opt_w = np.concatenate([log_ratio[rows, cols], np.zeros(anyone.size)])
    order = np.lexsort((-opt_w, opt_row))
    opt_row, opt_col, opt_w = opt_row[order], opt_col[order], opt_w[order]
    first = np.ones(opt_row.size, dtype=bool)
    first[1:] = opt_row[1:] != opt_row[:-1]
    base[opt_row[first]] = opt_col[first]
    best_w = np.zeros(t)
    best_w[opt_row[first]] = opt_w[first]
    # deviations from the best event: (part, what it sets, regret); a lone track's part is its row
    dev_part = list(opt_row[~first])
    dev_set: list[tuple[Array, Array]] = [(np.array([r]), np.array([c])) for r, c in zip(opt_row[~first], opt_col[~first])]
    dev_regret = list(best_w[opt_row[~first]] - opt_w[~first])
    total = float(best_w.sum())
    for c, (tracks, rets) in enumerate(clusters):
        events, weights = _murty(log_ratio[np.ix_(tracks, rets)], gated[np.ix_(tracks, rets)], k)
        mapped = np.where(events >= 0, rets[np.maximum(events, 0)], -1)
        base[tracks] = mapped[0]
        total += float(weights[0])
        dev_part += [t + c] * (len(weights) - 1)
        dev_set += [(tracks, m) for m in mapped[1:]]
        dev_regret += list(weights[0] - weights[1:])
    chosen = _least_regrets(np.asarray(dev_regret, dtype=float), np.asarray(dev_part, dtype=int), k)
    events = np.tile(base, (len(chosen), 1))
    scores = np.full(len(chosen), total)
    for e, picks in enumerate(chosen):
        for d in picks:
            tracks, sets = dev_set[d]
            events[e, tracks] = sets
            scores[e] -= dev_regret[d]
    return events, scores


def _least_regrets(regret: Array, part: Array, k: int) -> list[tuple[int, ...]]:
    """The ``k`` sets of deviations (at most one per part) of least summed regret, least first, the empty set
    (the best event) first: a best-first walk over the subsets of the ``k - 1`` least regrets (an event with a larger
    one has at least ``k`` events before it: the best and those ``k - 1`` single deviations), each subset reached
    once (extend by the next, or move the last to the next)."""
    if k == 1 or regret.size == 0:
        return [()]
    keep = np.argsort(regret, kind="stable")[: k - 1]
    r, p = regret[keep], part[keep]
    out: list[tuple[int, ...]] = [()]
    heap: list[tuple[float, tuple[int, ...]]] = [(float(r[0]), (0,))]
    while heap and len(out) < k:
        total, idx = heapq.heappop(heap)
        last = idx[-1]
        # (a subset's descendants keep all but its last member: its prefix is valid, or it was never pushed; one
        # whose last member repeats a part is not taken, nor extended, only moved on)
        valid = int(p[last]) not in {int(p[i]) for i in idx[:-1]}
        if valid:
            out.append(tuple(int(keep[i]) for i in idx))
        if last + 1 < r.size:
            if valid:
                heapq.heappush(heap, (total + float(r[last + 1]), (*idx, last + 1)))
            heapq.heappush(heap, (total - float(r[last]) + float(r[last + 1]), (*idx[:-1], last + 1)))
    return out


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
