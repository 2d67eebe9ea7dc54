"""Between the viewer's core (:class:`zentrack.viewer.core.Viewer`) and a payload part, the part that knows one
kind of run: what a part is given to draw on (:class:`Canvas`) and what it does for the core (:class:`Payload`).

Two parts: one target (:class:`~zentrack.viewer.single_target.SingleTarget`: estimates, covariance ellipsoids,
rays, rounds) and many (:class:`~zentrack.viewer.multi_target.MultiTarget`: track lists, trails, GOSPA). The core
and its part share one canvas: the core logs the events it handles on it and flushes it, the part draws.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys
from zentrack.viewer.columns import ColumnBuffer
from zentrack.viewer.layout import node_color


class Canvas:
    """A run's recording as the viewer draws it: the Rerun stream ``rec``, its column buffer (``ts`` the step's
    duration; ``kinds`` a part's own kinds of row), each node's colour, the latest step drawn, and the count of
    what was drawn per kind of message (``counts``, then ``bad``: messages refused), as the viewer reports them."""

    def __init__(self, rec: rr.RecordingStream, ts: float, nodes: int, counts: tuple[str, ...],
                 kinds: Mapping[str, Callable[[list], Any]] | None = None) -> None:
        self.rec = rec
        self.buf = ColumnBuffer(rec, ts, kinds)
        self.colors = [node_color(i, nodes) for i in range(nodes)]
        self.logged = {**dict.fromkeys(counts, 0), "bad": 0}
        #: the latest step drawn: where events land on the timelines
        self.current_step = 0

    @property
    def nodes(self) -> int:
        return len(self.colors)

    def reached(self, k: int) -> None:
        """Step k is drawn (the latest step moves on, never back)."""
        self.current_step = max(self.current_step, k)

    def at(self, k: int) -> None:
        """The timelines of what ``rec.log`` logs next: step k (``step``) at its sample time (``time``)."""
        self.reached(k)
        self.rec.set_time("step", sequence=k)
        self.rec.set_time("time", duration=k * self.buf.ts)

    def event(self, k: int, text: str, level: str) -> None:
        """A line of the event log (``events``) at step k."""
        self.at(k)
        self.rec.log("events", rr.TextLog(text, level=level))

    def log_sensors(self, positions: np.ndarray) -> None:
        """``world/sensors`` (static): each node's sensor in its colour, labelled ``s<i>``."""
        self.rec.log("world/sensors", rr.Points3D(positions, colors=self.colors, radii=-5.0,
                                                  labels=[f"s{i}" for i in range(self.nodes)]), static=True)

    def log_key(self, markdown: str) -> None:
        """``key`` (static): what the views show."""
        self.rec.log("key", rr.TextDocument(markdown, media_type="text/markdown"), static=True)


class Payload(Protocol):
    """One kind of run's part of the viewer, driven by the core: its subscriptions, its layout, its static
    entities, and every message of a run but the core's own (``alive``, ``stop``)."""

    def topics(self, keys: Keys) -> dict[str, str]:
        """The part's subscriptions besides the truth's: message tag -> key expression."""
        ...

    def blueprint(self) -> rrb.Blueprint:
        """The screen's layout for this run."""
        ...

    def summary(self) -> str:
        """The run as the viewer's start line names it (nodes, scenario)."""
        ...

    def log_static(self) -> None:
        """What does not change over the run (sensors, key, series names)."""
        ...

    def handle(self, msg: Message, node: int | None) -> None:
        """Draw ``msg`` (``truth`` or one of :meth:`topics`); ``node`` the sender the key names when it is one of
        the run's nodes, else None. Raises :class:`~zentrack.transport.codec.WireError` for a message refused."""
        ...
