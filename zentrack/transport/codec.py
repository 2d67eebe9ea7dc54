"""Wire codec: the framing every message shares, and the checked decoding of its parts.

Every message is a msgpack map with ``v`` (schema version), ``kind``, ``k`` (step index), ``t`` (sample time, s
since the run's t0), ``sender`` and kind-specific fields (:mod:`zentrack.transport.messages` holds one typed
class per kind). Arrays travel as raw little-endian float64 bytes with their shape (``{"shape": [...], "data":
b"..."}``); symmetric matrices as the packed upper triangle (``{"sym": n, "data": b"..."}``, n(n+1)/2 values,
row by row). Version 1 messages are refused with reason ``version``.

Decoding raises one typed error, :class:`WireError`, whose ``reason`` is one of :data:`REASONS`; a receiver
drops the message, counts it under that reason and keeps running. Never ``eval``, never pickle.

The checks are the tracker's per-message cost, so small arrays take fast paths (``tests/test_fast_paths.py``
pins them against the numpy versions they replaced): arrays of at most :data:`LOOP_MAX_VALUES` values are
checked by plain loops over the unpacked floats, and positive definiteness by LAPACK's ``potrf`` called
directly.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, TypeVar

import msgpack
import numpy as np

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
KINDS = ("meas", "prior", "scan", "relay", "est", "truth", "start", "stop", "tracks")
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


# ---------------------------------------------------------------- encoding

def pack_array(a: np.ndarray) -> dict:
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"shape": list(a.shape), "data": a.tobytes()}


_TRIU: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _triu(n: int) -> tuple[np.ndarray, np.ndarray]:
    if n not in _TRIU:
        _TRIU[n] = np.triu_indices(n)
    return _TRIU[n]


def pack_symmetric(m: np.ndarray) -> dict:
    n = m.shape[-1]
    iu = _triu(n)
    return {"sym": n, "data": np.ascontiguousarray(m[iu], dtype="<f8").tobytes()}


def pack_blocks(blocks: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    return {name: {"Y": pack_symmetric(mat), "y": pack_array(vec)} for name, (mat, vec) in blocks.items()}


def header(kind: str, k: int, t: float, sender: int | str) -> dict[str, Any]:
    """The fields every message starts with; a message's own fields follow in its map (in their order)."""
    return {"v": SCHEMA_VERSION, "kind": kind, "k": int(k), "t": float(t), "sender": sender}


def packed(msg: dict[str, Any]) -> bytes:
    """A message map as bytes (numpy arrays in it must already be packed with the helpers above)."""
    return msgpack.packb(msg, use_bin_type=True)


def encode(kind: str, k: int, t: float, sender: int | str, **fields: Any) -> bytes:
    """Serialise one message of ``kind`` with ``fields`` after its header."""
    msg = header(kind, k, t, sender)
    msg.update(fields)
    return packed(msg)


# ---------------------------------------------------------------- the map and its scalar fields

