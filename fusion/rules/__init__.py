"""Fusion rules with rounds (:class:`FusionRule`), found by name in :data:`RULE_REGISTRY`.

A rule's module is imported the first time its name is asked for (a tracker fusing by ``ci`` imports ``ci`` and
no other rule). The built-ins are ``ci``, then ``independent``; any other module file of this package is found
by the registry's discovery, so a new rule is one new file. The rule classes are imported on first access.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..registry import lazy_package_getattr
from .base import (
    RULE_REGISTRY,
    FusionRule,
    RoundContribution,
    make_rule,
    next_round_blocks,
    stack_messages,
    stack_pairs,
    unstack_message,
)

if TYPE_CHECKING:
    from .ci import CovarianceIntersection
    from .independent import IndependentFusion

    FUSION_RULES: tuple[str, ...]

RULE_REGISTRY.expect(f"{__name__}.ci", ("ci",), builtin=True)
RULE_REGISTRY.expect(f"{__name__}.independent", ("independent",), builtin=True)

_LAZY = {"CovarianceIntersection": "ci", "IndependentFusion": "independent"}


#: ``FUSION_RULES`` (every registered name, built-ins first, then the modules found in this package) and the
#: built-in rule classes, imported on first use
__getattr__ = lazy_package_getattr(__name__, globals(), "FUSION_RULES", RULE_REGISTRY, _LAZY)


__all__ = [
    "FUSION_RULES",
    "RULE_REGISTRY",
    "CovarianceIntersection",
    "FusionRule",
    "IndependentFusion",
    "RoundContribution",
    "make_rule",
    "next_round_blocks",
    "stack_messages",
    "stack_pairs",
    "unstack_message",
]
