"""Covariance-intersection diffusion (paper 0 Algorithm 2 line 10), optionally repeated in rounds.

``Y_i = sum_j w_ij Y_j``, ``y_i = sum_j w_ij y_j`` over the pairs present (the row renormalised over them),
then ``P_i = Y_i^-1``, ``x_i = P_i y_i``.  CI is consistent for any convex weights and any correlation
(paper 0 Lemma 1, Theorem 3), so repeating the mix L times per step stays consistent and spreads each
node's information L hops.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..covariance_intersection import ci_fuse, ci_fuse_one
from ..defaults import MAX_ROUNDS
from ..linalg import GaussianState, InformationPair
from ..registry import Param
from .base import RELAY_SCANS, RULE_REGISTRY, FusionRule

Array = np.ndarray


class CovarianceIntersection(FusionRule):
    """CI diffusion with ``rounds`` rounds per step."""

    name = "ci"

    def __init__(self, rounds: int = 1, share_scans: bool = False, relay_scans: bool = False) -> None:
        if rounds < 1:
            raise ValueError(f"rounds must be >= 1, got {rounds}")
        if relay_scans and not share_scans:
            raise ValueError("relay_scans relays the scans that share_scans forwards: set share_scans too")
        self._rounds = int(rounds)
        self.exchanges_scans = bool(share_scans)
        self.relays_scans = bool(relay_scans)

    def rounds(self, step: int) -> int:
        return self._rounds

    def combine(
        self, round: int, weights: Array, messages: Mapping[str, InformationPair], present: Array | None = None
    ) -> dict[str, GaussianState]:
        return {name: ci_fuse(weights, pair, present) for name, pair in messages.items()}

    def combine_one(self, round: int, weights: Array, messages: Sequence[Mapping[str, tuple[Array, Array]]]
                    ) -> dict[str, GaussianState]:
        """:func:`~zentrack.fusion.covariance_intersection.ci_fuse_one` per block, bit for bit :meth:`combine`'s
        result; a subclass that combines otherwise (chosen weights, hybrid) keeps the stacking default."""
        if type(self).combine is not CovarianceIntersection.combine:
            return super().combine_one(round, weights, messages)
        return {name: ci_fuse_one(weights, [m[name][0] for m in messages], [m[name][1] for m in messages])
                for name in messages[0]}


RULE_REGISTRY.register(
    "ci",
    CovarianceIntersection,
    (Param("rounds", int, 1, lo=1, hi=MAX_ROUNDS, help="diffusion rounds per step"),
     Param("share_scans", bool, False, help="forward scans to the neighbours before the local update (paper 2)"),
     RELAY_SCANS),
    "covariance-intersection diffusion (paper 0 Algorithm 2 line 10), rows renormalised over present senders",
)
