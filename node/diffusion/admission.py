"""Which message a tracker accepts for which step, and why not: decoding, step windows, duplicates, floods.

Every message is decoded by its wire type (every field checked, ``zentrack/transport/messages.py``), then admitted
against what the node knows: the step window its timing allows (``node/timing.py``), the rounds its rule has,
the scans its filter takes, who may relay whose scans (its configuration lists its neighbours' neighbours).
A refused message raises :class:`~zentrack.transport.wire.WireError` with its reason; the schedule counts it
and keeps running. An accepted one waits in :class:`Buffers` until its step is processed. A genuine message
that comes after its step (or round) was used is counted ``late``, not refused.

Round messages (realtime) and forgeries. Without authentication (insecure mode) a receiver cannot tell a
sender's message from a forged copy, so neither arrival order nor the number of copies may decide:

- a round message for step s cannot be genuine before step s - 1 is sampled (its sender's time update needs
  the measurement of s - 1, which the truth publishes then): one that arrives more than
  :data:`EARLY_TOLERANCE_STEPS` of a period before that is refused as ``early`` (:func:`earliest_round_message`);
- each (step, round, sender) keeps the first two distinct messages; two are a **conflict** (neither is fused,
  ``node/diffusion/fusion_policy.py``), and every further distinct one is refused as a ``conflict`` at once. Nothing a
  forger sends can evict the real message; an exact replay is a ``duplicate``. (Sensors of their own: a message of
  another step of its sender, mapped to the same step of this tracker's after the estimate of the sender's clock
  moved by a period, takes the place of those held, ``neighbour_clocks.py``; a forger must move that estimate,
  a fifth of its samples, to do the same.)
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from zentrack.node.counters import Counters
from zentrack.node.diffusion.neighbour_clocks import (
    VALIDITY_SLACK_S,
    NeighbourClocks,
    predicted_blocks,
    prior_valid_at,
)
from zentrack.node.diffusion.tracker import NUMERIC_ERRORS, Pair, Tracker
from zentrack.node.intake import StepSlots, own_measurement
from zentrack.node.timing import StepTiming
from zentrack.transport.codec import MAX_ROUNDS, Message, WireError, check_step
from zentrack.transport.messages import Measurement, RoundMessage
from zentrack.transport.scan_messages import ForwardedScan, Relay, decode_scan_key

#: distinct messages kept per (step, round, sender): two are already a conflict (neither is fused)
MAX_COPIES = 2
#: a round message for step s is refused as early when it arrives more than this part of a period before the
#: sample time of step s - 1 (room for the clocks' residual offset and scheduling jitter)
EARLY_TOLERANCE_STEPS = 0.25


def earliest_round_message(timing: StepTiming, s: int) -> float | None:
    """The earliest arrival time of a genuine round message for step ``s`` (realtime; None in lockstep, which
    has no clock): the run's sample time of step s - 1 (``t0``, without the node's latency budget: a sender
    can update as soon as its measurement is in), less :data:`EARLY_TOLERANCE_STEPS` periods."""
    if not timing.realtime or timing.t0 is None:
        return None
    return timing.t0 + (s - 1 - EARLY_TOLERANCE_STEPS) * timing.ts


@dataclass(slots=True)
class Arrival:
    """The node's own measurement of a step and when it arrived (wall clock)."""

    meas: Measurement
    t_recv: float


@dataclass
class Buffers:
    """What a node holds between arrival and use, by step."""

    meas: dict[int, Arrival] = field(default_factory=dict)  #: step -> own measurement, with its receive time
    #: (step, round) -> sender -> the distinct round messages received
    priors: defaultdict[tuple[int, int], dict[int, list[Pair]]] = field(default_factory=lambda: defaultdict(dict))
    fwd: StepSlots[ForwardedScan] = field(default_factory=lambda: StepSlots("scan"))  #: step -> sender -> scan
    relayed: StepSlots[Relay] = field(default_factory=lambda: StepSlots("relay"))  #: step -> sender -> relay

    def drop_before(self, step: int, priors_only: bool = False) -> None:
        for key in [key for key in self.priors if key[0] < step]:
            del self.priors[key]
        if not priors_only:
            self.fwd.drop_before(step)
            self.relayed.drop_before(step)
            for k in [k for k in self.meas if k < step]:
                del self.meas[k]


