"""Global nearest neighbour: the single most likely joint event of a scan, by 2-D assignment.

The most likely event of :mod:`~zentrack.fusion.multitarget.gating` maximises ``sum log a_tj`` over its pairs,
i.e. minimises the negative log-likelihood ``-log(P_D l_tj) + log(lambda (1 - P_D P_G))`` =
``d2_tj / 2 + log sqrt(det 2 pi S_t) - log P_D + log(lambda (1 - P_D P_G))`` (Mahalanobis distance plus
log-determinant). With one dummy column per track for its missed detection, the ``T x (J + T)`` matrix

    C = [ -log a        | diag(0), inf off the diagonal ]

(inf outside the gate) is the square problem with dummy rows for clutter and dummy columns for misses
(Blackman & Popoli 1999, the assignment formulation of GNN; costs ``-log(P_D l)``, ``-log(1 - P_D P_G)`` per missed track and
``-log lambda`` per clutter return) with the constants of every complete event taken out, so SciPy's
``linear_sum_assignment`` on ``C`` gives the same event. :func:`assignment_cost` builds ``C`` (also for
Murty's ranking, :mod:`~zentrack.fusion.multitarget.murty`); :func:`best_assignment` solves it.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..registry import Param
from .base import ASSOCIATOR_REGISTRY, Association, Associator, ScanLikelihood
from .gating import check_clutter_params, log_likelihood_ratio, track_clusters

Array = np.ndarray

#: the event index of a missed detection
MISSED = -1


def assignment_cost(log_ratio: Array, gated: Array) -> Array:
    """The ``T x (J + T)`` cost ``C`` of the module docstring from ``log a`` and the gate mask ``(T, J)``."""
    t, j = gated.shape
    cost = np.full((t, j + t), np.inf)
    cost[:, :j] = np.where(gated, -np.asarray(log_ratio, dtype=float), np.inf)
    cost[np.arange(t), j + np.arange(t)] = 0.0
    return cost


def event_of_columns(columns: Array, returns: int) -> Array:
    """The assigned columns of ``C`` as an event: return index per track, :data:`MISSED` for dummy columns."""
    cols = np.asarray(columns)
    return np.where(cols < returns, cols, MISSED)


def best_assignment(log_ratio: Array, gated: Array) -> Array:
    """The event ``(T,)`` (return per track, :data:`MISSED` if none) maximising ``sum log a`` over gated pairs.

    The problem splits over the clusters of :func:`~zentrack.fusion.multitarget.gating.track_clusters`: a track
    alone in its cluster takes its likeliest gated return if ``a > 1`` (better than missed), every other cluster
    is solved by ``linear_sum_assignment`` on its block of :func:`assignment_cost`."""
    t, j = gated.shape
    event = np.full(t, MISSED)
    if t == 0 or j == 0 or not gated.any():
        return event
    lone, clusters = track_clusters(gated)
    if lone.any():
        ratio = np.where(gated[lone], log_ratio[lone], -np.inf)
        best = np.argmax(ratio, axis=1)
        event[lone] = np.where(ratio[np.arange(best.size), best] > 0.0, best, MISSED)
    for tracks, rets in clusters:
        cost = assignment_cost(log_ratio[np.ix_(tracks, rets)], gated[np.ix_(tracks, rets)])
        rows, cols = linear_sum_assignment(cost)
        picked = event_of_columns(cols, rets.size)
        event[tracks[rows]] = np.where(picked >= 0, rets[np.maximum(picked, 0)], MISSED)
    return event


def event_association(event: Array, gated: Array) -> Association:
    """The 0/1 :class:`Association` of one event (``beta[t, event[t]] = 1``, ``beta0 = 1`` if missed)."""
    t, j = gated.shape
    beta = np.zeros((t, j))
    hit = event >= 0
    beta[np.flatnonzero(hit), event[hit]] = 1.0
    return Association(beta, (~hit).astype(float), gated)


class GlobalNearestNeighbour(Associator):
    """GNN: every track takes the return of the most likely joint event (module docstring)."""

    name = "gnn"

    def __init__(self, detection_prob: float = 0.9, clutter_density: float = 1e-4, gate_prob: float = 0.999) -> None:
        check_clutter_params(detection_prob, clutter_density, gate_prob)
        self.detection_prob = float(detection_prob)
        self.clutter_density = float(clutter_density)
        self.gate_prob = float(gate_prob)

    def associate(self, likelihood: ScanLikelihood) -> Association:
        log_ratio = log_likelihood_ratio(likelihood.log_lik, self.detection_prob, self.clutter_density, self.gate_prob)
        return event_association(best_assignment(log_ratio, likelihood.gated), likelihood.gated)


#: the parameters every associator takes
CLUTTER_ASSOCIATION_PARAMS = (
    Param("detection_prob", float, 0.9, lo=0.0, hi=1.0, lo_open=True, help="P_D of a target"),
    Param("clutter_density", float, 1e-4, lo=0.0, lo_open=True,
          help="Poisson clutter returns per unit measurement volume and scan (lambda)"),
    Param("gate_prob", float, 0.999, lo=0.0, hi=1.0, lo_open=True, hi_open=True,
          help="P_G: probability that a track's own return falls inside its chi-square gate"),
)

ASSOCIATOR_REGISTRY.register(
    "gnn", GlobalNearestNeighbour, CLUTTER_ASSOCIATION_PARAMS,
    "global nearest neighbour: 2-D assignment on the negative log-likelihood, dummies for misses and clutter",
)
