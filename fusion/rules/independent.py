"""Naive independent fusion: the information sum over the neighbours and self (assumes independent errors).

``Y_i = sum_j Y_j``, ``y_i = sum_j y_j`` over the senders with a non-zero weight that are present.  Not
consistent under correlated errors (it counts shared information twice); kept for comparison with CI.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..covariance_intersection import mix_information
from ..linalg import GaussianState, InformationPair, from_information
from .base import RULE_REGISTRY, FusionRule

Array = np.ndarray


class IndependentFusion(FusionRule):
    """Information sum; ``weights`` only select the senders (non-zero entries)."""

    name = "independent"

    def combine(
        self, round: int, weights: Array, messages: Mapping[str, InformationPair], present: Array | None = None
    ) -> dict[str, GaussianState]:
        support = np.asarray(weights) != 0
        if present is not None:
            support = support & present
        mask = support.astype(float)
        return {name: from_information(mix_information(mask, pair)) for name, pair in messages.items()}

    def network_weights(self, weights: Array, adjacency: Array) -> Array:
        """Every neighbour and self (the adjacency with self loops), whatever the diffusion weights."""
        adj = np.asarray(adjacency)
        return ((adj != 0) | np.eye(adj.shape[-1], dtype=bool)).astype(float)


RULE_REGISTRY.register(
    "independent", IndependentFusion, (), "information sum over neighbours and self (not consistent; comparison only)"
)
