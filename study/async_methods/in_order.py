"""Detections applied on arrival: **drop late** (what is older than the estimate is lost) and its reference, **zero
latency** (every detection arrives at its measurement time, in time order, so nothing is late)."""
from __future__ import annotations

from zentrack.fusion.scan import Scan
from zentrack.truth.simulation.sensor_stream import SimulatedDetection

from .base import AsyncMethod, older


class DropLate(AsyncMethod):
    """Each detection is applied on arrival if it is not older than the estimate (predicted to its time, updated),
    else dropped and counted. Every fusion moves the estimate to the tick's time, so a detection that arrives after
    a tick later than its measurement is dropped too."""

    name = "drop-late"
    label = "drop late"

    def detection(self, t: float, scan: Scan) -> None:
        self.counts.arrived += 1
        if older(t, self.t):
            self.counts.dropped += 1
            return
        self.est = self.node.correct(self.node.predict(self.est, t - self.t), [scan])
        self.t = max(self.t, t)
        self.counts.applied += 1


class ZeroLatency(DropLate):
    """The reference: every detection arrives at its measurement time (in time order), so none is ever late."""

    name = "zero-latency"
    label = "zero latency (reference)"

    def arrival(self, det: SimulatedDetection) -> float:
        return det.t
