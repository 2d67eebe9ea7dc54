"""Covariance intersection with weights chosen per step from the covariances (``ci-fast``, ``ci-trace``).

CI is consistent for *any* convex weights over the senders (paper 0 Lemma 1, Theorem 3), so a receiver may
choose them from what it received instead of using the fixed diffusion weights:

- ``ci-fast`` (fast CI, Niehsen, "Information fusion based on fast covariance intersection filtering",
  FUSION 2002): ``omega_j = (1 / tr P_j) / sum_k (1 / tr P_k)`` over the receiver's neighbours that sent (and
  itself): the better-informed estimate weighs more
  (:func:`~zentrack.fusion.covariance_intersection.inverse_covariance_trace_weights`);
- ``ci-trace``: the ``omega`` on the simplex that minimises ``tr P`` of the fused
  ``P^-1 = sum_j omega_j P_j^-1`` (the classical CI criterion, Julier & Uhlmann 1997), by a multiplicative
  fixed-point iteration (:func:`~zentrack.fusion.covariance_intersection.min_trace_weights`).

Both combine with :func:`~zentrack.fusion.covariance_intersection.ci_fuse`, the CI of every rule.

The graph still decides who is fused (the diffusion weights' support), not how much. With ``share_scans`` the
nodes also forward their scans to the neighbours before the local update (measurement sharing), so each node
updates with its one-hop neighbourhood's measurements and then intersects the neighbours' estimates.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..covariance_intersection import ci_fuse, inverse_covariance_trace_weights, min_trace_weights, renormalise_rows
from ..defaults import MAX_ROUNDS
from ..linalg import GaussianState, InformationPair
from ..registry import Param
from .base import RELAY_SCANS, RULE_REGISTRY
from .ci import CovarianceIntersection

Array = np.ndarray


class WeightedCovarianceIntersection(CovarianceIntersection):
    """CI whose weights each receiver chooses per step from the senders' covariances (module docstring):
    ``choose(infos (R, S, n, n), support (R, M, S)) -> omega (R, M, S)``, a weight rule of
    :mod:`~zentrack.fusion.covariance_intersection`."""

    choose = staticmethod(inverse_covariance_trace_weights)

    def combine(
        self, round: int, weights: Array, messages: Mapping[str, InformationPair], present: Array | None = None
    ) -> dict[str, GaussianState]:
        w = renormalise_rows(weights, present) if present is not None else np.asarray(weights, dtype=float)
        out = {}
        for name, pair in messages.items():
            runs = pair.matrix.shape[0]
            support = np.broadcast_to(w > 0, (runs,) + w.shape[-2:])
            out[name] = ci_fuse(self.choose(pair.matrix, support), pair)
        return out


class FastCI(WeightedCovarianceIntersection):
    name = "ci-fast"
    choose = staticmethod(inverse_covariance_trace_weights)


class MinTraceCI(WeightedCovarianceIntersection):
    name = "ci-trace"
    choose = staticmethod(min_trace_weights)


_PARAMS = (Param("rounds", int, 1, lo=1, hi=MAX_ROUNDS, help="rounds per step"),
           Param("share_scans", bool, False, help="forward scans to the neighbours before the local update"),
           RELAY_SCANS)
RULE_REGISTRY.register("ci-fast", FastCI, _PARAMS,
                       "covariance intersection with fast-CI weights per step, omega_j ~ 1/tr(P_j) (Niehsen 2002)")
RULE_REGISTRY.register("ci-trace", MinTraceCI, _PARAMS,
                       "covariance intersection with the weights that minimise the fused trace, per step")
