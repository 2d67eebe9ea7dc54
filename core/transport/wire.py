"""Wire format: msgpack maps with a schema version, validated completely on decoding.

Every message is a map with ``v`` (schema version), ``kind``, ``k`` (step index), ``t`` (sample time, s since
the run's t0), ``sender`` and kind-specific fields. Arrays travel as raw little-endian float64 bytes with their
shape (``{"shape": [...], "data": b"..."}``); symmetric matrices as the packed upper triangle
(``{"sym": n, "data": b"..."}``, n(n+1)/2 values, row by row).

Version 2 (this one) carries every seed's traffic:

- ``meas`` (truth -> node i): a *scan*, ``returns`` of shape ``(J, m)`` with J >= 0 (J = 0: the sensor looked
  and saw nothing; ``present = false``: no scan at all), and the sensor's ``pose`` at step k;
- ``prior`` (node -> neighbours): one fusion round's message, ``round`` (1..L) and ``blocks``, a map of named
  information pairs (``{"state": {Y, y}}`` for a plain filter; e.g. kinematics and extent fused apart);
- ``scan`` (node -> neighbours): a scan forwarded with the pose and noise of the sensor that took it;
- ``relay`` (node -> neighbours, on its ``scan`` key): the scans of its neighbours it received for step k,
  ``scans``, a list of ``{origin, returns, pose, R}`` (rules with ``relay_scans``);
- ``start`` carries the run's initial estimate ``x0``, ``est`` a node's kinematic posterior.

Version 1 messages are refused with reason ``version``.

Decoding raises one typed error, :class:`WireError`, whose ``reason`` is one of :data:`REASONS`; a node drops
the message, counts it under that reason and keeps running. Never ``eval``, never pickle.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

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
#: the largest magnitude of a return or sensor position (m, or rad for angles): far beyond any scenario, far
#: below where a filter's squares overflow (a pose of 1e155 m makes a bearing Jacobian inf / inf)
MAX_COORDINATE = 1e12
KINDS = ("meas", "prior", "scan", "relay", "est", "truth", "start", "stop")
#: scans one relay message may carry: a node relays each neighbour's scan of the step, and a network has at
#: most 1000 nodes (a relay that would pass MAX_MESSAGE_BYTES leaves scans out instead: :func:`encode_relay`)
MAX_RELAYED = 999
REASONS = (
    "size", "undecodable", "version", "kind", "schema", "shape", "nonfinite", "asymmetric", "not_pd",
    "stale", "future", "sender_mismatch", "duplicate", "unexpected",
    "flood",  # more distinct copies of one sender's message for one step and round than a receiver keeps
    "conflict",  # a control message that contradicts the run under way
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
    est), the key it came on, its bytes, and the wall-clock receive time."""

    tag: str
    key: str
    payload: bytes
    t_recv: float


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


def encode(kind: str, k: int, t: float, sender: int | str, **fields: Any) -> bytes:
    """Serialise one message; numpy arrays in ``fields`` must already be packed with the helpers above."""
    msg = {"v": SCHEMA_VERSION, "kind": kind, "k": int(k), "t": float(t), "sender": sender}
    msg.update(fields)
    return msgpack.packb(msg, use_bin_type=True)


