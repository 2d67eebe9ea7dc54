"""How a tracker handles detections that arrive late (issue 52), one class per method (:mod:`.base` says what they
share): zero latency (the reference), drop late, the live tracker's fixed lag, re-processing, and the OOSM algorithm
Al1. ``zentrack bench async`` runs each on a network of trackers (:mod:`zentrack.study.async_network`)."""
from __future__ import annotations

from zentrack.fusion.estimates import Estimate

from .base import AsyncMethod, MethodCounts, NodeModel
from .fixed_lag import DEFAULT_LAG_S, FixedLag
from .in_order import DropLate, ZeroLatency
from .oosm import OosmAl1
from .reprocess import DEFAULT_MAX_LAG_S, Reprocess

#: the methods by name, in the order the bench reports them
METHODS: dict[str, type[AsyncMethod]] = {m.name: m for m in (ZeroLatency, DropLate, FixedLag, Reprocess, OosmAl1)}



def make_method(name: str, node: NodeModel, prior: Estimate, t0: float = 0.0, **settings: float) -> AsyncMethod:
    """Method ``name`` for one tracker with estimate ``prior`` at ``t0``; of ``settings`` (``lag``, ``max_lag``) it
    gets those it takes."""
    cls = METHODS[name]
    return cls(node, prior, t0, **{k: v for k, v in settings.items() if k in cls.takes})


__all__ = ["DEFAULT_LAG_S", "DEFAULT_MAX_LAG_S", "METHODS", "AsyncMethod", "DropLate", "FixedLag", "MethodCounts",
           "NodeModel", "OosmAl1", "Reprocess", "ZeroLatency", "make_method"]
