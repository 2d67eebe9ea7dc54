"""The k best joint events of a scan by Murty's ranking of assignments.

Murty (1968, "An algorithm for ranking all the assignments in order of increasing cost") partitions the
solutions left after the best one ``a* = (c_0, ..., c_{T-1})`` into ``T`` disjoint sub-problems: the ``i``-th
forces rows ``0..i-1`` to ``a*``'s columns and forbids ``(i, c_i)``. The best solution of each sub-problem
goes into a priority queue; the next best assignment overall is the cheapest in the queue, and it is
partitioned the same way (Cox & Miller 1995 for its use in multi-target tracking). On the cost matrix of
:func:`~zentrack.fusion.multitarget.gnn.assignment_cost` every assignment is one joint event (a track's miss is
its own dummy column), so the ``k`` cheapest assignments are the ``k`` most likely events.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

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
    (return per track, -1 missed) and their log weights ``sum log a`` ``(E,)``."""
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
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
