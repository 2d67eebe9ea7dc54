"""The inbox every process reads its messages from: all subscriptions feed one queue through callbacks that
Zenoh runs directly on its receiving thread, behind a flood guard (size, per-key rate, queue bound, framing).
"""
from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

import zenoh

from zentrack.transport.codec import MAX_MESSAGE_BYTES, Message, WireError, check_framing


def direct(callback: Callable) -> zenoh.handlers.Callback:
    """A callback Zenoh runs on its own receiving thread. zenoh-python's default (``indirect=True``) runs each
    subscription's callback on a Python thread of its own, fed through a channel: one more thread wake-up per
    message on the way to the main loop, per subscription a thread. The inbox's callbacks only copy bytes and
    enqueue, so they are safe to run directly."""
    return zenoh.handlers.Callback(callback, indirect=False)


class Inbox:
    """All subscriptions of a process feed one queue; Zenoh callbacks only copy bytes and enqueue (run directly
    on Zenoh's receiving thread, see :func:`direct`).

    Flood guard, applied in the Zenoh callback before a payload is even copied: a message over
    ``max_bytes`` is dropped (``size``); each key has a token bucket (``rate_per_key`` messages per second,
    bursts of ``burst`` s worth) and a message beyond it is dropped (``rate``); data messages (every tag but
    the control ones) beyond ``max_queued`` waiting in the queue are dropped (``queue``). Drops are counted in
    ``dropped`` (``"<tag>/<reason>"`` -> count), which a caller may share across inboxes.

    Decode, then limit: once a key's bucket is down to half (and until it is empty: then nothing takes a
    token anyway, and nothing is looked at), a data message takes a token only if it frames
    as one of zentrack's (:func:`~zentrack.transport.codec.check_framing`: msgpack, version, kind, step); anything
    else is dropped under the framing's reason (``undecodable``, ``version``, ...) without a token. So a
    stranger's garbage flood on a key cannot use up the bucket its genuine publisher needs (the truth's
    measurements on ``meas/<i>``); a flood of well-formed messages still can in insecure mode (``--secure``
    lets only the truth publish there)."""

    CONTROL_TAGS = ("start", "stop", "alive")

    def __init__(self, rate_per_key: float = 200.0, burst: float = 2.0, max_bytes: int = MAX_MESSAGE_BYTES,
                 max_queued: int = 2000, dropped: dict[str, int] | None = None) -> None:
        # SimpleQueue: put and a timed get are one C call each (Queue's are a dozen Python calls and a Condition)
        self.queue: queue.SimpleQueue[Message] = queue.SimpleQueue()
        self.rate_per_key, self.burst, self.max_bytes, self.max_queued = rate_per_key, burst, max_bytes, max_queued
        self.dropped: dict[str, int] = dropped if dropped is not None else {}
        self._buckets: dict[str, list[float]] = {}  # key -> [tokens, last refill]
        self._queued = 0  # data messages waiting (control ones are not bounded here: rate-limited per key)
        self._lock = threading.Lock()

    def set_rate(self, rate_per_key: float) -> None:
        """Messages per second per key before the guard drops (e.g. once the run's period is known)."""
        with self._lock:
            self.rate_per_key = float(rate_per_key)

    def admit(self, tag: str, key: str, size: int, now: float, payload: Callable[[], bytes] | None = None) -> bool:
        """Whether a message of ``size`` bytes on ``key`` may be queued; counts it under its reason if not.
        ``payload`` gives its bytes, framed (class docstring) once the key's bucket is down to half."""
        reason = None
        with self._lock:
            if size > self.max_bytes:
                reason = "size"
            else:
                cap = self.rate_per_key * self.burst
                tokens, last = self._buckets.get(key, (cap, now))
                tokens = min(cap, tokens + (now - last) * self.rate_per_key)
                if payload is not None and 1.0 <= tokens < 0.5 * cap and tag not in self.CONTROL_TAGS:
                    try:
                        check_framing(payload())
                    except WireError as err:  # not one of ours: no token for it
                        name = f"{tag}/{err.reason}"
                        self.dropped[name] = self.dropped.get(name, 0) + 1
                        return False
                if tokens < 1.0:
                    reason = "rate"
                elif tag not in self.CONTROL_TAGS and self._queued >= self.max_queued:
                    reason = "queue"
                else:
                    tokens -= 1.0
                    if tag not in self.CONTROL_TAGS:
                        self._queued += 1
                if len(self._buckets) < 10_000 or key in self._buckets:  # keys are few; a flood of new ones is not kept
                    self._buckets[key] = [tokens, now]
            if reason is not None:
                name = f"{tag}/{reason}"
                self.dropped[name] = self.dropped.get(name, 0) + 1
        return reason is None

    def callback(self, tag: str) -> zenoh.handlers.Callback:
        put, admit = self.queue.put, self.admit

        def on_sample(sample: zenoh.Sample) -> None:
            now, payload = time.time(), sample.payload  # (each ``sample.payload`` is a new Python object)
            key = str(sample.key_expr)
            if admit(tag, key, len(payload), now, payload.to_bytes):  # (bytes copied if looked at)
                put(Message(tag, key, payload.to_bytes(), now))

        return direct(on_sample)

    def liveliness_callback(self, tag: str = "alive") -> zenoh.handlers.Callback:
        put = self.queue.put

        def on_token(sample: zenoh.Sample) -> None:
            kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
            put(Message(tag, str(sample.key_expr), kind.encode(), time.time()))

        return direct(on_token)

    def reply_callback(self, tag: str) -> zenoh.handlers.Callback:
        """For ``session.get``: each good reply becomes a message like a sample on its key."""
        put = self.queue.put

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                put(Message(tag, str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.time()))

        return direct(on_reply)

    def drain(self, handle: Callable[[Message], None], timeout: float = 0.0) -> int:
        """``handle`` every queued message (waiting up to ``timeout`` for the first); returns how many."""
        count = 0
        msg = self.get(timeout)
        while msg is not None:
            handle(msg)
            count += 1
            msg = self.get(0.0)
        return count

    def get(self, timeout: float) -> Message | None:
        try:
            msg = self.queue.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None
        if msg.tag not in self.CONTROL_TAGS:
            with self._lock:
                self._queued -= 1
        return msg
