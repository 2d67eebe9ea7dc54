"""A tracker's filter over any interval: what predicts an estimate to a detection's own time.

A sensor of its own (issue 52) measures when it measures, so a tracker predicts its estimate over intervals that
are not the scenario's sample period. :class:`IntervalPredictor` holds the filter built for the sample period and
builds (and keeps) the same filter for any other interval from the plant over that interval
(:func:`~zentrack.fusion.models.plant_over`): the transition and the process noise of dt, every other parameter
the filter's own. A negative interval predicts back (a neighbour's estimate valid a few ms after the tracker's
fusion time: ``node/diffusion/neighbour_clocks.py``). An interval of the sample period itself uses the node's
filter unchanged, so a sensor that samples on the run's grid is predicted exactly as the synchronous tracker
predicts it. The filter may be one tracker's (a :class:`~.base.NodeFilter` on one estimate) or a stack's (a
:class:`~.base.LocalFilter`: every track of a many-target tracker, ``fusion/multitarget/tracker.py``): anything that
predicts one period.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any, Generic, Protocol, TypeVar

from ..scan import Scan

#: filters kept for other intervals (the least recently used goes first)
KEPT_INTERVALS = 64
#: intervals closer than this (s) to the sample period, or to zero, count as it
INTERVAL_TOLERANCE_S = 1e-9


class Predicts(Protocol):
    """A filter that predicts an estimate (or a stack of them) one interval ahead."""

    def predict(self, est: Any) -> Any: ...


F = TypeVar("F", bound=Predicts)
E = TypeVar("E")


class IntervalPredictor(Generic[F]):
    """``predict(est, dt)``: ``est`` predicted ``dt`` seconds ahead (module docstring). ``build(dt)`` makes the
    filter for an interval; ``period`` is the sample period ``base`` was built for."""

    def __init__(self, base: F, period: float, build: Callable[[float], F]) -> None:
        self.base, self.period, self.build = base, float(period), build
        self._kept: OrderedDict[float, F] = OrderedDict()

    def filter_for(self, dt: float) -> F:
        """The filter whose one prediction spans ``dt`` seconds."""
        if abs(dt - self.period) <= INTERVAL_TOLERANCE_S:
            return self.base
        key = round(dt, 9)
        found = self._kept.get(key)
        if found is None:
            found = self._kept[key] = self.build(key)
            if len(self._kept) > KEPT_INTERVALS:
                self._kept.popitem(last=False)
        else:
            self._kept.move_to_end(key)
        return found

    def predict(self, est: E, dt: float) -> E:
        """``est`` predicted ``dt`` seconds ahead (``dt`` = 0: ``est`` itself; ``dt`` < 0: back, with the process
        noise of ``|dt|``, :func:`~zentrack.fusion.models.plant_over`)."""
        if abs(dt) <= INTERVAL_TOLERANCE_S:
            return est
        return self.filter_for(dt).predict(est)


def update_at_times(est: E, t_from: float, t_to: float, timed: Sequence[tuple[float, Scan]],
                    predictor: IntervalPredictor, correct: Callable[[E, list[Scan], float], E]) -> E:
    """``est`` (valid at ``t_from``) corrected with each scan at its own time, predicting to each (``timed``: (time,
    scan) in time order, ``t_from <= time <= t_to``), then predicted to ``t_to``: the estimate valid at ``t_to``
    (paper 0 Algorithm 2 lines 6-8, the update at each detection's time). ``correct(est, scans, t)`` is the update
    at time ``t``; ``est`` is one tracker's estimate or a stack of tracks (whatever ``predictor`` predicts)."""
    t = t_from
    for t_scan, scan in timed:
        est = correct(predictor.predict(est, t_scan - t), [scan], t_scan)
        t = t_scan
    return predictor.predict(est, t_to - t)
