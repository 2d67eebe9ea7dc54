"""The viewer's core: one run's subscriptions, the loop that drains them into Rerun, and the messages every run
has (the truth's ``ctl/stop``, liveliness), driving a payload part that draws the rest
(:class:`~zentrack.viewer.payload.Payload`: :mod:`~zentrack.viewer.single_target` or
:mod:`~zentrack.viewer.multi_target`) on the canvas they share (:class:`~zentrack.viewer.payload.Canvas`).

Timelines ``step`` and ``time`` (k·Ts; a sensor's detection at its own time); ``events`` logs nodes joining and
leaving. A part that subscribes ``ctl/start`` (tag ``start``: sensors of their own) also has it asked for, as a
viewer that started after the run needs. A message that does not decode
(:class:`~zentrack.transport.codec.WireError`) is counted in ``canvas.logged["bad"]`` and skipped.
"""
from __future__ import annotations

import logging
import time

from zentrack.common.procs import StopFlag
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import Keys, node_id
from zentrack.transport.messages import Stop
from zentrack.transport.zsession import Inbox
from zentrack.viewer.payload import Canvas, Payload

log = logging.getLogger("zentrack.viewer")


class Viewer:
    """Logs a run to ``canvas``'s recording through ``payload``. ``session`` None: no subscriptions, messages come
    through :meth:`handle` (tests)."""

    def __init__(self, session, keys: Keys, canvas: Canvas, payload: Payload, flush_s: float = 1.0) -> None:
        self.keys, self.canvas, self.payload, self.flush_s = keys, canvas, payload, flush_s
        self.inbox = Inbox(rate_per_key=1e9, max_queued=100_000)  # every round of every node, faster in lockstep
        self.stopped = False
        self.subs: list = []
        self.token = None
        if session is not None:
            topics = {"truth": keys.truth, **payload.topics(keys), "stop": keys.stop}
            self.subs = [session.declare_subscriber(key, self.inbox.callback(tag)) for tag, key in topics.items()]
            if "start" in topics:  # the truth and every tracker answer
                session.get(keys.start, self.inbox.reply_callback("start"), timeout=2.0)
            self.subs.append(session.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(),
                                                                     history=True))
            self.token = session.liveliness().declare_token(keys.alive("viewer"))
        payload.log_static()

    def run(self, stop: StopFlag, duration: float | None, stop_grace: float = 1.0) -> None:
        """Log until ctl/stop (then ``stop_grace`` seconds more for stragglers), a signal, or ``duration``."""
        end = None if duration is None else time.time() + duration
        next_flush = time.time() + self.flush_s
        while not stop and (end is None or time.time() < end):
            msg = self.inbox.get(0.2)
            while msg is not None:
                was_stopped = self.stopped
                self.handle(msg)
                if self.stopped and not was_stopped:
                    end = time.time() + stop_grace if end is None else min(end, time.time() + stop_grace)
                msg = self.inbox.get(0.0) if time.time() < next_flush else None
            if time.time() >= next_flush:
                self.canvas.buf.flush()
                next_flush = time.time() + self.flush_s
        self.canvas.buf.flush()

    def handle(self, msg: Message) -> None:
        """Draw one message; one that does not decode is counted and skipped."""
        try:
            if msg.tag == "alive":
                who = self.keys.last_segment(msg.key)
                joined = msg.payload == b"put"
                self.canvas.event(self.canvas.current_step,
                                  f"{'node ' if node_id(who) is not None else ''}{who} {'joined' if joined else 'left'}",
                                  "INFO" if joined else "WARN")
            elif msg.tag == "stop":
                Stop.decode(msg.payload)  # the truth's (anything else on ctl/stop is counted and ignored)
                self.stopped = True
            else:
                self.payload.handle(msg, self._sender(msg.key))
        except WireError as err:
            self.canvas.logged["bad"] += 1
            if self.canvas.logged["bad"] <= 3:
                log.warning("viewer: dropped a %s message (%s)", msg.tag, err)

    def _sender(self, key: str) -> int | None:
        """The node a key ends with when it is one of the run's, else None."""
        i = self.keys.node_of(key)
        return i if i is not None and i < self.canvas.nodes else None

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        if self.token is not None:
            self.token.undeclare()
