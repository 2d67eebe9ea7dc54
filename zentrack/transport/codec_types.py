"""The wire's limits and types: the caps on every variable size, the message kinds, the refusal reasons and
their error (:class:`WireError`), the registry of kinds (:func:`wire_kind`), the record of a received message (:class:`Message`), and the two helpers
every decoder uses (:func:`built`, :func:`short`).

Imported by the codec's modules (:mod:`zentrack.transport.codec`, :mod:`zentrack.transport.codec_arrays`);
callers import these names from :mod:`zentrack.transport.codec`, which re-exports them.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

SCHEMA_VERSION = 2
#: caps on variable sizes (a message is also capped at MAX_MESSAGE_BYTES)
MAX_RETURNS = 2048
#: particles an estimate may carry for viewers
MAX_SAMPLES = 256
MAX_BLOCKS = 8
MAX_BLOCK_NAME = 32
MAX_DIM = 64
MAX_ROUNDS = 32
MAX_MESSAGE_BYTES = 256 * 1024
#: node ids are 0 .. MAX_NODES - 1 (a network has at most 1000 nodes)
MAX_NODES = 1000
#: the largest magnitude of a return or sensor position (m, or rad for angles): far beyond any scenario, far
#: below where a filter's squares overflow (a pose of 1e155 m makes a bearing Jacobian inf / inf)
MAX_COORDINATE = 1e12
#: every message kind on the wire -> its class, each registered by the class (:func:`wire_kind`), in the order the
#: message modules define them: a kind no class declares is refused (``kind``) before anything else is read
KINDS: dict[str, type] = {}
#: scans one relay message may carry: a node relays each neighbour's scan of the step, and a network has at
#: most 1000 nodes (a relay that would pass MAX_MESSAGE_BYTES leaves scans out instead: ``Relay.encode_capped``)
MAX_RELAYED = MAX_NODES - 1
#: an estimate's counters: at most this many names per map, each at most MAX_COUNTER_NAME characters long
MAX_COUNTERS = 64
MAX_COUNTER_NAME = 64
#: the largest count (msgpack's int64 range; a counter is never negative)
MAX_COUNT = 2**63 - 1
REASONS = (
    "size", "undecodable", "version", "kind", "schema", "shape", "nonfinite", "asymmetric", "not_pd",
    "stale", "future", "sender_mismatch", "duplicate", "unexpected",
    "flood",  # more distinct copies of one sender's message for one step and round than a receiver keeps
    "conflict",  # a control message that contradicts the run, or a third different copy of a round message
    "early",  # a round message that came before its sender could have made it (realtime)
    "range",  # a finite return or sensor position beyond MAX_COORDINATE
)


class WireError(ValueError):
    """A message that must be dropped; ``reason`` names the check that failed (one of :data:`REASONS`)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


C = TypeVar("C", bound=type)


def wire_kind(name: str) -> Callable[[C], C]:
    """Class decorator: the message class of kind ``name`` (its map's ``kind``); the kind joins :data:`KINDS`."""
    def register(cls: C) -> C:
        if KINDS.setdefault(name, cls) is not cls:
            raise ValueError(f"message kind {name!r} is declared by {KINDS[name].__name__} and {cls.__name__}")
        return cls
    return register


@dataclass
class Message:
    """One received message before decoding: ``tag`` (which subscription: meas, prior, start, stop, alive,
    est), the key it came on, its bytes, and the wall-clock receive time. ``decoded``: what a first reader decoded
    it into without a step window (the node's clock decodes every measurement), so a later one need not again."""

    tag: str
    key: str
    payload: bytes
    t_recv: float
    decoded: Any = None


T = TypeVar("T")
_NEW = object.__new__


def built(cls: type[T], fields: dict[str, Any]) -> T:
    """An instance of the frozen dataclass ``cls`` holding ``fields`` (every one of its fields, by name, checked
    by the caller), made without its ``__init__``: a frozen ``__init__`` sets each field through
    ``object.__setattr__``, about 0.1 µs a field, which is a tenth of a small message's decoding."""
    obj = _NEW(cls)
    obj.__dict__.update(fields)
    return obj


def short(value: Any) -> str:
    """``repr(value)`` cut to 40 characters: error messages name the bad value, a forged 4 KB string included."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
