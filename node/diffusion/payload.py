"""The single-target payload: one target tracked by the five seed systems' diffusion, driven by the schedule.

One step k, realtime: the measurement of step k arrives (or the coast deadline passes: predict only) →
[rules that exchange scans: forward the own scan on ``scan/<i>``, wait for the neighbours' until the scan
deadline] → local update, the estimate goes out on ``est`` → [rules with ``relay_scans``: relay the
neighbours' scans, wait for theirs, update the prior with the two-hop scans too] → the time update is the
round-1 message for k + 1 on ``prior`` (at once, or held until step k's deadline when fusion follows it) →
fuse each round once every live neighbour's message is in or at the round's deadline → step k + 1. A round
fused without every live neighbour's message counts as ``partial_rounds``; each round's duration goes out with
the next estimate (``round_ms``). Lockstep has no deadlines: nothing coasts, nothing warms, and a node waits
for every participating neighbour. A relay node (no sensor) never counts as stale.

The payload holds its parts and calls them: the step's state (``state.py``), what it admits (``admission.py``),
the local step (``local_step.py``), the rounds (``rounds.py``), the warm start (``warm_start.py``), the fusion
policy (``fusion_policy.py``), the estimation state (``tracker.py``) and the counters (``node/counters.py``).
"""
from __future__ import annotations

import math

from zentrack.config.node_config import NodeConfig
from zentrack.node.context import NodeContext
from zentrack.node.counters import Counters
from zentrack.node.detections import DetectionIntake, SensorLink
from zentrack.node.diffusion.admission import Admission, Buffers
from zentrack.node.diffusion.fusion_policy import FusionPolicy
from zentrack.node.diffusion.local_step import LocalStep
from zentrack.node.diffusion.neighbour_clocks import NeighbourClocks
from zentrack.node.diffusion.rounds import Rounds
from zentrack.node.diffusion.state import StepState
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.diffusion.warm_start import COLD_AFTER_STEPS, WarmStart
from zentrack.node.phases import Phase
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.transport.codec import Message, WireError
from zentrack.transport.detection_messages import Detection
from zentrack.transport.messages import Start

__all__ = ["DiffusionPayload"]


