"""The live tracker's method: a **fixed lag** L (``node/diffusion/local_step.py`` ``window_step``,
``node/detections.py``).

Fusion step k runs at wall time ``t_k + L``: it takes, in measurement-time order, every detection of its window
``[t_(k-1), t_k)`` that has arrived, updates at each one's own time, predicts to ``t_k``
(:meth:`~zentrack.study.async_methods.base.NodeModel.over`, i.e. :func:`~zentrack.fusion.filters.interval.update_at_times`,
what the tracker's ``Tracker.update_over`` calls), publishes that estimate and fuses it. A detection that arrives
after its window was taken is counted too old and dropped. The simulation keeps the windows' rule; the tracker's
intake adds what a process needs and a simulation does not (hostile time, rate limits, duplicates, clock
estimation).
"""
from __future__ import annotations

import bisect
import itertools

from zentrack.fusion.estimates import Estimate
from zentrack.fusion.scan import Scan

from .base import TIME_EPS, AsyncMethod, NodeModel, older

#: the live tracker's lag in the bench (s)
DEFAULT_LAG_S = 0.35


class FixedLag(AsyncMethod):
    """Windows of measurement time, each processed ``lag`` seconds after it closes (module docstring)."""

    name = "fixed-lag"
    label = "fixed lag"
    takes = ("lag",)

    def __init__(self, node: NodeModel, prior: Estimate, t0: float = 0.0, lag: float = DEFAULT_LAG_S) -> None:
        super().__init__(node, prior, t0)
        self.publish_lag = float(lag)
        self._kept: list[tuple[float, int, Scan]] = []  # (time, arrival order, scan), in time order
        self._order = itertools.count()

    def detection(self, t: float, scan: Scan) -> None:
        self.counts.arrived += 1
        if older(t, self.t):  # its window is processed: too old
            self.counts.too_old += 1
            return
        bisect.insort(self._kept, (t, next(self._order), scan), key=lambda e: (e[0], e[1]))

    def share(self, k: int, t_k: float) -> Estimate:
        cut = bisect.bisect_left([e[0] for e in self._kept], t_k - TIME_EPS)  # the window is [t_(k-1), t_k)
        taken, self._kept = self._kept[:cut], self._kept[cut:]
        self.counts.applied += len(taken)
        return self.node.over(self.est, self.t, t_k, [(t, scan) for t, _, scan in taken])
