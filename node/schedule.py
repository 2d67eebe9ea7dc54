"""A tracker's schedule as a state machine free of I/O: what to do with each message and when to act.

:class:`NodeSchedule` is fed messages (:meth:`~NodeSchedule.handle`) and wake-ups (:meth:`~NodeSchedule.advance`);
the time comes from an injected clock and every publication goes through an injected ``send(channel,
payload)``, so the whole schedule runs in unit tests without Zenoh (``node/process.py`` only moves bytes).
It composes small parts, each with its own module and tests:

- ``phases.py``: the phases of a step and the table of allowed transitions;
- ``timing.py``: deadlines, the fusion window and round deadlines from the run's t0 and period;
- ``admission.py``: which message is accepted for which step (windows, duplicates, floods), and the buffers;
- ``fusion_policy.py``: which neighbours' messages a round fuses (gate, equivocation, outvote);
- ``relays.py``: relayed two-hop scans; ``warm_start.py``: how a warming node rejoins;
- ``run_control.py``: membership (liveliness), the run's start and stop; ``counters.py``: what is counted.

One step k, realtime: the measurement of step k arrives (or the coast deadline passes: predict only) →
[rules that exchange scans: forward the own scan on ``scan/<i>``, wait for the neighbours' until the scan
deadline] → local update, the estimate goes out on ``est`` → [rules with ``relay_scans``: relay the
neighbours' scans, wait for theirs, update the prior with the two-hop scans too] → the time update is the
round-1 message for k + 1 on ``prior`` (at once, or held until step k's deadline when fusion follows it) →
fuse each round once every live neighbour's message is in or at the round's deadline → step k + 1. A round
fused without every live neighbour's message counts as ``partial_rounds``; each round's duration goes out with
the next estimate (``round_ms``). Lockstep has no deadlines: nothing coasts, nothing warms, and a node waits
for every participating neighbour. A relay node (no sensor) never counts as stale. Measurements that arrive
before ``ctl/start`` are kept (a few steps' worth) and handled when it comes.
"""
from __future__ import annotations

import logging
from collections.abc import Callable

from zentrack.config.node_config import NodeConfig
from zentrack.fusion.estimates import Estimate
from zentrack.fusion.scan import Scan
from zentrack.node.admission import EARLY_KEPT, MAX_COPIES, Admission, Arrival, Buffers
from zentrack.node.counters import COUNTERS_EVERY_STEPS, Counters, RejectLog, snapshot
from zentrack.node.fusion_policy import OUTVOTED_STREAK, FusionPolicy
from zentrack.node.phases import Phase
from zentrack.node.run_control import STOP_CONFIRM_S, ControlledRun, Membership, StopConfirm, start_conflicts
from zentrack.node.timing import COAST_MARGIN_S, FUSION_MARGIN_S, REALTIME_FUTURE_STEPS, StepTiming
from zentrack.node.tracker import Pair, Tracker
from zentrack.node.warm_start import COLD_AFTER_STEPS, WarmStart
from zentrack.transport.codec import Message, WireError
from zentrack.transport.messages import Start
from zentrack.transport.miss_notes import MissNote

__all__ = ["COAST_MARGIN_S", "COLD_AFTER_STEPS", "COUNTERS_EVERY_STEPS", "EARLY_KEPT", "FUSION_MARGIN_S",
           "MAX_COPIES", "OUTVOTED_STREAK", "REALTIME_FUTURE_STEPS", "STOP_CONFIRM_S", "NodeSchedule", "Phase"]

log = logging.getLogger("zentrack.node")


