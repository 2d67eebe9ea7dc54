"""A many-target tracker's sensors of their own (issue 52): their detections taken in fixed-lag windows.

As the single-target tracker's (``node/diffusion/local_step.py``, ``window_step``), step k takes the detections
whose measurement time on the tracker's clock falls in its window ``[t_(k-1), t_k)``, ``t_k = t0 + k ts``, once
the lag after it is over (at ``t_k + lag``: the schedule's budget, ``NodeContext`` adds ``lag_ms``), in
measurement-time order: every track is predicted to each scan's time over that interval, the scan associated and
taken in, then every track predicted to ``t_k``
(:meth:`~zentrack.fusion.multitarget.network.NetworkTracker.local_step_over`). The track list of step k is valid
at ``t_k`` and is fused with the neighbours' lists as a synchronous one is. A scan without returns is a look that
saw nothing: it counts as a miss for the tracks it did not detect, as on the run's grid.

What is kept, refused (``future``, ``stale``, ``rate``, ``duplicate``, ``sender_mismatch``), too old or out of order,
and each sensor's clock offset, are :class:`~zentrack.node.detections.DetectionIntake`'s, unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

from zentrack.fusion.multitarget.network import NetworkTracker
from zentrack.fusion.scan import Scan
from zentrack.node.context import NodeContext
from zentrack.node.detections import DetectionIntake, SensorLink
from zentrack.transport.codec import Message, WireError
from zentrack.transport.detection_messages import Detection


@dataclass(frozen=True)
class WindowStep:
    """What one window step did: its scans, and the last one's publication and arrival times (tracker clock;
    None without a scan): what the track list carries for the latency."""

    scans: int
    t_meas_pub: float | None
    t_recv: float | None


class DetectionWindows:
    """Node ``ctx.id``'s detections of the sensors ``links`` (module docstring); ``measurement_dim``: a return's
    width."""

    def __init__(self, ctx: NodeContext, links: list[SensorLink], measurement_dim: int) -> None:
        self.ctx, self.measurement_dim = ctx, measurement_dim
        self.intake = DetectionIntake(links)

    def fastest_hz(self) -> float:
        """The highest rate of its sensors (Hz)."""
        return 1.0 / self.intake.period_s

    def subscriptions(self) -> list[tuple[str, str]]:
        return [(self.ctx.keys.det(s), "det") for s in self.intake.sensors]

    def window(self, k: int) -> tuple[float, float]:
        """Step k's window of measurement times on the tracker's clock, ``[t_(k-1), t_k)`` (step 0: none)."""
        timing = self.ctx.timing
        assert timing.t0 is not None
        t_to = timing.t0 + k * timing.ts
        return (t_to - timing.ts if k > 0 else t_to), t_to

    def due(self, k: int) -> float:
        """When step k's window is taken: its end plus the lag."""
        return self.ctx.timing.start() + k * self.ctx.timing.ts

    def admit(self, msg: Message, step: int, listed: bool) -> None:
        """A detection of one of this tracker's sensors, kept for the window of its time; ``step``: the node's
        current step, ``listed``: whether its window is taken already (its list is out)."""
        sensor = self.ctx.keys.node_of(msg.key)
        if sensor is None or sensor not in self.intake.sensors:
            raise WireError("sender_mismatch", f"det on key {msg.key!r}")
        det = Detection.decode(msg.payload, sensor, self.measurement_dim)
        timing = self.ctx.timing
        processed = None
        if timing.t0 is not None:  # the end of the last window taken (step k's starts at t0 + (k - 1) ts)
            processed = timing.t0 + max(step - 1 + listed, 0) * timing.ts
        self.intake.admit(det, msg.t_recv, processed)

    def step(self, network: NetworkTracker, k: int) -> WindowStep:
        """Step k of ``network`` on its window's detections, from its tracks of its last step."""
        t_from, t_to = self.window(k)
        taken = self.intake.take(t_from, t_to)
        timed = [(d.t, Scan(k, d.det.sensor, d.det.returns, d.det.pose, d.det.noise_cov)) for d in taken]
        last, timing = network.step, self.ctx.timing
        assert timing.t0 is not None
        network.local_step_over(k, t_from if last is None else timing.t0 + last * timing.ts, t_to, timed)
        if not taken:
            return WindowStep(0, None, None)
        det = taken[-1]  # (its publication time on the tracker's clock: its sensor's offset taken off, as its time's)
        return WindowStep(len(taken), det.det.t_pub - (self.intake.offset(det.det.sensor) or 0.0), det.t_recv)

    def counts(self) -> dict[str, int]:
        """The intake's counts (a map of counts on the wire: ``COUNTER_MAPS``)."""
        return dict(self.intake.counts.__dict__)

    def offsets(self) -> dict[str, float | None]:
        """Each sensor's clock offset as applied now (s; None before any sample)."""
        return {str(s): self.intake.offset(s) for s in self.intake.sensors}
