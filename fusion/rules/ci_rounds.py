"""``ci3``: covariance-intersection diffusion with three rounds per step.

The contract proof of the rule registry: this file is the whole rule, built only from the base class and
:func:`~zentrack.fusion.covariance_intersection.ci_fuse`, and registers itself when the registry discovers it; no other
file names it.  It equals ``ci`` with ``rounds=3``.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..covariance_intersection import ci_fuse
from ..linalg import GaussianState, InformationPair
from .base import RULE_REGISTRY, FusionRule


class ThreeRoundCI(FusionRule):
    """CI diffusion (paper 0 Algorithm 2 line 10) repeated three times per step."""

    name = "ci3"

    def rounds(self, step: int) -> int:
        return 3

    def combine(
        self, round: int, weights: np.ndarray, messages: Mapping[str, InformationPair], present: np.ndarray | None = None
    ) -> dict[str, GaussianState]:
        return {name: ci_fuse(weights, pair, present) for name, pair in messages.items()}


RULE_REGISTRY.register("ci3", ThreeRoundCI, (), "covariance-intersection diffusion, three rounds per step")