class NodeSchedule(WarmStart, ControlledRun):
    """Node ``tracker.id``'s schedule. ``send(channel, payload)`` publishes on ``est``, ``prior`` or ``scan``."""

    def __init__(self, keys, cfg: NodeConfig, tracker: Tracker, clock: Callable[[], float],
                 send: Callable[[str, bytes], None], cold_after: int = COLD_AFTER_STEPS, incarnation: int = 0,
                 fusion_after_deadline: bool | None = None) -> None:
        self.keys, self.tracker, self.clock, self.send = keys, tracker, clock, send
        self.incarnation, self.id, self.mode, self.cold_after = incarnation, tracker.id, cfg.mode, cold_after
        self.timing = StepTiming(cfg.mode, cfg.deadline_frac, cfg.ts, after_deadline=fusion_after_deadline,
                                 budget=cfg.latency_budget_ms / 1000)
        self.relay = cfg.role == "relay"
        self.exchange = tracker.rule.exchanges_scans  # forward scans to the neighbours before the update
        self.counters = Counters()
        self.rejects = RejectLog(self.id, clock)
        self.buffers = Buffers()
        self.admission = Admission(tracker, self.counters, self.buffers)
        self.policy = FusionPolicy(self.id, self.mode == "lockstep", tracker.gate, self.counters)
        self.members = Membership()
        self.stop_confirm = StopConfirm()
        self.dropped: dict[str, int] = {}  # dropped before decoding by the process's flood guard (tag/reason)
        self.steps: int | None = None
        self.participants: set[int] | None = None
        self.start_payload: bytes | None = None  # truth's ctl/start as received, served to a restarted truth
        self.start_fields: Start | None = None  # ... and decoded: a later start must repeat it
        self.stopped = False
        self.phase = Phase.IDLE
        self.miss_notes: list[MissNote] = []
        self.idle_s = 0.0  # how much later than planned this wake-up came (a frozen or starved process)
        self.wake_due: float | None = None  # when the loop meant to wake (clock)
        self.step = 0  # the step being processed (await_meas) or whose measurement produced own_pair
        self.fuse_step: int | None = None
        self.fuse_round = 1
        self.own_pair: Pair | None = None
        self.pending: Arrival | None = None  # own measurement waiting for the neighbours' scans
        self.core_scans: list[Scan] = []  # the step's one-hop scans, waiting for the relayed ones
        self.post: Estimate | None = None  # the step's posterior, waiting for the relayed scans (await_relays)
        self.coast_run = 0  # consecutive steps without a measurement
        self.warm_published: int | None = None  # the step of the last warm pair published while warming
        self.empty_warm_steps = 0
        self.warm_next = False
        self.last_fused = 0
        self.fused_upto = 0  # the last step whose prior has been fused (the cold prior is step 0)
        self.round_started = 0.0  # when the round being fused began (its own message sent)
        self.round_deadline = 0.0  # when the round being fused stops waiting (realtime)
        self.round_ms: list[float] = []  # the durations of the rounds of the step being fused
        self.last_round_ms: list[float] = []  # ... and of the rounds that made the current prior
        self.hold_until: float | None = None  # realtime: when the held round-1 message goes out

    # ------------------------------------------------------------------ views of the parts
    t0 = property(lambda self: self.timing.t0)
    ts = property(lambda self: self.timing.ts, lambda self, v: setattr(self.timing, "ts", v))
    frac = property(lambda self: self.timing.frac, lambda self, v: setattr(self.timing, "frac", v))
    early = property(lambda self: self.buffers.early)
    live = property(lambda self: self.members.live)
    truth_gone_since = property(lambda self: self.members.truth_gone_since)

    @property
    def measurement_dim(self) -> int:
        return self.tracker.measurement_dim

    def subscriptions(self) -> list[tuple[str, str]]:
        """``(key, tag)`` of what the node hears besides the control keys: its measurements, the neighbours'
        round messages and (rules that exchange scans) their scans."""
        keys, neighbours = self.keys, self.tracker.neighbours
        return [(keys.meas(self.id), "meas"), *[(keys.prior(j), "prior") for j in neighbours],
                *[(keys.scan(j), "scan") for j in (neighbours if self.exchange else [])]]

    def publications(self) -> dict[str, tuple[str, bool]]:
        """channel -> ``(key, express)``: round messages and scans at once, estimates batched."""
        keys = self.keys
        return {"prior": (keys.prior(self.id), True), "est": (keys.est(self.id), False),
                "scan": (keys.scan(self.id), True)}

    def flood_rate(self) -> float:
        """Messages per second and key the flood guard lets through: 4x the most a neighbour sends per key (a
        prior per round and step, at the run's wall-clock period once the start is known), plus 20."""
        period = self.ts if self.ts else 0.1
        return 4.0 * (max(1, self.tracker.rounds(1)) + 1) / period + 20.0

    def fusion_after_deadline(self) -> bool:
        return self.timing.fusion_after_deadline()

    # ------------------------------------------------------------------ public interface
    def done(self) -> bool:
        return self.stopped or (self.mode == "lockstep" and self.steps is not None and self.step >= self.steps)

    def timeout(self) -> float:
        """How long to wait for a message before the next timed action (at most 0.2 s, at least 1 ms)."""
        timing = self.timing
        if self.mode != "realtime" or timing.t0 is None or (self.steps is not None and self.step >= self.steps):
            self.wake_due = None
            return 0.2
        now, phase = self.clock(), self.phase
        if phase is Phase.FUSING:
            if self.hold_until is not None:
                wait = self.hold_until - now
            else:  # the settle time first (a wake-up then fuses a complete round), then the deadline
                settle = self.settle_until()
                wait = (settle if now < settle else self.round_deadline) - now
        elif phase is Phase.AWAIT_MEAS:
            wait = timing.deadline(self.step) - COAST_MARGIN_S - now
        elif phase is Phase.AWAIT_SCANS:
            wait = timing.scan_deadline(self.step, self.tracker.rounds(self.step + 1)) - now
        elif phase is Phase.AWAIT_RELAYS:
            wait = timing.relay_deadline(self.step, self.tracker.rounds(self.step + 1)) - now
        elif phase is Phase.WARMING and self.fuse_step is not None:
            wait = timing.fusion_window_end(self.fuse_step) - now
        else:
            wait = 0.05
        wait = min(0.2, max(0.001, wait))
        self.wake_due = now + wait  # a wake-up much later than this: the process did not run (advance)
        return wait

    def handle(self, msg: Message) -> None:
        """One message: validated, then buffered or acted on; a bad one is counted under its reason."""
        try:
            tag = msg.tag
            if tag == "alive":
                self._on_alive(msg.key, msg.payload == b"put")
            elif tag == "start":
                self._on_start(Start.decode(msg.payload))
                self.start_payload = msg.payload
            elif tag == "stop":
                self._on_stop(msg.payload)
            elif tag in ("meas", "prior", "scan"):
                self._admit(msg)
        except WireError as err:
            self.rejects.add(msg.tag, err)

    def advance(self) -> None:
        """Take the transitions that are due now (a few per wake-up, e.g. fuse then a buffered measurement)."""
        self._check_pending_stop()
        self.idle_s = 0.0 if self.wake_due is None else max(0.0, self.clock() - self.wake_due)
        for _ in range(4):
            before = (self.phase, self.step, self.fuse_step, self.fuse_round)
            now, phase = self.clock(), self.phase
            if phase is Phase.AWAIT_MEAS:
                self._try_step(now)
            elif phase is Phase.AWAIT_SCANS:
                self._try_scans(now)
            elif phase is Phase.AWAIT_RELAYS:
                self._try_relays(now)
            elif phase is Phase.FUSING:
                self._try_fuse(now)
            elif phase is Phase.WARMING:
                self._try_warm(now)
            if (self.phase, self.step, self.fuse_step, self.fuse_round) == before:
                return

    def snapshot(self) -> dict:
        """The counters as published with every ``COUNTERS_EVERY_STEPS``-th estimate and in ``node-<i>.json``."""
        return snapshot(self.counters, self.rejects.counts, self.dropped, self.tracker.refused, self.incarnation)

    # ------------------------------------------------------------------ messages
    def _admit(self, msg: Message) -> None:
        """A measurement, a neighbour's round message or its forwarded or relayed scan (``node/admission.py``)."""
        tag, timing = msg.tag, self.timing
        sender = None
        if tag != "meas":
            sender = self.keys.node_of(msg.key)
            if sender is None or (tag == "scan" and sender not in self.tracker.neighbours):
                raise WireError("sender_mismatch", f"{tag} on key {msg.key!r}")
        if timing.t0 is None:  # before the start (a lost or late ctl/start): keep it for when the start comes
            self.buffers.keep_early(msg)
            return
        if tag == "prior":
            assert sender is not None
            lo, hi = timing.prior_window(self.fused_upto, msg.t_recv)
            fusing = (self.fuse_step, self.fuse_round) if self.phase is Phase.FUSING and self.fuse_step is not None else None
            self.admission.prior(msg, sender, lo, hi, self.fused_upto, fusing, timing)
            return
        lo, hi = timing.meas_window(self.step + (self.phase is Phase.FUSING), msg.t_recv)
        if tag == "meas":
            self.admission.measurement(msg, lo, hi)
        else:
            assert sender is not None
            self.admission.scan(msg, sender, lo - 1, hi)

    def _on_start(self, start: Start) -> None:
        if start.mode != self.mode:
            raise WireError("schema", f"run mode {start.mode} differs from this node's {self.mode}")
        if self.start_fields is not None:
            # the run is under way: a start can only repeat it (truth re-sends it when a node joins, a restarted
            # truth resumes it); one that moves t0, the timing, the participants or x0 is refused and counted
            diff = start_conflicts(start, self.start_fields)
            if diff:
                raise WireError("conflict", f"a start that contradicts the run under way ({', '.join(diff)})")
            return
        try:
            self.tracker.set_initial(start.x0)
        except ValueError as exc:
            raise WireError("shape", f"start: {exc}") from None
        self.timing.t0, self.steps, self.timing.ts = start.t0, start.steps, start.ts
        self.participants = set(start.participants)
        self.start_fields = start
        now = self.clock()
        fresh = self.mode == "lockstep" or now < self.timing.deadline(0) - COAST_MARGIN_S
        if fresh and self.id in self.participants:
            self.tracker.cold_start(0)
            self._enter(Phase.AWAIT_MEAS)
            self.step = 0
            log.info("node %d: cold start, %d participants", self.id, len(self.participants))
        else:
            self._start_warming(now)
        early, self.buffers.early = self.buffers.early, []
        for msg in early:  # messages that came before the start
            self.handle(msg)