def short(value: Any) -> str:
    """``repr(value)`` cut to 40 characters: error messages name the bad value, a forged 4 KB string included."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


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


# ---------------------------------------------------------------- arrays

#: arrays of at most this many values are checked by a plain loop over the unpacked floats (no numpy call
#: overhead); larger ones by numpy
LOOP_MAX_VALUES = 16
_STRUCTS: dict[int, struct.Struct] = {}
#: per n: for each entry of an n x n matrix, its index in the packed upper triangle (an n x n array)
_SYM_GATHER: dict[int, np.ndarray] = {}


def _finite_values(data: bytes, count: int, name: str, bound: float | None = None) -> np.ndarray:
    """The ``count`` little-endian float64 values of ``data`` (``8 * count`` bytes, checked by the caller) as a
    new writable array; WireError('nonfinite') if one is NaN or infinite, then WireError('range') if one's
    magnitude passes ``bound``."""
    if count <= LOOP_MAX_VALUES:
        unpacker = _STRUCTS.get(count)
        if unpacker is None:
            unpacker = _STRUCTS[count] = struct.Struct(f"<{count}d")
        values = unpacker.unpack(data)
        if not all(map(math.isfinite, values)):
            raise WireError("nonfinite", f"{name}: NaN or Inf")
        if bound is not None and count and (max(values) > bound or min(values) < -bound):
            raise WireError("range", f"{name}: a value of magnitude {max(map(abs, values)):.3g} > {bound:g}")
        return np.array(values, dtype=float)
    raw = np.frombuffer(data, dtype="<f8")
    if not np.isfinite(raw).all():
        raise WireError("nonfinite", f"{name}: NaN or Inf")
    return within_range(raw.astype(float), name, bound) if bound is not None else raw.astype(float)


def _sym_gather(n: int) -> np.ndarray:
    if n not in _SYM_GATHER:
        pos = np.empty((n, n), dtype=np.intp)
        iu = _triu(n)
        pos[iu] = np.arange(iu[0].size)
        pos[(iu[1], iu[0])] = pos[iu]
        _SYM_GATHER[n] = pos
    return _SYM_GATHER[n]


def unpack_array(obj: Any, shape: tuple[int, ...], name: str, bound: float | None = None) -> np.ndarray:
    """An array of exactly ``shape``, every value finite (and within ``bound``, reason ``range``)."""
    if type(obj) is not dict or type(obj.get("data")) is not bytes or type(obj.get("shape")) is not list:
        raise WireError("schema", f"{name}: expected {{shape, data}}")
    if tuple(obj["shape"]) != shape:
        raise WireError("shape", f"{name}: shape {obj['shape']} != expected {list(shape)}")
    count = math.prod(shape)
    if len(obj["data"]) != 8 * count:
        raise WireError("shape", f"{name}: {len(obj['data'])} bytes do not match shape {list(shape)}")
    values = _finite_values(obj["data"], count, name, bound)
    return values if len(shape) == 1 else values.reshape(shape)


def unpack_symmetric(obj: Any, n: int, name: str) -> np.ndarray:
    """A symmetric matrix from the packed upper triangle (or a full matrix, then checked for symmetry)."""
    if type(obj) is dict and "sym" in obj:
        if obj.get("sym") != n or type(obj.get("data")) is not bytes:
            raise WireError("shape", f"{name}: packed size {short(obj.get('sym'))} != expected {n}")
        if len(obj["data"]) != 8 * n * (n + 1) // 2:
            raise WireError("shape", f"{name}: {len(obj['data'])} bytes do not hold a packed {n}x{n} matrix")
        count = n * (n + 1) // 2
        if count > LOOP_MAX_VALUES:  # the gather below copies: no need for _finite_values' copy
            tri = np.frombuffer(obj["data"], dtype="<f8")
            if not np.isfinite(tri).all():
                raise WireError("nonfinite", f"{name}: NaN or Inf")
            return tri[_sym_gather(n)].astype(float, copy=False)
        return _finite_values(obj["data"], count, name)[_sym_gather(n)]
    m = unpack_array(obj, (n, n), name)
    with np.errstate(over="ignore"):  # m - m.T of values near 1e308 is inf: not symmetric
        if not np.allclose(m, m.T, rtol=1e-12, atol=0.0):
            raise WireError("asymmetric", f"{name}: not symmetric")
    return 0.5 * m + 0.5 * m.T  # 0.5 * (m + m.T), the same bits, without overflowing near 1e308


def leading_dim(obj: Any, ndim: int, cap: int, name: str) -> int:
    """The first dimension of an array of ``ndim`` dimensions: an int from 0 to ``cap`` (its other
    dimensions and its data are checked by :func:`unpack_array`)."""
    shape = obj.get("shape") if type(obj) is dict else None
    if type(shape) is not list or len(shape) != ndim:
        raise WireError("schema", f"{name}: expected {'a vector' if ndim == 1 else f'an array of {ndim} dimensions'}")
    rows = shape[0]
    if type(rows) is not int or not 0 <= rows <= cap:
        raise WireError("shape", f"{name}: {short(rows)} rows, expected 0 to {cap}")
    return rows


def unpack_vector(obj: Any, name: str) -> np.ndarray:
    """A state vector of unknown dimension n, 1 <= n <= MAX_DIM."""
    n = leading_dim(obj, 1, MAX_DIM, name)
    if n == 0:
        raise WireError("shape", f"{name}: an empty state")
    return unpack_array(obj, (n,), name)


def optional_rows(obj: Any, width: int | None, cap: int, name: str) -> np.ndarray | None:
    """An optional ``(S, width)`` array (``(S,)`` when ``width`` is None) with S <= ``cap``; None if absent."""
    if obj is None:
        return None
    rows = leading_dim(obj, 1 if width is None else 2, cap, name)
    return unpack_array(obj, (rows,) if width is None else (rows, width), name)


def unpack_returns(obj: Any, m: int) -> np.ndarray:
    """A scan's returns ``(J, m)``, 0 <= J <= MAX_RETURNS, each value within MAX_COORDINATE."""
    j = leading_dim(obj, 2, MAX_RETURNS, "returns")
    return unpack_array(obj, (j, m), "returns", MAX_COORDINATE)


