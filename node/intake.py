"""What every tracker's admission shares, single- and many-target: the own measurement checked against the steps
it may carry, and a neighbour's message held one per step and sender.

Each payload's admission (``node/diffusion/admission.py``, ``node/track_lists/admission.py``) decides its own
windows and message kinds and calls these; a refused message raises
:class:`~zentrack.transport.codec.WireError` naming why, a genuine one that came after its step was used is
counted ``late`` by the caller.
"""
from __future__ import annotations

from typing import Generic, TypeVar

from zentrack.transport.codec import Message, WireError, check_step
from zentrack.transport.messages import Measurement

T = TypeVar("T")


def own_measurement(msg: Message, node: int, dim: int, lo: int, hi: int) -> Measurement:
    """Node ``node``'s measurement message for a step in ``[lo, hi]`` (decoded already by the run's clock, which
    takes its samples from measurements, or decoded here with every field checked)."""
    m = msg.decoded
    if type(m) is Measurement:  # decoded by the clock (no window): the window here
        check_step({"k": m.k}, lo, hi)
        return m
    return Measurement.decode(msg.payload, node, dim, lo, hi)


class StepSlots(Generic[T]):
    """Step -> sender -> the one message a sender may send for a step; ``done_upto``: the last step already used
    (a later copy of an earlier step is late)."""

    def __init__(self, what: str) -> None:
        self.what = what  #: what a slot holds, for the refusal's text ("scan", "relay", "list")
        self.by_step: dict[int, dict[int, T]] = {}
        self.done_upto = -1

    def late(self, k: int) -> bool:
        return k <= self.done_upto

    def put(self, k: int, sender: int, item: T) -> None:
        """Hold ``item``; a second one from the same sender for the same step is refused as a duplicate."""
        held = self.by_step.setdefault(k, {})
        if sender in held:
            raise WireError("duplicate", f"a second {self.what} from node {sender} for step {k}")
        held[sender] = item

    def get(self, k: int) -> dict[int, T]:
        return self.by_step.get(k, {})

    def take(self, k: int) -> dict[int, T]:
        """Step k's messages, now used: a copy that comes later is late."""
        self.done_upto = max(self.done_upto, k)
        return self.by_step.pop(k, {})

    def drop_before(self, step: int) -> None:
        for k in [k for k in self.by_step if k < step]:
            del self.by_step[k]

    def __contains__(self, k: int) -> bool:
        return k in self.by_step