class Admission:
    """Node ``tracker.id``'s admission of measurements, round messages and forwarded or relayed scans."""

    def __init__(self, tracker: Tracker, counters: Counters, buffers: Buffers,
                 clocks: NeighbourClocks | None = None) -> None:
        self.tracker, self.counters, self.buffers = tracker, counters, buffers
        #: sensors of their own: the neighbours' clocks (``neighbour_clocks.py``); None: on the run's clock
        self.clocks = clocks

    def check_returns(self, returns: np.ndarray | None, what: str) -> None:
        """A scan with more returns than this node's filter takes is refused, not fed to the filter."""
        cap = self.tracker.max_returns
        if returns is not None and cap is not None and returns.shape[0] > cap:
            raise WireError("shape", f"{what}: {returns.shape[0]} returns, this node's filter "
                                     f"({self.tracker.cfg.filter}) takes at most {cap} per scan")

    def measurement(self, msg: Message, lo: int, hi: int) -> None:
        """The node's own scan for a step in ``[lo, hi]``: one per step."""
        m = own_measurement(msg, self.tracker.id, self.tracker.measurement_dim, lo, hi)
        self.check_returns(m.returns, f"measurement of step {m.k}")
        if m.k in self.buffers.meas:
            raise WireError("duplicate", f"second measurement for step {m.k}")
        self.buffers.meas[m.k] = Arrival(m, msg.t_recv)
        self.counters.meas_rx += 1

    def prior(self, msg: Message, sender: int, lo: int, hi: int, fused_upto: int,
              fusing: tuple[int, int] | None, timing: StepTiming) -> None:
        """Node ``sender``'s round message for a step in ``[lo, hi]``; ``fusing``: the (step, round) being
        fused, whose earlier rounds are over. Sensors of their own (``clocks``): its step and time mapped from the
        sender's clock to this tracker's first (``neighbour_clocks.py``)."""
        tracker, clocks = self.tracker, self.clocks
        if clocks is None:
            p = RoundMessage.decode(msg.payload, sender, tracker.block_dims, lo, hi, max_round=MAX_ROUNDS)
            k, offset = p.k, 0.0
        else:  # the sample first, whatever the step: the mapping needs it
            p = RoundMessage.decode(msg.payload, sender, tracker.block_dims, max_round=MAX_ROUNDS)
            clocks.observe(sender, msg.t_recv, p.t_pub, (p.k, p.round))
            if abs(p.t - prior_valid_at(p.k, timing.ts)) > VALIDITY_SLACK_S:
                raise WireError("schema", f"node {sender}'s prior for step {p.k} says it is valid at {p.t:.6g} s, "
                                          f"not at the start of its window ({prior_valid_at(p.k, timing.ts):.6g} s)")
            k, offset = clocks.own_step(sender, p.k), clocks.offset(sender)
            check_step({"k": k}, lo, hi)
        rnd = p.round
        if rnd > tracker.rounds(k):
            raise WireError("schema", f"round {rnd} of step {k}: this run's rule has {tracker.rounds(k)}")
        earliest = earliest_round_message(timing, p.k)  # (on the sender's clock: its step, its time)
        if earliest is not None and msg.t_recv + offset < earliest:
            early_ms = (earliest - msg.t_recv - offset) * 1e3
            raise WireError("early", f"node {sender}'s prior for step {p.k} came {early_ms:.0f} ms before its sender "
                                     "could have made it")
        if k <= fused_upto or (fusing is not None and k == fusing[0] and rnd < fusing[1]):
            self.counters.late += 1  # a genuine message that came after we fused that step or round
            return
        copies = self.buffers.priors[(k, rnd)].setdefault(sender, [])
        if clocks is not None and copies and all(c.sent_step != p.k for c in copies):
            copies.clear()  # its sender's other step, mapped here by an earlier estimate of its clock: this one wins
        if any(c.raw == msg.payload for c in copies):
            raise WireError("duplicate", f"second copy of node {sender}'s prior for step {k} round {rnd}")
        if len(copies) >= MAX_COPIES:
            raise WireError("conflict", f"another different prior from node {sender} for step {k} round {rnd} "
                                        f"(it already conflicts)")
        blocks = p.blocks
        if clocks is not None:  # valid at this tracker's time of step k's prior
            try:
                blocks = predicted_blocks(tracker, blocks, clocks.lead(sender, k, p.t))
            except NUMERIC_ERRORS as exc:
                raise WireError("shape", f"node {sender}'s prior for step {p.k}: {exc}") from None
        copies.append(Pair(k, blocks, warm=p.warm, round=rnd, raw=msg.payload, sent_step=p.k))
        self.counters.prior_rx += 1

    def scan(self, msg: Message, key_node: int, lo: int, hi: int) -> None:
        """A neighbour's forwarded scan, or its relay of its own neighbours' scans, for a step in ``[lo, hi]``."""
        tracker, buffers = self.tracker, self.buffers
        sc = decode_scan_key(msg.payload, key_node, tracker.measurement_dim, lo, hi)
        sender, k = sc.sender, sc.k
        if isinstance(sc, Relay):
            if not tracker.rule.relays_scans:
                raise WireError("unexpected", f"relay from node {sender}: this run's rule relays no scans")
            links = tracker.cfg.neighbour_links.get(sender)
            for entry in sc.scans:  # node j relays its own neighbours' scans, nobody else's
                origin = entry.origin
                if not 0 <= origin < tracker.cfg.nodes or (links is not None and origin not in links):
                    raise WireError("sender_mismatch", f"relay from node {sender}: origin {origin} is not "
                                                       f"one of its neighbours")
                self.check_returns(entry.returns, f"relay from node {sender}: scan of origin {origin}")
            if buffers.relayed.late(k):  # a copy of a relay this node already used (or gave up on)
                self.counters.late += 1
                return
            buffers.relayed.put(k, sender, sc)
            self.counters.relays_rx += 1
            return
        sc.check_origin(sender)
        self.check_returns(sc.returns, f"scan from node {sender}")
        if buffers.fwd.late(k):
            self.counters.late += 1
            return
        buffers.fwd.put(k, sender, sc)