def pack_blocks(blocks: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    return {name: {"Y": pack_symmetric(mat), "y": pack_array(vec)} for name, (mat, vec) in blocks.items()}


def encode_prior(k: int, t: float, sender: int, blocks: dict[str, tuple[np.ndarray, np.ndarray]], t_pub: float,
                 warm: bool = False, round: int = 1) -> bytes:
    """Node ``sender``'s message of fusion round ``round`` for step k: named information pairs ``(Y, y)``.
    ``warm``: the sender has no recent measurement support (it is warming up or coasted too long), so a node
    with fresh pairs leaves this one out of its fusion."""
    return encode("prior", k, t, sender, round=int(round), blocks=pack_blocks(blocks), t_pub=t_pub, warm=bool(warm))


def encode_meas(k: int, t: float, node: int, returns: np.ndarray | None, t_pub: float,
                pose: np.ndarray | None = None) -> bytes:
    """Node ``node``'s scan at step k: ``returns`` ``(J, m)`` (J may be 0), or None for no scan; a ``(m,)``
    vector is one return."""
    fields: dict[str, Any] = {"node": node, "present": returns is not None, "t_pub": t_pub}
    if returns is not None:
        fields["returns"] = pack_array(np.atleast_2d(returns))
        if pose is not None:
            fields["pose"] = pack_array(pose)
    return encode("meas", k, t, "truth", **fields)


def encode_scan(k: int, t: float, sender: int, origin: int, returns: np.ndarray | None, pose: np.ndarray | None,
                noise_cov: np.ndarray | None, t_pub: float) -> bytes:
    """A scan of sensor ``origin`` at step k forwarded by node ``sender`` (returns ``(J, m)``, pose, noise);
    ``returns=None`` says "no scan this step", so the neighbours waiting for it need not wait."""
    fields: dict[str, Any] = {"origin": int(origin), "present": returns is not None, "t_pub": t_pub}
    if returns is not None:
        if pose is None or noise_cov is None:
            raise ValueError("a forwarded scan needs the pose and noise of its sensor")
        fields.update(returns=pack_array(np.atleast_2d(returns)), pose=pack_array(pose), R=pack_symmetric(noise_cov))
    return encode("scan", k, t, sender, **fields)


# ---------------------------------------------------------------- decoding

def unpack(payload: bytes) -> dict:
    """msgpack bytes -> map, with size limits; raises WireError('size'|'undecodable'|'version'|'schema')."""
    if len(payload) > MAX_MESSAGE_BYTES:
        raise WireError("size", f"{len(payload)} bytes > {MAX_MESSAGE_BYTES}")
    try:
        msg = msgpack.unpackb(
            payload, raw=False, strict_map_key=True, max_bin_len=MAX_MESSAGE_BYTES,
            max_str_len=4096, max_array_len=4096, max_map_len=256, max_ext_len=0,
        )
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError("undecodable", f"not msgpack ({type(exc).__name__})") from None
    if not isinstance(msg, dict):
        raise WireError("undecodable", f"top level is {type(msg).__name__}, not a map")
    if msg.get("v") != SCHEMA_VERSION:
        raise WireError("version", f"schema version {msg.get('v')!r}, expected {SCHEMA_VERSION}")
    for key, typ in (("kind", str), ("k", int), ("t", (int, float))):
        if not isinstance(msg.get(key), typ) or isinstance(msg.get(key), bool):
            raise WireError("schema", f"field {key!r} missing or of the wrong type")
    if msg["kind"] not in KINDS:
        raise WireError("kind", f"unknown kind {msg['kind']!r}")
    if not math.isfinite(msg["t"]):
        raise WireError("nonfinite", "sample time t is not finite")
    return msg


def _field(msg: dict, key: str, typ) -> Any:
    value = msg.get(key)
    if not isinstance(value, typ) or (isinstance(value, bool) and typ is not bool):
        raise WireError("schema", f"field {key!r} missing or of the wrong type")
    return value


#: arrays of at most this many values are checked by a plain loop over the unpacked floats (no numpy call
#: overhead); larger ones by numpy
LOOP_MAX_VALUES = 16
_STRUCTS: dict[int, struct.Struct] = {}
#: per n: for each entry of an n x n matrix, row by row, its index in the packed upper triangle
_SYM_GATHER: dict[int, np.ndarray] = {}


def _finite_values(data: bytes, count: int, name: str) -> np.ndarray:
    """The ``count`` little-endian float64 values of ``data`` (``8 * count`` bytes, checked by the caller) as a
    new writable array; WireError('nonfinite') if one is NaN or infinite."""
    if count <= LOOP_MAX_VALUES:
        unpacker = _STRUCTS.get(count)
        if unpacker is None:
            unpacker = _STRUCTS[count] = struct.Struct(f"<{count}d")
        values = unpacker.unpack(data)
        if not all(map(math.isfinite, values)):
            raise WireError("nonfinite", f"{name}: NaN or Inf")
        return np.array(values, dtype=float)
    raw = np.frombuffer(data, dtype="<f8")
    if not np.isfinite(raw).all():
        raise WireError("nonfinite", f"{name}: NaN or Inf")
    return raw.astype(float)


def _sym_gather(n: int) -> np.ndarray:
    if n not in _SYM_GATHER:
        pos = np.empty((n, n), dtype=np.intp)
        iu = _triu(n)
        pos[iu] = np.arange(iu[0].size)
        pos[(iu[1], iu[0])] = pos[iu]
        _SYM_GATHER[n] = pos.ravel()
    return _SYM_GATHER[n]


def unpack_array(obj: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    if not isinstance(obj, dict) or not isinstance(obj.get("data"), bytes) or not isinstance(obj.get("shape"), list):
        raise WireError("schema", f"{name}: expected {{shape, data}}")
    if tuple(obj["shape"]) != shape:
        raise WireError("shape", f"{name}: shape {obj['shape']} != expected {list(shape)}")
    count = math.prod(shape)
    if len(obj["data"]) != 8 * count:
        raise WireError("shape", f"{name}: {len(obj['data'])} bytes do not match shape {list(shape)}")
    return _finite_values(obj["data"], count, name).reshape(shape)


def unpack_symmetric(obj: Any, n: int, name: str) -> np.ndarray:
    """A symmetric matrix from the packed upper triangle (or a full matrix, then checked for symmetry)."""
    if isinstance(obj, dict) and "sym" in obj:
        if obj.get("sym") != n or not isinstance(obj.get("data"), bytes):
            raise WireError("shape", f"{name}: packed size {obj.get('sym')!r} != expected {n}")
        if len(obj["data"]) != 8 * n * (n + 1) // 2:
            raise WireError("shape", f"{name}: {len(obj['data'])} bytes do not hold a packed {n}x{n} matrix")
        tri = _finite_values(obj["data"], n * (n + 1) // 2, name)
        return tri[_sym_gather(n)].reshape(n, n)
    m = unpack_array(obj, (n, n), name)
    if not np.allclose(m, m.T, rtol=1e-12, atol=0.0):
        raise WireError("asymmetric", f"{name}: not symmetric")
    return 0.5 * (m + m.T)


_POTRF: list[Any] = []  # LAPACK's dpotrf, imported on first use (``zentrack health`` never loads SciPy)


def check_pd(m: np.ndarray, name: str) -> None:
    """WireError('not_pd') unless the Cholesky factorisation of ``m`` (finite, symmetric) succeeds: LAPACK's
    ``potrf`` called directly, a third of ``numpy.linalg.cholesky``'s cost on one small matrix."""
    if not _POTRF:
        from scipy.linalg import lapack

        _POTRF.append(lapack.dpotrf)
    if _POTRF[0](m, lower=1, clean=0)[1] != 0:
        raise WireError("not_pd", f"{name}: not positive definite")


#: blocks that carry an information *increment* (seed 004 consensus on measurements): positive semidefinite,
#: and zero for a relay, so they are checked for PSD instead of PD
PSD_BLOCKS = frozenset({"increment"})


def check_psd(m: np.ndarray, name: str) -> None:
    scale = max(float(np.max(np.abs(m))), 1e-300)
    if float(np.linalg.eigvalsh(m)[0]) < -1e-9 * scale:
        raise WireError("not_pd", f"{name}: not positive semidefinite")


def check_step(msg: dict, lo: int | None, hi: int | None) -> None:
    if lo is not None and msg["k"] < lo:
        raise WireError("stale", f"step {msg['k']} < {lo}")
    if hi is not None and msg["k"] > hi:
        raise WireError("future", f"step {msg['k']} > {hi}")


def unpack_returns(obj: Any, m: int) -> np.ndarray:
    """A scan's returns ``(J, m)``, 0 <= J <= MAX_RETURNS."""
    if not isinstance(obj, dict) or not isinstance(obj.get("shape"), list) or len(obj["shape"]) != 2:
        raise WireError("schema", "returns: expected a (J, m) array")
    j = obj["shape"][0]
    if not isinstance(j, int) or isinstance(j, bool) or not 0 <= j <= MAX_RETURNS:
        raise WireError("shape", f"returns: {j!r} returns, expected 0 to {MAX_RETURNS}")
    return within_range(unpack_array(obj, (j, m), "returns"), "returns")


def within_range(arr: np.ndarray, what: str) -> np.ndarray:
    """``arr`` itself if no value's magnitude passes :data:`MAX_COORDINATE` (reason ``range`` otherwise)."""
    if not arr.size:
        return arr
    # a plain loop on a few values (a bearing, a pose) is cheaper than numpy's per-call overhead
    largest = max(map(abs, arr.ravel().tolist())) if arr.size <= LOOP_MAX_VALUES else float(np.max(np.abs(arr)))
    if largest > MAX_COORDINATE:
        raise WireError("range", f"{what}: a value of magnitude {largest:.3g} > {MAX_COORDINATE:g}")
    return arr


def _node_message(payload: bytes, kind: str, key_node: int, lo: int | None, hi: int | None) -> dict:
    """Unpack a message of ``kind`` from node ``key_node``'s key: right kind, sender equals the key, step in
    the window."""
    msg = unpack(payload)
    if msg["kind"] != kind:
        raise WireError("kind", f"kind {msg['kind']!r} on a {kind} key")
    if msg.get("sender") != key_node:
        raise WireError("sender_mismatch", f"sender {msg.get('sender')!r} on key of node {key_node}")
    check_step(msg, lo, hi)
    return msg


def decode_prior(payload: bytes, key_node: int, dims: dict[str, int] | int, lo: int | None = None,
                 hi: int | None = None, max_round: int = 1) -> dict:
    """Validate a fusion message from ``prior/<key_node>``: sender, step window, round, the block names and
    sizes the receiver expects (``dims``: name -> n; an int means one block ``state``), finiteness, SPD."""
    if isinstance(dims, int):
        dims = {"state": dims}
    msg = _node_message(payload, "prior", key_node, lo, hi)
    rnd = _field(msg, "round", int)
    if not 1 <= rnd <= min(max_round, MAX_ROUNDS):
        raise WireError("schema", f"round {rnd} outside 1..{max_round}")
    raw = _field(msg, "blocks", dict)
    if len(raw) > MAX_BLOCKS or not all(isinstance(b, str) and len(b) <= MAX_BLOCK_NAME for b in raw):
        raise WireError("schema", "blocks: too many or badly named")
    if set(raw) != set(dims):
        raise WireError("shape", f"blocks {sorted(raw)} != expected {sorted(dims)}")
    blocks = {}
    for name, n in dims.items():
        pair = raw[name]
        if not isinstance(pair, dict):
            raise WireError("schema", f"block {name!r}: expected {{Y, y}}")
        y_mat = unpack_symmetric(pair.get("Y"), n, f"{name}.Y")
        y_vec = unpack_array(pair.get("y"), (n,), f"{name}.y")
        (check_psd if name in PSD_BLOCKS else check_pd)(y_mat, f"{name}.Y")
        blocks[name] = (y_mat, y_vec)
    warm = msg.get("warm", False)
    if not isinstance(warm, bool):
        raise WireError("schema", "field 'warm' must be a boolean")
    return {"k": msg["k"], "t": float(msg["t"]), "sender": key_node, "round": rnd, "blocks": blocks,
            "t_pub": float(_field(msg, "t_pub", (int, float))), "warm": warm}


def decode_meas(payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> dict:
    """Validate a scan on ``meas/<key_node>`` (sender must be ``truth``): ``returns`` is ``(J, m)`` or None
    (no scan), ``pose`` the sensor position or None (the configured one)."""
    msg = unpack(payload)
    if msg["kind"] != "meas":
        raise WireError("kind", f"kind {msg['kind']!r} on a measurement key")
    if msg.get("sender") != "truth" or msg.get("node") != key_node:
        raise WireError("sender_mismatch", f"sender {msg.get('sender')!r} / node {msg.get('node')!r} on key of node {key_node}")
    check_step(msg, lo, hi)
    present = _field(msg, "present", bool)
    returns = unpack_returns(msg.get("returns"), m) if present else None
    pose = within_range(unpack_array(msg["pose"], (3,), "pose"), "pose") if present and "pose" in msg else None
    return {"k": msg["k"], "t": float(msg["t"]), "returns": returns, "pose": pose,
            "t_pub": float(_field(msg, "t_pub", (int, float)))}


def _scan_fields(obj: dict, m: int, relayed: bool = False) -> dict:
    """A scan's ``origin``, ``returns`` ``(J, m)`` or None, ``pose`` and SPD noise ``R`` (None without returns)."""
    origin = _field(obj, "origin", int)
    if not 0 <= origin < 1000:
        raise WireError("schema", f"origin {origin} out of range")
    out = {"origin": origin, "returns": None, "pose": None, "noise_cov": None}
    if not _field(obj, "present", bool):
        if relayed:
            raise WireError("schema", f"a relay carries scans with returns only, not origin {origin}'s absent one")
        return out
    noise = unpack_symmetric(obj.get("R"), m, "R")
    check_pd(noise, "R")
    out.update(returns=unpack_returns(obj.get("returns"), m),
               pose=within_range(unpack_array(obj.get("pose"), (3,), "pose"), "pose"),
               noise_cov=noise)
    return out


def decode_scan(payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> dict:
    """Validate a message on ``scan/<key_node>``: a forwarded scan (``kind`` scan: returns ``(J, m)``, pose,
    SPD noise) or a relay (``kind`` relay: ``scans``, a list of such scans with their origins)."""
    msg = unpack(payload)
    if msg["kind"] not in ("scan", "relay"):
        raise WireError("kind", f"kind {msg['kind']!r} on a scan key")
    if msg.get("sender") != key_node:
        raise WireError("sender_mismatch", f"sender {msg.get('sender')!r} on key of node {key_node}")
    check_step(msg, lo, hi)
    out = {"kind": msg["kind"], "k": msg["k"], "t": float(msg["t"]), "sender": key_node,
           "t_pub": float(_field(msg, "t_pub", (int, float)))}
    if msg["kind"] == "scan":
        out.update(_scan_fields(msg, m))
        return out
    scans = _field(msg, "scans", list)
    if len(scans) > MAX_RELAYED or not all(isinstance(s, dict) for s in scans):
        raise WireError("schema", f"scans: expected at most {MAX_RELAYED} maps")
    out["scans"] = [_scan_fields(s, m, relayed=True) for s in scans]
    if len({s["origin"] for s in out["scans"]}) != len(out["scans"]):
        raise WireError("schema", "scans: an origin relayed twice")
    return out


def encode_relay(k: int, t: float, sender: int, scans: Sequence[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
                 t_pub: float) -> tuple[bytes, int]:
    """Node ``sender``'s relay of the scans it received for step k: ``(origin, returns (J, m), pose, noise)``
    each (only scans with returns: "no scan" needs no relay). Returns the message and how many scans it left
    out: scans are kept in the given order while the message stays within MAX_MESSAGE_BYTES (a hub of a
    cluttered network), so a relay is never refused for its size and the receivers never wait for one."""
    entries = [{"origin": int(origin), "present": True, "returns": pack_array(np.atleast_2d(returns)),
                "pose": pack_array(pose), "R": pack_symmetric(noise)} for origin, returns, pose, noise in scans]
    whole = encode("relay", k, t, sender, scans=entries, t_pub=t_pub)
    if len(whole) <= MAX_MESSAGE_BYTES:  # the common case: everything fits
        return whole, 0
    budget = MAX_MESSAGE_BYTES - len(encode("relay", k, t, sender, scans=[], t_pub=t_pub)) - 16
    kept = []
    for entry in entries:
        size = len(msgpack.packb(entry, use_bin_type=True))
        if size <= budget:
            kept.append(entry)
            budget -= size
    return encode("relay", k, t, sender, scans=kept, t_pub=t_pub), len(entries) - len(kept)


def encode_est(k: int, t: float, sender: int, mean: np.ndarray, cov: np.ndarray,
               samples: np.ndarray | None = None, beta: np.ndarray | None = None,
               round_ms: Sequence[float] | None = None, **fields: Any) -> bytes:
    """A node's posterior for step k (kinematic mean and covariance) with timings and counters; for viewers,
    optionally ``samples`` ``(S, n)`` of its particle cloud and ``beta`` ``(J,)``, the association probability
    of each return of its scan; ``round_ms``: how long each fusion round of the prior took (ms)."""
    if round_ms:
        fields["round_ms"] = pack_array(np.asarray(round_ms, dtype=float))
    if samples is not None:
        fields["samples"] = pack_array(samples)
    if beta is not None:
        fields["beta"] = pack_array(beta)
    return encode("est", k, t, sender, x=pack_array(mean), P=pack_symmetric(cov), **fields)


def decode_est(payload: bytes, key_node: int) -> dict:
    msg = unpack(payload)
    if msg["kind"] != "est":
        raise WireError("kind", f"kind {msg['kind']!r} on an estimate key")
    if msg.get("sender") != key_node:
        raise WireError("sender_mismatch", f"sender {msg.get('sender')!r} on key of node {key_node}")
    x_obj = msg.get("x")
    if not isinstance(x_obj, dict) or not isinstance(x_obj.get("shape"), list) or len(x_obj["shape"]) != 1:
        raise WireError("schema", "x: expected a vector")
    n = int(x_obj["shape"][0])
    if not 1 <= n <= 64:
        raise WireError("shape", f"x: dimension {n} out of range")
    out = dict(msg)
    out["x"] = unpack_array(x_obj, (n,), "x")
    out["P"] = unpack_symmetric(msg.get("P"), n, "P")
    out["samples"] = _optional_rows(msg.get("samples"), n, MAX_SAMPLES, "samples")
    beta = _optional_rows(msg.get("beta"), None, MAX_RETURNS, "beta")
    if beta is not None and not np.all((beta >= 0.0) & (beta <= 1.0)):
        raise WireError("schema", "beta: association probabilities must lie in [0, 1]")
    out["beta"] = beta
    rounds = _optional_rows(msg.get("round_ms"), None, MAX_ROUNDS, "round_ms")
    if rounds is not None and not np.all(rounds >= 0.0):
        raise WireError("schema", "round_ms: round durations must be non-negative")
    out["round_ms"] = rounds
    return out


def _optional_rows(obj: Any, width: int | None, cap: int, name: str) -> np.ndarray | None:
    """An optional ``(S, width)`` array (``(S,)`` when ``width`` is None) with S <= ``cap``; None if absent."""
    if obj is None:
        return None
    shape = obj.get("shape") if isinstance(obj, dict) else None
    if not isinstance(shape, list) or len(shape) != (1 if width is None else 2):
        raise WireError("schema", f"{name}: expected a {'vector' if width is None else f'(S, {width}) array'}")
    rows = shape[0]
    if not isinstance(rows, int) or isinstance(rows, bool) or not 0 <= rows <= cap:
        raise WireError("shape", f"{name}: {rows!r} rows, expected 0 to {cap}")
    return unpack_array(obj, (rows,) if width is None else (rows, width), name)


def encode_truth(k: int, t: float, x: np.ndarray, t_pub: float) -> bytes:
    return encode("truth", k, t, "truth", x=pack_array(x), t_pub=t_pub)


def decode_truth(payload: bytes) -> dict:
    msg = unpack(payload)
    if msg["kind"] != "truth" or msg.get("sender") != "truth":
        raise WireError("kind", "not a truth message from truth")
    x_obj = msg.get("x")
    n = len(x_obj["shape"]) == 1 and x_obj["shape"][0] if isinstance(x_obj, dict) and isinstance(x_obj.get("shape"), list) else 0
    if not n or not 1 <= n <= 64:
        raise WireError("shape", "x: expected a vector")
    return {"k": msg["k"], "t": float(msg["t"]), "x": unpack_array(x_obj, (n,), "x"), "t_pub": msg.get("t_pub")}


def encode_start(t0: float, ts: float, steps: int, mode: str, participants: list[int], deadline_frac: float,
                 x0: np.ndarray) -> bytes:
    """The run's start: timing, participants and the initial estimate ``x0`` every tracker starts from."""
    return encode("start", 0, 0.0, "truth", t0=t0, ts=ts, steps=steps, mode=mode, participants=participants,
                  deadline_frac=deadline_frac, x0=pack_array(x0))


def decode_start(payload: bytes) -> dict:
    msg = unpack(payload)
    if msg["kind"] != "start" or msg.get("sender") != "truth":
        raise WireError("kind", "not a start message from truth")
    t0, ts, steps = _field(msg, "t0", (int, float)), _field(msg, "ts", (int, float)), _field(msg, "steps", int)
    mode, parts = _field(msg, "mode", str), _field(msg, "participants", list)
    frac = _field(msg, "deadline_frac", (int, float))
    if not (math.isfinite(t0) and math.isfinite(ts) and ts > 0 and steps > 0 and 0 < frac < 1):
        raise WireError("schema", "start: t0/ts/steps/deadline_frac out of range")
    if mode not in ("realtime", "lockstep") or not all(isinstance(p, int) and not isinstance(p, bool) for p in parts):
        raise WireError("schema", "start: bad mode or participants")
    x0_obj = msg.get("x0")
    if not isinstance(x0_obj, dict) or not isinstance(x0_obj.get("shape"), list) or len(x0_obj["shape"]) != 1 \
            or not isinstance(x0_obj["shape"][0], int) or not 1 <= x0_obj["shape"][0] <= MAX_DIM:
        raise WireError("schema", "start: x0 must be a vector")
    return {"t0": float(t0), "ts": float(ts), "steps": steps, "mode": mode, "participants": parts,
            "deadline_frac": float(frac), "x0": unpack_array(x0_obj, (x0_obj["shape"][0],), "x0")}


def encode_stop(k: int) -> bytes:
    return encode("stop", k, 0.0, "truth")
