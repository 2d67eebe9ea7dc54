"""Multi-target tracking in one node: tracks, gating, association (GNN, JPDA), life cycle and initiation.

Component families after Stone Soup's, each with its base in :mod:`.base`: associators
(:class:`~.gnn.GlobalNearestNeighbour`, :class:`~.jpda.JointProbabilisticDataAssociation`, found by name in
:data:`ASSOCIATOR_REGISTRY`), initiators (:class:`~.initiator.TwoPointInitiator`,
:class:`~.initiator.PriorInitiator`), confirmers and deleters (:mod:`.lifecycle`), put together by
:class:`~.tracker.MultiTargetTracker`. Pure mathematics on numpy and scipy, like the rest of ``fusion``.
"""
from __future__ import annotations

from .base import (
    ASSOCIATOR_REGISTRY,
    TRANSITIONS,
    Association,
    Associator,
    Birth,
    Confirmer,
    Deleter,
    Initiator,
    ScanLikelihood,
    Track,
    TrackStatus,
)

ASSOCIATOR_REGISTRY.expect(f"{__name__}.gnn", ("gnn",), builtin=True)
ASSOCIATOR_REGISTRY.expect(f"{__name__}.jpda", ("jpda",), builtin=True)


def make_associator(name: str, params: dict[str, object] | None = None) -> Associator:
    """The registered associator ``name`` with its parameters checked by the registry."""
    return ASSOCIATOR_REGISTRY.create(name, params)


__all__ = [
    "ASSOCIATOR_REGISTRY",
    "TRANSITIONS",
    "Association",
    "Associator",
    "Birth",
    "Confirmer",
    "Deleter",
    "Initiator",
    "ScanLikelihood",
    "Track",
    "TrackStatus",
    "make_associator",
]
