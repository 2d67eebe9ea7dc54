"""Joint probabilistic data association (Fortmann, Bar-Shalom & Scheffe 1983; Bar-Shalom & Fortmann 1988 Sec. 9.3).

The marginal probability that return ``j`` is track ``t``'s is the posterior mass of the joint events that
pair them, ``beta_tj = sum_{theta ∋ (t, j)} P(theta | Z)``, and ``beta_t0`` that of the events where ``t`` is
missed, with ``P(theta | Z) ∝ prod_{(t, j) in theta} a_tj`` (:mod:`~zentrack.fusion.multitarget.gating`).

Only tracks that share gated returns interact, so the tracks are split into clusters, the connected
components of the bipartite graph "track t gates return j" (:func:`~zentrack.fusion.multitarget.gating.track_clusters`); events factor over
clusters. A track alone in its cluster is the PDA (:func:`~zentrack.fusion.filters.pda_common.pda_betas`, batched
over every such cluster). A larger cluster is enumerated exactly (:func:`enumerate_events`) while it has at
most ``max_events`` events; beyond that its ``k_best`` most likely events (Murty's ranking,
:mod:`~zentrack.fusion.multitarget.murty`) stand for all of them. Truncating to a set of events changes each
marginal by at most the posterior mass left out (``|beta - beta_k| <= p_out``), so the approximation is
close where the tail is light.
"""
from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from ..filters.pda_common import pda_betas
from ..registry import Param
from .base import ASSOCIATOR_REGISTRY, Association, Associator, ScanLikelihood
from .gating import check_clutter_params, log_likelihood_ratio, track_clusters
from .gnn import CLUTTER_ASSOCIATION_PARAMS, MISSED
from .murty import k_best_events

Array = np.ndarray


def enumerate_events(log_ratio: Array, gated: Array, max_events: int) -> tuple[Array, Array] | None:
    """Every joint event of a cluster, ``events`` ``(E, T)`` (return per track, -1 missed) and their log
    weights ``(E,)``; None as soon as there are more than ``max_events``. Built track by track, all partial
    events at once: each extends by "missed" or by a gated return no earlier track took."""
    t, j = gated.shape
    events = np.zeros((1, 0), dtype=int)
    used = np.zeros((1, j), dtype=bool)
    log_w = np.zeros(1)
    for track in range(t):
        ext_e = [np.column_stack([events, np.full(len(events), MISSED)])]
        ext_u, ext_w = [used], [log_w]
        for ret in np.flatnonzero(gated[track]):
            free = ~used[:, ret]
            if not free.any():
                continue
            ext_e.append(np.column_stack([events[free], np.full(int(free.sum()), ret)]))
            u = used[free].copy()
            u[:, ret] = True
            ext_u.append(u)
            ext_w.append(log_w[free] + log_ratio[track, ret])
        events, used, log_w = np.concatenate(ext_e), np.concatenate(ext_u), np.concatenate(ext_w)
        if len(events) > max_events:
            return None
    return events, log_w


def event_marginals(events: Array, log_w: Array, returns: int) -> tuple[Array, Array]:
    """``beta`` ``(T, J)`` and ``beta0`` ``(T,)`` of a set of events with log weights (normalised over the set)."""
    p = np.exp(log_w - logsumexp(log_w))
    t = events.shape[1]
    cell = np.where(events >= 0, events, returns) + (returns + 1) * np.arange(t)  # last column: the misses
    beta = np.bincount(cell.ravel(), weights=np.repeat(p, t), minlength=t * (returns + 1)).reshape(t, returns + 1)
    return beta[:, :returns], beta[:, returns]


def lone_track_betas(log_ratio: Array, gated: Array) -> tuple[Array, Array]:
    """The PDA of tracks that share no gated return: ``beta_j = a_j / (1 + sum_i a_i)``, ``beta_0 = 1 / (1 +
    sum_i a_i)`` (:func:`~zentrack.fusion.filters.pda_common.pda_betas` with ``P_D l`` replaced by ``a`` and
    ``b`` by 1), on the gated returns of each row moved to the front."""
    jg = int(gated.sum(axis=1).max(initial=0))
    front = np.argsort(~gated, axis=1, kind="stable")[:, :jg]
    assoc = pda_betas(np.take_along_axis(log_ratio, front, axis=1), np.take_along_axis(gated, front, axis=1),
                      1.0, np.ones(gated.shape[0]))
    beta = np.zeros(gated.shape)
    np.put_along_axis(beta, front, assoc.beta, axis=1)
    return beta, assoc.beta0


class JointProbabilisticDataAssociation(Associator):
    """JPDA with clusters, exact enumeration up to ``max_events`` per cluster and Murty's ``k_best`` beyond
    (module docstring). ``last_exact`` tells whether every cluster of the last scan was enumerated exactly."""

    name = "jpda"

    def __init__(self, detection_prob: float = 0.9, clutter_density: float = 1e-4, gate_prob: float = 0.999,
                 max_events: int = 10_000, k_best: int = 200) -> None:
        check_clutter_params(detection_prob, clutter_density, gate_prob)
        if max_events < 1 or k_best < 1:
            raise ValueError(f"max_events and k_best must be >= 1, got {max_events} and {k_best}")
        self.detection_prob = float(detection_prob)
        self.clutter_density = float(clutter_density)
        self.gate_prob = float(gate_prob)
        self.max_events = int(max_events)
        self.k_best = int(k_best)
        self.last_exact = True

    def associate(self, likelihood: ScanLikelihood) -> Association:
        gated = likelihood.gated
        t, j = gated.shape
        log_ratio = log_likelihood_ratio(likelihood.log_lik, self.detection_prob, self.clutter_density, self.gate_prob)
        beta, beta0 = np.zeros((t, j)), np.ones(t)
        self.last_exact = True
        lone, clusters = track_clusters(gated)
        for tracks, rets in clusters:
            sub_ratio, sub_gated = log_ratio[np.ix_(tracks, rets)], gated[np.ix_(tracks, rets)]
            found = enumerate_events(sub_ratio, sub_gated, self.max_events)
            if found is None:
                self.last_exact = False
                found = k_best_events(sub_ratio, sub_gated, self.k_best)
            b, b0 = event_marginals(*found, rets.size)
            beta[np.ix_(tracks, rets)] = b
            beta0[tracks] = b0
        if lone.any():
            beta[lone], beta0[lone] = lone_track_betas(log_ratio[lone], gated[lone])
        return Association(beta, beta0, gated)


ASSOCIATOR_REGISTRY.register(
    "jpda", JointProbabilisticDataAssociation,
    CLUTTER_ASSOCIATION_PARAMS + (
        Param("max_events", int, 10_000, lo=1, help="joint events enumerated exactly per cluster at most"),
        Param("k_best", int, 200, lo=1, help="events (Murty's k best) standing for a larger cluster"),
    ),
    "joint probabilistic data association: clusters, exact events up to a cap, Murty's k best beyond",
)