class DiffusionPayload:
    """Node ``tracker.id``'s single-target steps (module docstring)."""

    def __init__(self, ctx: NodeContext, cfg: NodeConfig, tracker: Tracker, cold_after: int = COLD_AFTER_STEPS) -> None:
        self.ctx, self.tracker = ctx, tracker
        self.state = StepState()
        self.counters = Counters()
        self.buffers = Buffers()
        #: sensors of their own: the tracker runs on its own clock, its neighbours' offsets estimated (or taken as
        #: synchronised, ``clock = "configured"``: ``neighbour_clocks.py``); None: the run's clock
        self.clocks = None if cfg.detections is None else NeighbourClocks(
            ctx.id, tracker.neighbours, cfg.ts, estimated=cfg.detections["clock"] == "estimated")
        self.admission = Admission(tracker, self.counters, self.buffers, self.clocks)
        self.policy = FusionPolicy(ctx.id, ctx.lockstep, tracker.gate, self.counters)
        self.exchange = tracker.rule.exchanges_scans  # forward scans to the neighbours before the update
        self.rounds = Rounds(ctx, self.state, tracker, self.buffers, self.counters, self.policy)
        self.warm = WarmStart(ctx, self.state, tracker, self.buffers, self.counters, self.policy, self.rounds,
                              cold_after)
        #: sensors of their own (``node/detections.py``); None: the truth's measurements on ``meas/<i>``
        self.intake = None if cfg.detections is None else DetectionIntake(
            [SensorLink(**link) for link in cfg.detections["sensors"]])
        if self.intake is not None:  # a 1 Hz sensor leaves a 10 Hz tracker 9 steps of 10 without a detection:
            # stale only after its fastest sensor's period on top of what a synchronous tracker allows
            self.rounds.max_coast_steps += math.ceil(self.intake.period_s / cfg.ts - 1e-9)
            self.rounds.own_clock = True
        self.local = LocalStep(ctx, self.state, tracker, self.buffers, self.counters, self.rounds, self.warm,
                               relay=cfg.role == "relay", snapshot=self.snapshot, intake=self.intake)

    # ------------------------------------------------------------------ the payload interface
    @property
    def step(self) -> int:
        return self.state.step

    @property
    def measurement_dim(self) -> int:
        return self.tracker.measurement_dim

    @property
    def stale(self) -> bool:
        return self.rounds.stale

    def subscriptions(self) -> list[tuple[str, str]]:
        """Its measurements, the neighbours' round messages and (rules that exchange scans) their scans."""
        keys, neighbours, node = self.ctx.keys, self.tracker.neighbours, self.ctx.id
        own = [(keys.meas(node), "meas")] if self.intake is None else [(keys.det(s), "det") for s in self.intake.sensors]
        return [*own, *[(keys.prior(j), "prior") for j in neighbours],
                *[(keys.scan(j), "scan") for j in (neighbours if self.exchange else [])]]

    def publications(self) -> dict[str, tuple[str, bool]]:
        """Round messages and scans at once, estimates batched."""
        keys, node = self.ctx.keys, self.ctx.id
        return {"prior": (keys.prior(node), True), "est": (keys.est(node), False), "scan": (keys.scan(node), True)}

    def flood_rate(self) -> float:
        """4x the most a neighbour sends per key (a prior per round and step, at the run's wall-clock period once
        the start is known), plus 20."""
        period = self.ctx.timing.ts if self.ctx.timing.ts else 0.1
        return 4.0 * (max(1, self.tracker.rounds(1)) + 1) / period + 20.0

    def snapshot_parts(self) -> tuple[dict, dict]:
        extra: dict = {"refused": dict(self.tracker.refused)}
        if self.intake is not None:  # (a map of counts: ``COUNTER_MAPS`` on the wire)
            extra["detections"] = {**self.intake.counts.__dict__, "gated": self.tracker.gated_detections}
        return dict(self.counters.__dict__), extra

    def detection_period_s(self) -> float | None:
        return None if self.intake is None else self.intake.period_s

    def report_parts(self) -> dict:
        """Sensors of their own: each sensor's and each neighbour's clock offset to this tracker's as applied now
        (s; None before any sample)."""
        if self.intake is None or self.clocks is None:
            return {}
        return {"sensor_offsets_s": {str(s): self.intake.offset(s) for s in self.intake.sensors},
                "neighbour_offsets_s": self.clocks.report()}

    def snapshot(self) -> dict:
        return self.ctx.snapshot(*self.snapshot_parts())

    def take_start(self, start: Start) -> None:
        try:
            self.tracker.set_initial(start.x0)
        except ValueError as exc:
            raise WireError("shape", f"start: {exc}") from None

    def begin(self, fresh: bool, now: float) -> None:
        ctx = self.ctx
        assert ctx.participants is not None  # set with the start
        if fresh and ctx.id in ctx.participants:
            self.tracker.cold_start(0)
            self.state.enter(Phase.AWAIT_MEAS)
            self.state.step = 0
            self.local.log_start(len(ctx.participants))
        else:
            self.warm.start_warming(now)

    def due(self, now: float) -> float | None:
        """When the phase stops waiting: the coast deadline, the scan or relay deadline, the held round 1, the
        settle time then the round's deadline, or the end of the warming node's fusion window."""
        state, timing, rounds_next = self.state, self.ctx.timing, self.tracker.rounds(self.state.step + 1)
        phase = state.phase
        if phase is Phase.FUSING:
            if state.hold_until is not None:
                return state.hold_until
            settle = self.rounds.settle_until()  # a wake-up then fuses a complete round
            return settle if now < settle else state.round_deadline
        if phase is Phase.AWAIT_MEAS:
            return timing.deadline(state.step) - COAST_MARGIN_S
        if phase is Phase.AWAIT_SCANS:
            return timing.scan_deadline(state.step, rounds_next)
        if phase is Phase.AWAIT_RELAYS:
            return timing.relay_deadline(state.step, rounds_next)
        if phase is Phase.WARMING and state.fuse_step is not None:
            return timing.fusion_window_end(state.fuse_step)
        return None

    def advance(self, now: float) -> bool:
        before, phase = self.state.marker(), self.state.phase
        if phase is Phase.AWAIT_MEAS:
            self.local.try_step(now)
        elif phase is Phase.AWAIT_SCANS:
            self.local.try_scans(now)
        elif phase is Phase.AWAIT_RELAYS:
            self.local.try_relays(now)
        elif phase is Phase.FUSING:
            self.rounds.try_fuse(now)
        elif phase is Phase.WARMING:
            self.warm.try_warm(now)
        return self.state.marker() != before

    def admit(self, msg: Message) -> None:
        """A measurement, a neighbour's round message or its forwarded or relayed scan (``admission.py``)."""
        tag, timing, state = msg.tag, self.ctx.timing, self.state
        if tag == "det":
            self.admit_detection(msg)
            return
        sender = None
        if tag != "meas":
            sender = self.ctx.keys.node_of(msg.key)
            if sender is None or (tag == "scan" and sender not in self.tracker.neighbours):
                raise WireError("sender_mismatch", f"{tag} on key {msg.key!r}")
        if tag == "prior":
            assert sender is not None
            lo, hi = timing.prior_window(state.fused_upto, msg.t_recv)
            fusing = (state.fuse_step, state.fuse_round) \
                if state.phase is Phase.FUSING and state.fuse_step is not None else None
            self.admission.prior(msg, sender, lo, hi, state.fused_upto, fusing, timing)
            return
        lo, hi = timing.meas_window(state.step + (state.phase is Phase.FUSING), msg.t_recv)
        if tag == "meas":
            self.admission.measurement(msg, lo, hi)
        elif tag == "scan":
            assert sender is not None
            self.admission.scan(msg, sender, lo - 1, hi)

    def admit_detection(self, msg: Message) -> None:
        """A detection of one of this tracker's sensors (``node/detections.py``): kept for the window of its time,
        counted too old when that window is gone."""
        assert self.intake is not None
        sensor = self.ctx.keys.node_of(msg.key)
        if sensor is None or sensor not in self.intake.sensors:
            raise WireError("sender_mismatch", f"det on key {msg.key!r}")
        det = Detection.decode(msg.payload, sensor, self.tracker.measurement_dim)
        self.admission.check_returns(det.returns, f"detection {det.seq} of sensor {sensor}")
        timing, state = self.ctx.timing, self.state
        processed = None
        if timing.t0 is not None:  # the end of the last window taken (step k's starts at t0 + (k - 1) ts)
            processed = timing.t0 + max(state.step - 1 + (state.phase is Phase.FUSING), 0) * timing.ts
        self.intake.admit(det, msg.t_recv, processed)
