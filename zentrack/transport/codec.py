"""Wire codec: the framing every message shares, and the checked decoding of its parts.


Every message is a msgpack map with ``v`` (schema version), ``kind``, ``k`` (step index), ``t`` (sample time, s
since the run's t0), ``sender`` and kind-specific fields (:mod:`zentrack.transport.messages` holds one typed
class per kind). Arrays travel as raw little-endian float64 bytes with their shape (``{"shape": [...], "data":
b"..."}``); symmetric matrices as the packed upper triangle (``{"sym": n, "data": b"..."}``, n(n+1)/2 values,
row by row). Version 1 messages are refused with reason ``version``.

Decoding raises one typed error, :class:`WireError`, whose ``reason`` is one of :data:`REASONS`; a receiver
drops the message, counts it under that reason and keeps running. Never ``eval``, never pickle.

This module holds the framing (header, encoding, :func:`unpack`, :func:`check_framing`) and the checked
scalar fields; the limits and types are in :mod:`zentrack.transport.codec_types` and the arrays in
:mod:`zentrack.transport.codec_arrays`. Every name of both is re-exported here, where callers import them.
"""
from __future__ import annotations

import math
from typing import Any

import msgpack

from zentrack.transport.codec_arrays import (
    LOOP_MAX_VALUES,
    PSD_BLOCKS,
    all_within,
    check_pd,
    check_psd,
    leading_dim,
    optional_rows,
    pack_array,
    pack_blocks,
    pack_symmetric,
    unpack_array,
    unpack_pose,
    unpack_returns,
    unpack_symmetric,
    unpack_symmetrics,
    unpack_vector,
    unpack_vectors,
    within_range,
)
from zentrack.transport.codec_types import (
    KINDS,
    MAX_BLOCK_NAME,
    MAX_BLOCKS,
    MAX_COORDINATE,
    MAX_COUNT,
    MAX_COUNTER_NAME,
    MAX_COUNTERS,
    MAX_DIM,
    MAX_MESSAGE_BYTES,
    MAX_NODES,
    MAX_RELAYED,
    MAX_RETURNS,
    MAX_ROUNDS,
    MAX_SAMPLES,
    REASONS,
    SCHEMA_VERSION,
    Message,
    WireError,
    built,
    short,
    wire_kind,
)

__all__ = [
    # the framing and the scalar fields (this module)
    "FRAMING_BYTES", "FRAMING_FIELDS", "check_framing", "check_step", "encode", "field", "flag", "header",
    "node_id", "node_message", "number", "optional_number", "packed", "truth_message", "unpack",
    # re-exported from zentrack.transport.codec_types
    "KINDS", "MAX_BLOCK_NAME", "MAX_BLOCKS", "MAX_COORDINATE", "MAX_COUNT", "MAX_COUNTER_NAME", "MAX_COUNTERS",
    "MAX_DIM", "MAX_MESSAGE_BYTES", "MAX_NODES", "MAX_RELAYED", "MAX_RETURNS", "MAX_ROUNDS", "MAX_SAMPLES",
    "REASONS", "SCHEMA_VERSION", "Message", "WireError", "built", "short", "wire_kind",
    # re-exported from zentrack.transport.codec_arrays
    "LOOP_MAX_VALUES", "PSD_BLOCKS", "all_within", "check_pd", "check_psd", "leading_dim", "optional_rows",
    "pack_array", "pack_blocks", "pack_symmetric", "unpack_array", "unpack_pose", "unpack_returns",
    "unpack_symmetric", "unpack_symmetrics", "unpack_vector", "unpack_vectors", "within_range",
]


# ---------------------------------------------------------------- encoding

def header(kind: str, k: int, t: float, sender: int | str) -> dict[str, Any]:
    """The fields every message starts with; a message's own fields follow in its map (in their order)."""
    return {"v": SCHEMA_VERSION, "kind": kind, "k": int(k), "t": float(t), "sender": sender}


def packed(msg: dict[str, Any]) -> bytes:
    """A message map as bytes (numpy arrays in it must already be packed: :func:`pack_array`,
    :func:`pack_symmetric`)."""
    return msgpack.packb(msg, use_bin_type=True)


def encode(kind: str, k: int, t: float, sender: int | str, **fields: Any) -> bytes:
    """Serialise one message of ``kind`` with ``fields`` after its header."""
    msg = header(kind, k, t, sender)
    msg.update(fields)
    return packed(msg)


# ---------------------------------------------------------------- the map and its scalar fields

def unpack(payload: bytes) -> dict:
    """msgpack bytes -> map, with size limits; raises WireError('size'|'undecodable'|'version'|'schema'|
    'kind'|'stale'|'nonfinite'). The map's ``kind``, ``k`` (a step: 0 to MAX_COUNT) and ``t`` are checked;
    nothing else is."""
    if len(payload) > MAX_MESSAGE_BYTES:
        raise WireError("size", f"{len(payload)} bytes > {MAX_MESSAGE_BYTES}")
    try:
        msg = msgpack.unpackb(
            payload, raw=False, strict_map_key=True, max_bin_len=MAX_MESSAGE_BYTES,
            max_str_len=4096, max_array_len=4096, max_map_len=256, max_ext_len=0,
        )
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError("undecodable", f"not msgpack ({type(exc).__name__})") from None
    if type(msg) is not dict:
        raise WireError("undecodable", f"top level is {type(msg).__name__}, not a map")
    return _checked_header(msg)


