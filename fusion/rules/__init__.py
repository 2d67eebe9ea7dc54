"""Fusion rules with rounds (:class:`FusionRule`), found by name in :data:`RULE_REGISTRY`.

Built-ins register when imported (``ci``, then ``independent``); any other module file of this package is
imported when the registry is first used, so a new rule is one new file.
"""
from __future__ import annotations

from .base import (
    RULE_REGISTRY,
    FusionRule,
    RoundMessage,
    make_rule,
    next_round_blocks,
    stack_messages,
    stack_pairs,
    unstack_message,
)

from .ci import CovarianceIntersection  # isort: skip
from .independent import IndependentFusion  # isort: skip

#: the registered rule names (built-ins first, then the modules found in this package)
FUSION_RULES: tuple[str, ...] = RULE_REGISTRY.names()

__all__ = [
    "FUSION_RULES",
    "RULE_REGISTRY",
    "CovarianceIntersection",
    "FusionRule",
    "IndependentFusion",
    "RoundMessage",
    "make_rule",
    "next_round_blocks",
    "stack_messages",
    "stack_pairs",
    "unstack_message",
]
