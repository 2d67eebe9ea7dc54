"""What one tracker does with detections that come late: the interface every method of ``zentrack bench async``
implements (issue 52), and the filter it works with.

A sensor of its own measures at its own times; its detections reach the tracker after a latency, some after a later
one (reordered). The tracker also fuses with its ring neighbours on the fusion period (covariance intersection,
single round). The simulation (:mod:`zentrack.study.async_network`) drives one method per tracker, in wall-clock
order:

- a detection measured at ``t`` (tracker clock) arrives at wall time :meth:`AsyncMethod.arrival`:
  :meth:`AsyncMethod.detection` ``(t, scan)``;
- fusion tick k, at wall time ``t_k + publish_lag``: :meth:`AsyncMethod.share` ``(k, t_k)`` returns the estimate
  valid at ``t_k`` the tracker publishes and shares with its neighbours; then :meth:`AsyncMethod.fused` gets the
  fused estimate and ``refuse``, a function that fuses another own estimate of ``t_k`` with the same neighbours'
  messages (what re-processing needs to redo a fusion it rolls back over).

Every method predicts, updates and fuses through :class:`NodeModel`: the node filter of the scenario
(:func:`~zentrack.fusion.filters.make_node_filter`), its prediction over any interval
(:class:`~zentrack.fusion.filters.interval.IntervalPredictor`) and its update. The methods differ only in what they
do with time.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from zentrack.fusion.estimates import Estimate
from zentrack.fusion.filters import FilterContext, NodeFilter, make_node_filter
from zentrack.fusion.filters.interval import INTERVAL_TOLERANCE_S, IntervalPredictor, update_at_times
from zentrack.fusion.models import plant_over
from zentrack.fusion.scan import Scan
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.sensor_stream import SimulatedDetection

#: two times closer than this (s) are the same time (a detection at a tick's time belongs to the next window)
TIME_EPS = INTERVAL_TOLERANCE_S
#: what a filter may raise on an update it cannot make: the estimate is kept, the update counted refused
NUMERIC_ERRORS = (np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError, OverflowError, ValueError)

#: ``refuse(est)``: ``est`` (an own estimate of the tick's time) fused again with the tick's neighbours' messages
Refuse = Callable[[Estimate], Estimate]


@dataclass
class NodeModel:
    """A tracker's filter (module docstring): one per scenario, shared by its trackers (it holds no estimate)."""

    filter: NodeFilter
    interval: IntervalPredictor
    refused: int = 0  #: updates whose filter raised (the estimate was kept)

    @classmethod
    def of(cls, scn: ScenarioData, kind: str, params: dict | None = None) -> NodeModel:
        """The node filter ``kind`` of ``scn`` (its models, prior, sample period), built as a tracker builds it."""
        context = FilterContext.from_scenario(scn)
        base = make_node_filter(kind, context, params)
        interval = IntervalPredictor(base, scn.ts, lambda dt: make_node_filter(
            kind, FilterContext(plant_over(scn.plant, scn.ts, dt, scn.plant_params), context.measurement, context.p0,
                                context.lumped_var), params))
        return cls(base, interval)

    def predict(self, est: Estimate, dt: float) -> Estimate:
        """``est`` predicted ``dt`` seconds ahead (within :data:`TIME_EPS` of zero: itself)."""
        return self.interval.predict(est, max(dt, 0.0))

    def correct(self, est: Estimate, scans: Sequence[Scan], t: float | None = None) -> Estimate:
        """``est`` updated with ``scans`` (at time ``t``; an update the filter cannot make leaves it as it is,
        counted)."""
        try:
            return self.filter.update(est, scans)
        except NUMERIC_ERRORS:
            self.refused += 1
            return est

    def over(self, est: Estimate, t_from: float, t_to: float, timed: Sequence[tuple[float, Scan]]) -> Estimate:
        """``est`` (valid at ``t_from``) updated with each scan at its own time, then predicted to ``t_to``."""
        return update_at_times(est, t_from, t_to, timed, self.interval, self.correct)


@dataclass
class MethodCounts:
    """What one tracker's method did with its detections."""

    arrived: int = 0  #: detections that reached it
    applied: int = 0  #: detections that went into its estimate in time order (on arrival or in a window)
    late: int = 0  #: detections older than its estimate, applied all the same (re-processed or by the OOSM update)
    dropped: int = 0  #: detections older than its estimate, dropped (drop late)
    too_old: int = 0  #: detections older than its lag or buffer, dropped
    rollbacks: int = 0  #: re-processing: times it went back
    replayed: int = 0  #: re-processing: events (detections and fusions) done again
    lag_events: list[int] = field(default_factory=list)  #: OOSM: events between the stored estimate and now

    def add(self, other: MethodCounts) -> None:
        for name in ("arrived", "applied", "late", "dropped", "too_old", "rollbacks", "replayed"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.lag_events.extend(other.lag_events)


class AsyncMethod(ABC):
    """One tracker's way with late detections (module docstring). ``prior`` is its estimate at ``t0``."""

    #: the name on the command line and in the JSON
    name: ClassVar[str]
    #: what the table and the figure call it
    label: ClassVar[str]
    #: the estimate of tick k is published at wall time t_k + publish_lag
    publish_lag: float = 0.0
    #: the settings its constructor takes by keyword (``lag``, ``max_lag``: :func:`~zentrack.study.async_methods.make_method`)
    takes: ClassVar[tuple[str, ...]] = ()

    def __init__(self, node: NodeModel, prior: Estimate, t0: float = 0.0) -> None:
        self.node = node
        self.est: Estimate = prior
        self.t = float(t0)  #: the time ``est`` is valid at
        self.counts = MethodCounts()

    def arrival(self, det: SimulatedDetection) -> float:
        """The wall time ``det`` reaches the tracker (run time, s): when it was published."""
        return det.t_publish

    @abstractmethod
    def detection(self, t: float, scan: Scan) -> None:
        """A detection measured at ``t`` (the tracker's clock) has arrived."""

    def share(self, k: int, t_k: float) -> Estimate:
        """Tick k: the estimate valid at ``t_k`` to publish and share (by default the estimate predicted to it)."""
        return self.node.predict(self.est, t_k - self.t)

    def fused(self, k: int, t_k: float, fused: Estimate, refuse: Refuse) -> None:
        """Tick k's fusion result (valid at ``t_k``) is the tracker's estimate from now on."""
        self.est, self.t = fused, t_k


def older(t: float, than: float) -> bool:
    """Whether time ``t`` is before ``than`` (by more than :data:`TIME_EPS`)."""
    return t < than - TIME_EPS
