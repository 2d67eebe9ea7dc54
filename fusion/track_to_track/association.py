"""Association of two track lists: the CI-bound distance of two tracks, its cheap necessary screens, and the gated
assignment that takes the most gated pairs, then the smallest sum of distances (package docstring)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..defaults import DEFAULT_GATE
from ..gate import ci_gate_statistic, ci_gate_statistics, gate_threshold
from .tracks import TrackEstimate

Array = np.ndarray


def track_distance(a: TrackEstimate, b: TrackEstimate) -> float:
    """The association distance of two tracks: :func:`~zentrack.fusion.gate.ci_gate_statistic` (module
    docstring)."""
    return ci_gate_statistic(a.mean, a.cov, b.mean, b.cov)


def sum_distance(own: Sequence[TrackEstimate], other: Sequence[TrackEstimate]) -> Array:
    """``m2 = d^T (P_a + P_b)^-1 d`` for every pair ``(own[i], other[j])``, ``(len(own), len(other))``: the
    squared Mahalanobis distance as if the errors were independent, a cheap screen for the CI gate. The gate
    passes only if ``m2 <= 2^n * threshold``: its ``omega = 1/2`` bound is ``2 (P_a + P_b)``, and its
    smallest-volume bound ``B(omega*)`` is at most ``2^n (P_a + P_b)``. (In the basis of
    :mod:`~zentrack.fusion.gate`, ``B`` has eigenvalues ``s_i = 1/omega + lam_i/(1 - omega) >= 1 + lam_i``, and
    ``sum_i log s_i(omega*) <= sum_i log s_i(1/2) = sum_i log 2 (1 + lam_i)``, so each
    ``s_j(omega*) <= 2^n (1 + lam_j)``; ``1/2`` is among the omegas the gate searches.)"""
    (mean_a, cov_a), (mean_b, cov_b) = _stacked(own), _stacked(other)
    rows, cols = np.indices((len(own), len(other))).reshape(2, -1)
    return pair_sum_distance(mean_a[rows] - mean_b[cols], cov_a[rows], cov_b[cols]).reshape(len(own), len(other))


def pair_sum_distance(d: Array, cov_a: Array, cov_b: Array) -> Array:
    """:func:`sum_distance` of pairs: ``d`` ``(P, n)`` their differences, ``cov_a``, ``cov_b`` ``(P, n, n)``."""
    return np.einsum("pk,pk->p", d, np.linalg.solve(cov_a + cov_b, d[..., None])[..., 0])


def trace_screen(mean_a: Array, cov_a: Array, mean_b: Array, cov_b: Array, bound: float) -> tuple[Array, Array]:
    """The pairs ``(rows, cols)`` of two stacks of estimates whose :func:`sum_distance` may be within ``bound``:
    ``m2 >= |d|^2 / lam_max(P_a + P_b) >= |d|^2 / (tr P_a + tr P_b)``, so a pair with ``|d|^2`` above ``bound``
    times the traces' sum is out without solving its system (most pairs of a list of well separated targets)."""
    diff = mean_a[:, None, :] - mean_b[None, :, :]
    dist2 = np.einsum("ijk,ijk->ij", diff, diff)
    traces = np.trace(cov_a, axis1=1, axis2=2)[:, None] + np.trace(cov_b, axis1=1, axis2=2)[None, :]
    rows, cols = np.nonzero(dist2 <= bound * traces)
    return rows, cols


def _stacked(tracks: Sequence[TrackEstimate]) -> tuple[Array, Array]:
    return np.stack([t.mean for t in tracks]), np.stack([t.cov for t in tracks])


def associate_tracks(own: Sequence[TrackEstimate], other: Sequence[TrackEstimate],
                     false_rejection: float = DEFAULT_GATE) -> list[tuple[int, int]]:
    """Pairs ``(i, j)`` of ``own[i]`` and ``other[j]`` taken to be one target (module docstring): gated by
    :func:`~zentrack.fusion.gate.ci_gate_passes` at ``gate_threshold(n, false_rejection)``, the most gated pairs,
    then the smallest sum of :func:`track_distance`; sorted by ``i``."""
    return gated_assignment(own, other, false_rejection)[0]


def gated_assignment(own: Sequence[TrackEstimate], other: Sequence[TrackEstimate],
                     false_rejection: float = DEFAULT_GATE) -> tuple[list[tuple[int, int]], Array]:
    """:func:`associate_tracks`'s pairs and the gate's verdict on every pair, ``(len(own), len(other))`` bool."""
    admissible = np.zeros((len(own), len(other)), dtype=bool)
    if not own or not other:
        return [], admissible
    dims = {t.mean.size for t in (*own, *other)}
    if len(dims) != 1:
        raise ValueError(f"tracks of different state dimensions {sorted(dims)} cannot be associated")
    n = dims.pop()
    threshold = gate_threshold(n, false_rejection)
    (mean_a, cov_a), (mean_b, cov_b) = _stacked(own), _stacked(other)
    # necessary conditions, cheap for all pairs: the traces' screen, then sum_distance's for the pairs it leaves
    rows, cols = trace_screen(mean_a, cov_a, mean_b, cov_b, 2.0**n * threshold)
    d = mean_a[rows] - mean_b[cols]
    m2 = pair_sum_distance(d, cov_a[rows], cov_b[cols]) if rows.size else np.zeros(0)
    near = m2 <= 2.0**n * threshold
    rows, cols, d, m2 = rows[near], cols[near], d[near], m2[near]
    if not rows.size:
        return [], admissible
    # the gate passes as ci_gate_passes decides: the omega = 1/2 bound (0.5 m2) within the threshold, else the
    # smallest-volume one (q, track_distance). q is computed, in one batch each, only where it decides: for the pairs
    # the first bound leaves out, and as the assignment's cost where a track has more than one admissible partner (a
    # pair alone in its row and its column is in every assignment with the most pairs, whatever it costs). Every
    # TrackEstimate is SPD (checked on construction or where it came from), so a pair the first bound passes has a
    # finite q.
    half = 0.5 * m2 <= threshold
    q = np.zeros(rows.size)
    if not half.all():
        q[~half] = ci_gate_statistics(d[~half], cov_a[rows[~half]], cov_b[cols[~half]])
    passes = half | (q <= threshold)
    admissible[rows[passes], cols[passes]] = True
    rows, cols, d, q, known = rows[passes], cols[passes], d[passes], q[passes], ~half[passes]
    shared = (admissible.sum(axis=1)[rows] > 1) | (admissible.sum(axis=0)[cols] > 1)
    if not shared.any():  # (no admissible pair at all, or each alone: the assignment is the admissible pairs)
        return sorted(zip(rows.tolist(), cols.tolist())), admissible
    needed = shared & ~known
    q[needed] = ci_gate_statistics(d[needed], cov_a[rows[needed]], cov_b[cols[needed]])
    cost = np.zeros(admissible.shape)
    cost[rows, cols] = q
    # an inadmissible pair costs more than every admissible pair together: fewest inadmissible pairs first
    cost[~admissible] = 1.0 + 2.0 * float(cost[admissible].sum())
    from scipy.optimize import linear_sum_assignment  # imported here: a node without track lists never needs it

    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols) if admissible[i, j]], admissible