def unpack_pose(obj: Any) -> np.ndarray:
    """A sensor position ``(3,)`` within MAX_COORDINATE."""
    return unpack_array(obj, (3,), "pose", MAX_COORDINATE)


def all_within(arr: np.ndarray, lo: float, hi: float) -> bool:
    """Whether every value of ``arr`` (finite) lies in ``[lo, hi]`` (a plain loop on a few values: ``np.all``
    on a small array costs a microsecond)."""
    if arr.size > LOOP_MAX_VALUES:
        return bool(arr.min() >= lo and arr.max() <= hi)
    values = arr.ravel().tolist()
    return not values or (min(values) >= lo and max(values) <= hi)


def within_range(arr: np.ndarray, what: str, bound: float = MAX_COORDINATE) -> np.ndarray:
    """``arr`` itself if no value's magnitude passes ``bound`` (reason ``range`` otherwise)."""
    if not arr.size:
        return arr
    # a plain loop on a few values (a bearing, a pose) is cheaper than numpy's per-call overhead
    largest = max(map(abs, arr.ravel().tolist())) if arr.size <= LOOP_MAX_VALUES else float(np.max(np.abs(arr)))
    if largest > bound:
        raise WireError("range", f"{what}: a value of magnitude {largest:.3g} > {bound:g}")
    return arr


# ---------------------------------------------------------------- matrices

_POTRF: list[Any] = []  # LAPACK's dpotrf, imported on first use (``zentrack health`` never loads SciPy)


def check_pd(m: np.ndarray, name: str) -> None:
    """WireError('not_pd') unless the Cholesky factorisation of ``m`` (finite, symmetric) succeeds: LAPACK's
    ``potrf`` called directly, a third of ``numpy.linalg.cholesky``'s cost on one small matrix."""
    if not _POTRF:
        from zentrack.fusion.linalg import lapack  # SciPy's LAPACK without the whole of scipy.linalg

        _POTRF.append(lapack.dpotrf)
    if _POTRF[0](m, lower=1, clean=0)[1] != 0:
        raise WireError("not_pd", f"{name}: not positive definite")


#: blocks that carry an information *increment* (seed 004 consensus on measurements): positive semidefinite,
#: and zero for a relay, so they are checked for PSD instead of PD
PSD_BLOCKS = frozenset({"increment"})


def check_psd(m: np.ndarray, name: str) -> None:
    """WireError('not_pd') unless ``m`` (finite, symmetric) is positive semidefinite up to rounding."""
    scale = max(float(np.max(np.abs(m))), 1e-300)
    try:
        lowest = float(np.linalg.eigvalsh(m)[0])
    except np.linalg.LinAlgError:  # no convergence: no verdict, so no use
        lowest = math.nan
    if not lowest >= -1e-9 * scale:
        raise WireError("not_pd", f"{name}: not positive semidefinite")
