"""What a tracker counts: its step and message counters, and the log of refused messages by reason.

:class:`Counters` is published with every ``COUNTERS_EVERY_STEPS``-th estimate and written to
``node-<i>.json`` (:func:`snapshot`); :class:`RejectLog` counts every message a node refused, by the reason
:class:`~zentrack.transport.wire.WireError` names, and logs the first of each reason.
"""
from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

from zentrack.transport.wire import WireError

log = logging.getLogger("zentrack.node")

#: estimates carry the node's counters every this many steps (about 200 bytes and a dict build saved on the
#: others); a node that exits writes them all to ``node-<i>.json``, so only a killed node's last few steps of
#: counts can be missing from a run's summary
COUNTERS_EVERY_STEPS = 10


@dataclass
class Counters:
    """Every count a tracker keeps, all from zero at its (re)start."""

    meas_rx: int = 0  #: own measurement messages accepted
    prior_rx: int = 0  #: neighbours' round messages accepted (every distinct copy)
    late: int = 0  #: genuine messages that came after their step or round was fused
    coasted: int = 0  #: steps without a scan of the own sensor (predicted only)
    misses: int = 0  #: deadlines missed (a step skipped, an estimate or fusion after its deadline)
    steps: int = 0  #: estimates published
    warm_starts: int = 0  #: warm-ups that took the neighbours' pairs
    warm_self: int = 0  #: warm-ups that resumed from the node's own prediction and warm pairs
    cold_restarts: int = 0  #: warm-ups that gave up and took the configured initial prior
    partial_rounds: int = 0  #: fusion rounds fused at their deadline without every live neighbour's message
    relays_rx: int = 0  #: relays accepted (one per neighbour and step)
    partial_relays: int = 0  #: steps whose relays were used at the deadline without every live neighbour's
    relay_left_out: int = 0  #: relayed scans left out to keep a relay within the message cap
    gated: int = 0  #: neighbours' messages the gate refused
    conflicts: int = 0  #: round messages left out because their sender's (step, round) had another, different one
    outvoted: int = 0  #: rounds fused without the own message (the gate showed this node to be the odd one)
    gate_lifted: int = 0  #: rounds in which the node lifted its gate after a streak of refusals


def snapshot(counters: Counters, rejected: dict[str, int], dropped: dict[str, int], refused: dict[str, int],
             incarnation: int) -> dict:
    """The counters as they go out on the wire and into ``node-<i>.json`` (``incarnation`` tells a restarted
    process's counters from its predecessor's)."""
    return {**counters.__dict__, "rejected": dict(rejected), "dropped": dict(dropped), "refused": dict(refused),
            "incarnation": incarnation}


class RejectLog:
    """Counts rejections per reason; logs the first of each reason, then a summary at most every 5 s."""

    def __init__(self, node: int, clock: Callable[[], float]) -> None:
        self.node, self.clock = node, clock
        self.counts: dict[str, int] = defaultdict(int)
        self._since: dict[str, int] = defaultdict(int)
        self._last = -math.inf

    def add(self, where: str, err: WireError) -> None:
        first = self.counts[err.reason] == 0
        self.counts[err.reason] += 1
        self._since[err.reason] += 1
        now = self.clock()
        if first:
            log.warning("node %d: rejected %s message (%s); further rejections are summarised", self.node, where, err)
            self._since.clear()
            self._last = now
        elif now - self._last > 5.0 and self._since:
            log.warning("node %d: rejected in the last 5 s: %s", self.node, dict(self._since))
            self._since.clear()
            self._last = now
