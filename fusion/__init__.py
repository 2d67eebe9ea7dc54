"""zentrack.fusion: the pure mathematics of zentrack (numpy/scipy only; no I/O, no clocks).

Component families:
- motion and measurement models (:mod:`.motion`, :mod:`.measurement`), found by name in :mod:`.models`,
- local filters behind one interface (:mod:`.filters`: TESKF, ESKF, EKF, UKF, CKF), found by name in
  :data:`FILTER_REGISTRY`; :class:`NodeFilter` is what one tracker runs on typed estimates and scans,
- scans and typed single-node estimates (:mod:`.scan`, :mod:`.estimates`),
- fusion rules with rounds (:mod:`.rules`: CI diffusion, independent fusion, plug-ins), found by name in
  :data:`RULE_REGISTRY`, on the batched kernels of :mod:`.covariance_intersection`,
- the registry machinery (:mod:`.registry`), graphs and weights (:mod:`.graphs`), the consistency of estimates
  (:mod:`.consistency`).

The simulation of targets, sensors and clutter is ``zentrack.truth.simulation``; the batched network simulator,
the bound and the study metrics are ``zentrack.study``. Importing this package imports none of its modules:
each name below is imported from its module on first access, so a tracker process, which needs a filter, a
rule and its models, loads nothing else.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .covariance_intersection import ci_fuse, independent_fuse, renormalise_rows
    from .estimates import CompositeEstimate, Estimate, GaussianEstimate, InformationEstimate, ParticleEstimate
    from .filters import (
        FILTER_REGISTRY,
        LOCAL_FILTERS,
        FilterContext,
        GaussianNodeFilter,
        LocalFilter,
        NodeFilter,
        make_local_filter,
        make_node_filter,
    )
    from .linalg import GaussianState, InformationPair, from_information, to_information
    from .registry import Param, Registry, load_plugins
    from .rules import RULE_REGISTRY, FusionRule, RoundContribution, make_rule, next_round_blocks, stack_messages
    from .scan import Scan

#: module (relative to this package) -> the names this package re-exports from it
_EXPORTS: dict[str, tuple[str, ...]] = {
    "estimates": ("CompositeEstimate", "Estimate", "GaussianEstimate", "InformationEstimate", "ParticleEstimate"),
    "filters": ("FILTER_REGISTRY", "LOCAL_FILTERS", "FilterContext", "GaussianNodeFilter", "LocalFilter", "NodeFilter",
                "make_local_filter", "make_node_filter"),
    "covariance_intersection": ("ci_fuse", "independent_fuse", "renormalise_rows"),
    "linalg": ("GaussianState", "InformationPair", "from_information", "to_information"),
    "registry": ("Param", "Registry", "load_plugins"),
    "rules": ("RULE_REGISTRY", "FusionRule", "RoundContribution", "make_rule", "next_round_blocks", "stack_messages"),
    "scan": ("Scan",),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}


def __getattr__(name: str) -> Any:
    """A re-exported name, imported from its module on first access."""
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = [
    "FILTER_REGISTRY",
    "LOCAL_FILTERS",
    "RULE_REGISTRY",
    "CompositeEstimate",
    "Estimate",
    "FilterContext",
    "FusionRule",
    "GaussianEstimate",
    "GaussianNodeFilter",
    "GaussianState",
    "InformationEstimate",
    "InformationPair",
    "LocalFilter",
    "NodeFilter",
    "Param",
    "ParticleEstimate",
    "Registry",
    "RoundContribution",
    "Scan",
    "ci_fuse",
    "from_information",
    "independent_fuse",
    "load_plugins",
    "make_local_filter",
    "make_node_filter",
    "make_rule",
    "next_round_blocks",
    "renormalise_rows",
    "stack_messages",
    "to_information",
]
