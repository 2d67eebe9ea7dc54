"""**The OOSM algorithm**: no lag; a detection older than the estimate updates the current estimate directly by
Bar-Shalom's one-step solution Al1 (:mod:`zentrack.fusion.filters.oosm`, where its equations are), from the estimate
the tracker held at the last event at or before the detection's time.

The tracker keeps the estimates after its events (detections and fusions) of the last ``max_lag`` seconds; nothing
is done again. Exact for a linear-Gaussian filter when one update came after the detection's time; with several
(the fusions of a network, other detections) everything after the stored estimate counts as one equivalent
measurement (Bar-Shalom, Chen & Mallick 2004), an approximation.
"""
from __future__ import annotations

from zentrack.fusion.estimates import Estimate, GaussianEstimate
from zentrack.fusion.filters.oosm import OutOfSequence
from zentrack.fusion.scan import Scan

from .base import TIME_EPS, AsyncMethod, NodeModel, Refuse, older
from .reprocess import DEFAULT_MAX_LAG_S


class OosmAl1(AsyncMethod):
    """Al1 on a late detection (module docstring)."""

    name = "oosm"
    label = "OOSM (Al1)"
    takes = ("max_lag",)

    def __init__(self, node: NodeModel, prior: Estimate, t0: float = 0.0, max_lag: float = DEFAULT_MAX_LAG_S) -> None:
        super().__init__(node, prior, t0)
        self.max_lag = float(max_lag)
        self.al1 = OutOfSequence(node.interval, node.correct)
        self.history: list[tuple[float, Estimate]] = [(self.t, prior)]  # the last one is (self.t, self.est)

    def detection(self, t: float, scan: Scan) -> None:
        self.counts.arrived += 1
        if not older(t, self.t):
            self.est = self.node.correct(self.node.predict(self.est, t - self.t), [scan])
            self.t = max(self.t, t)
            self.history.append((self.t, self.est))
            self.counts.applied += 1
            return
        if older(t, self.t - self.max_lag) or older(t, self.history[0][0]):
            self.counts.too_old += 1
            return
        at = max(i for i, (ti, _) in enumerate(self.history) if ti <= t + TIME_EPS)
        t_s, stored = self.history[at]
        current = self.est
        if not isinstance(current, GaussianEstimate) or not isinstance(stored, GaussianEstimate):
            raise TypeError(f"the OOSM update needs a Gaussian filter, got {type(current).__name__}")
        self.est = self.al1.update(current, self.t, stored, t_s, min(t, self.t), scan)
        self.history[-1] = (self.t, self.est)
        self.counts.late += 1
        self.counts.lag_events.append(len(self.history) - 1 - at)

    def fused(self, k: int, t_k: float, fused: Estimate, refuse: Refuse) -> None:
        super().fused(k, t_k, fused, refuse)
        self.history.append((t_k, fused))
        # keep the last estimate at or before t - max_lag (a detection just within the lag needs one) and all after
        while len(self.history) > 1 and older(self.history[1][0], self.t - self.max_lag):
            self.history.pop(0)
