"""**Re-processing**: no lag; a detection older than the estimate rolls the tracker back and everything after it is
done again in time order.

The tracker keeps, over the last ``max_lag`` seconds, its events in time order, each with the estimate after it: its
detections (time, scan) and its fusions (tick time, the neighbours' messages it fused, as the function that fuses
again with them). A detection in time order is applied on arrival. One older than the estimate but within
``max_lag`` goes back to the estimate before it (the last event at or before its time), is applied there, and every
later event is done again: a detection predicted to and updated at its time, a fusion predicted to its tick and fused
*again* with the neighbours' messages stored with it (they are what the neighbours sent then; the tracker cannot
make them take the late detection). Older than ``max_lag``: too old, dropped.
"""
from __future__ import annotations

from dataclasses import dataclass

from zentrack.fusion.estimates import Estimate
from zentrack.fusion.scan import Scan

from .base import TIME_EPS, AsyncMethod, NodeModel, Refuse, older

#: how far back re-processing and the OOSM update go (s): past the latest detection of the bench (300 ms latency
#: plus one period of a 1 Hz sensor for a reordered one)
DEFAULT_MAX_LAG_S = 2.0


@dataclass
class Event:
    """One detection (``scan``) or fusion (``refuse``) at time ``t``, and the estimate after it."""

    t: float
    est: Estimate
    scan: Scan | None = None
    refuse: Refuse | None = None


class Reprocess(AsyncMethod):
    """Roll back and re-process (module docstring)."""

    name = "reprocess"
    label = "re-processing"
    takes = ("max_lag",)

    def __init__(self, node: NodeModel, prior: Estimate, t0: float = 0.0, max_lag: float = DEFAULT_MAX_LAG_S) -> None:
        super().__init__(node, prior, t0)
        self.max_lag = float(max_lag)
        self.log: list[Event] = []  # in time order
        self.base = Event(self.t, prior)  # the estimate before the first event kept

    def detection(self, t: float, scan: Scan) -> None:
        self.counts.arrived += 1
        if not older(t, self.t):
            self.est = self.node.correct(self.node.predict(self.est, t - self.t), [scan])
            self.t = max(self.t, t)
            self.log.append(Event(self.t, self.est, scan=scan))
            self.counts.applied += 1
            return
        if older(t, self.t - self.max_lag) or older(t, self.base.t):
            self.counts.too_old += 1
            return
        # back to the last event at or before t (a fusion at t's time stays before it, as in time order)
        at = next((i for i, e in enumerate(self.log) if e.t > t + TIME_EPS), len(self.log))
        start = self.log[at - 1] if at > 0 else self.base
        again = [Event(t, start.est, scan=scan), *self.log[at:]]
        est, now = start.est, start.t
        for e in again:
            est = self.node.predict(est, e.t - now)
            est = e.refuse(est) if e.refuse is not None else self.node.correct(est, [e.scan] if e.scan else [])
            e.est, now = est, e.t
        self.log[at:] = again
        self.est = est
        self.counts.late += 1
        self.counts.rollbacks += 1
        self.counts.replayed += len(again) - 1

    def fused(self, k: int, t_k: float, fused: Estimate, refuse: Refuse) -> None:
        super().fused(k, t_k, fused, refuse)
        self.log.append(Event(t_k, fused, refuse=refuse))
        while self.log and older(self.log[0].t, self.t - self.max_lag):
            self.base = self.log.pop(0)