#: how many leading fields :func:`check_framing` reads: every message starts with :func:`header`'s five
FRAMING_FIELDS = 5
#: ... within this many leading bytes (the five take under 60)
FRAMING_BYTES = 256


def check_framing(payload: bytes) -> None:
    """The cheap part of :func:`unpack`, at a cost that does not grow with the payload: the map's first
    :data:`FRAMING_FIELDS` fields (where every zentrack message has its header) must hold a valid ``v``,
    ``kind``, ``k`` and ``t``. Raises WireError as :func:`unpack` would; the flood guard's test of whether a
    message is one of ours before it takes a token."""
    if len(payload) > MAX_MESSAGE_BYTES:
        raise WireError("size", f"{len(payload)} bytes > {MAX_MESSAGE_BYTES}")
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=FRAMING_BYTES,
                                max_bin_len=FRAMING_BYTES, max_str_len=FRAMING_BYTES, max_array_len=64,
                                max_map_len=256, max_ext_len=0)
    try:
        unpacker.feed(payload[:FRAMING_BYTES])  # the header is short: a field that runs past this is not one
        fields = unpacker.read_map_header()
        head = {}
        for _ in range(min(fields, FRAMING_FIELDS)):
            key = unpacker.unpack()
            head[key] = unpacker.unpack()
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError("undecodable", f"not a msgpack map ({type(exc).__name__})") from None
    _checked_header(head)


def _checked_header(msg: dict) -> dict:
    """``msg`` if its ``v``, ``kind``, ``k`` and ``t`` are valid, else WireError (see :func:`unpack`)."""
    if msg.get("v") != SCHEMA_VERSION:
        raise WireError("version", f"schema version {short(msg.get('v'))}, expected {SCHEMA_VERSION}")
    # msgpack yields exact built-in types, so ``type() is`` both checks and keeps bools out of the numbers
    kind, t = msg.get("kind"), msg.get("t")
    if type(kind) is not str or type(msg.get("k")) is not int or (type(t) is not float and type(t) is not int):
        raise WireError("schema", "field 'kind', 'k' or 't' missing or of the wrong type")
    if kind not in KINDS:
        raise WireError("kind", f"unknown kind {short(kind)}")
    if msg["k"] < 0:
        raise WireError("stale", f"step {msg['k']} < 0")
    if msg["k"] > MAX_COUNT:  # msgpack's uint64 range passes int64's (numpy, Rerun)
        raise WireError("schema", "step k beyond a 64-bit integer")
    if not math.isfinite(t):
        raise WireError("nonfinite", "sample time t is not finite")
    return msg


def field(msg: dict, key: str, typ: type | tuple[type, ...]) -> Any:
    """``msg[key]`` if it is a ``typ`` (never a bool unless ``typ`` is bool); WireError('schema') otherwise."""
    value = msg.get(key)
    if not isinstance(value, typ) or (isinstance(value, bool) and typ is not bool):
        raise WireError("schema", f"field {key!r} missing or of the wrong type")
    return value


def number(msg: dict, key: str) -> float:
    """A finite number (int or float, not bool) as a float: WireError 'schema' or 'nonfinite' otherwise."""
    value = msg.get(key)
    if type(value) is float:
        if not math.isfinite(value):
            raise WireError("nonfinite", f"field {key!r} is not finite")
        return value
    if type(value) is int:
        return float(value)
    raise WireError("schema", f"field {key!r} missing or not a number")


def optional_number(msg: dict, key: str) -> float | None:
    """:func:`number`, or None when the field is absent or nil."""
    return None if msg.get(key) is None else number(msg, key)


def flag(msg: dict, key: str) -> bool:
    """An optional boolean field (absent: False)."""
    value = msg.get(key, False)
    if type(value) is not bool:
        raise WireError("schema", f"field {key!r} must be a boolean")
    return value


def node_id(value: Any, what: str) -> int:
    """A node id, 0 <= id < MAX_NODES."""
    if type(value) is not int or not 0 <= value < MAX_NODES:
        raise WireError("schema", f"{what}: {short(value)} is not a node id (0 to {MAX_NODES - 1})")
    return value


def check_step(msg: dict, lo: int | None, hi: int | None) -> None:
    if lo is not None and msg["k"] < lo:
        raise WireError("stale", f"step {msg['k']} < {lo}")
    if hi is not None and msg["k"] > hi:
        raise WireError("future", f"step {msg['k']} > {hi}")


def node_message(payload: bytes, kinds: tuple[str, ...], key_node: int, lo: int | None = None,
                 hi: int | None = None) -> dict:
    """Unpack a message of one of ``kinds`` from node ``key_node``'s key: right kind, sender equals the key,
    step in the window."""
    msg = unpack(payload)
    if msg["kind"] not in kinds:
        raise WireError("kind", f"kind {msg['kind']!r} on a {'/'.join(kinds)} key")
    if msg.get("sender") != key_node or type(msg.get("sender")) is not int:
        raise WireError("sender_mismatch", f"sender {short(msg.get('sender'))} on key of node {key_node}")
    check_step(msg, lo, hi)
    return msg


def truth_message(payload: bytes, kind: str) -> dict:
    """Unpack a message of ``kind`` that only the truth sends."""
    msg = unpack(payload)
    if msg["kind"] != kind or msg.get("sender") != "truth":
        raise WireError("kind", f"a {msg['kind']!r} message from {short(msg.get('sender'))}, not a {kind} message from truth")
    return msg
