"""What a tracker's schedule drives: the payload interface and its two implementations.

:class:`~zentrack.node.schedule.NodeSchedule` owns the run (start, stop, liveliness, messages before the start,
wake-ups, counters); a payload owns what a step does. Two implement :class:`Payload`:

- :class:`~zentrack.node.diffusion.payload.DiffusionPayload`: one target, the five seed systems' scans, rounds
  of covariance intersection, relays and warm start (``node/diffusion/``);
- :class:`~zentrack.node.track_lists.payload.TrackListPayload`: many targets, a multi-target tracker whose
  track lists the neighbours fuse (``node/track_lists/``).
"""
from __future__ import annotations

from typing import Protocol

from zentrack.transport.codec import Message
from zentrack.transport.messages import Start


class Payload(Protocol):
    """A step's work, driven by the schedule (every time is the run's clock's, every send the context's)."""

    @property
    def step(self) -> int:
        """The step being processed: the run is over once it reaches the run's steps."""
        ...

    @property
    def measurement_dim(self) -> int:
        """The own measurement's dimension (the clock reads its samples from measurement messages)."""
        ...

    def subscriptions(self) -> list[tuple[str, str]]:
        """``(key, tag)`` of what the node hears besides the control keys."""
        ...

    def publications(self) -> dict[str, tuple[str, bool]]:
        """channel -> ``(key, express)`` of what the node publishes."""
        ...

    def flood_rate(self) -> float:
        """Messages per second and key the flood guard lets through."""
        ...

    def take_start(self, start: Start) -> None:
        """The run's first start, before the schedule takes its timing: raises
        :class:`~zentrack.transport.codec.WireError` for one the payload cannot take (it is refused)."""
        ...

    def begin(self, fresh: bool, now: float) -> None:
        """The run's start is taken; ``fresh``: the node starts with the run (else it joins it under way)."""
        ...

    def admit(self, msg: Message) -> None:
        """A data message after the start: kept for its step, or refused with a WireError naming why."""
        ...

    def advance(self, now: float) -> bool:
        """Take the transition that is due now, if any; True if the payload moved (the schedule asks again)."""
        ...

    def due(self, now: float) -> float | None:
        """Realtime: when the current phase next needs a wake-up (None: no timed action, poll)."""
        ...

    def snapshot_parts(self) -> tuple[dict, dict]:
        """The payload's counts and its extra fields for the counters' snapshot (``NodeContext.snapshot``)."""
        ...

    def detection_period_s(self) -> float | None:
        """Sensors of their own: the longest its sensors leave between two detections when all is well (the
        fastest one's period, s); None for a tracker of the truth's measurements."""
        ...

    def report_parts(self) -> dict:
        """What the final report (``node-<i>.json``) holds beside the counters: figures that are no counts
        (e.g. the sensors' estimated clock offsets), which the counters on the wire do not carry."""
        ...
