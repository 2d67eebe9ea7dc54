"""Typed wire messages: one frozen class per kind, its encoding beside its checked decoding.

Version 2 of the wire format (:mod:`zentrack.transport.codec` holds the framing) carries every seed's traffic:

- :class:`Measurement` (``meas``, truth -> node i): a *scan*, ``returns`` of shape ``(J, m)`` with J >= 0
  (J = 0: the sensor looked and saw nothing; None: no scan at all), and the sensor's ``pose`` at step k;
- :class:`RoundMessage` (``prior``, node -> neighbours): one fusion round's message, ``round`` (1..L) and
  ``blocks``, named information pairs (``{"state": (Y, y)}`` for a plain filter; e.g. kinematics and extent
  fused apart);
- :class:`ForwardedScan` (``scan``, node -> neighbours): a scan forwarded with the pose and noise of the
  sensor that took it;
- :class:`Relay` (``relay``, node -> neighbours, on its ``scan`` key): the neighbours' scans it received for
  step k (:class:`RelayedScan` each; rules with ``relay_scans``); :func:`decode_scan_key` reads that key;
- :class:`EstimateMessage` (``est``): a node's kinematic posterior with its timings, flags and counters
  (in :mod:`zentrack.transport.estimate_message`, re-exported here);
- :class:`Truth` (``truth``), :class:`Start` (``ctl/start``, with the run's initial estimate ``x0``) and
  :class:`Stop` (``ctl/stop``).

``encode()`` gives the bytes; ``decode(payload, ...)`` returns the class or raises
:class:`~zentrack.transport.codec.WireError` and nothing else: every field is checked, optional ones
included (an absent optional field takes its default; a present one must be of its type). Unknown fields are
ignored. The classes hold numpy arrays, so they compare by identity (``eq=False``); compare their fields, or
their encodings. The per-step decoders build their instances with :func:`~zentrack.transport.codec.built`
(without the frozen ``__init__``'s per-field ``object.__setattr__``), so the classes have no ``__slots__``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Self

import msgpack
import numpy as np

from zentrack.transport.codec import (
    MAX_BLOCK_NAME,
    MAX_BLOCKS,
    MAX_COUNT,
    MAX_MESSAGE_BYTES,
    MAX_RELAYED,
    MAX_ROUNDS,
    PSD_BLOCKS,
    WireError,
    built,
    check_pd,
    check_psd,
    check_step,
    encode,
    field,
    flag,
    header,
    node_id,
    node_message,
    number,
    pack_array,
    pack_blocks,
    pack_symmetric,
    packed,
    short,
    truth_message,
    unpack,
    unpack_array,
    unpack_pose,
    unpack_returns,
    unpack_symmetric,
    unpack_vector,
)
from zentrack.transport.estimate_message import EstimateMessage

__all__ = ["Measurement", "RoundMessage", "RelayedScan", "ForwardedScan", "Relay", "decode_scan_key", "EstimateMessage",
           "Truth", "Start", "Stop"]


@dataclass(frozen=True, eq=False)
class Measurement:
    """Node ``node``'s scan at step k: ``returns`` ``(J, m)`` (J may be 0; a ``(m,)`` vector is one return) or
    None for no scan; ``pose`` the sensor's position, or None for the configured one (sent only with
    returns)."""

    k: int
    t: float
    node: int
    returns: np.ndarray | None
    pose: np.ndarray | None
    t_pub: float

    def encode(self) -> bytes:
        msg = header("meas", self.k, self.t, "truth")
        msg["node"], msg["present"], msg["t_pub"] = self.node, self.returns is not None, self.t_pub
        if self.returns is not None:
            msg["returns"] = pack_array(np.atleast_2d(self.returns))
            if self.pose is not None:
                msg["pose"] = pack_array(self.pose)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> Self:
        """A scan on ``meas/<key_node>`` (sender ``truth``) with returns of width ``m``, step in ``lo..hi``."""
        msg = unpack(payload)
        if msg["kind"] != "meas":
            raise WireError("kind", f"kind {msg['kind']!r} on a measurement key")
        if msg.get("sender") != "truth" or msg.get("node") != key_node or type(msg.get("node")) is not int:
            raise WireError("sender_mismatch", f"sender {short(msg.get('sender'))} / node {short(msg.get('node'))} on key of "
                                               f"node {key_node}")
        check_step(msg, lo, hi)
        present = field(msg, "present", bool)
        returns = unpack_returns(msg.get("returns"), m) if present else None
        pose = unpack_pose(msg["pose"]) if present and "pose" in msg else None
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "node": key_node, "returns": returns, "pose": pose,
                           "t_pub": number(msg, "t_pub")})


@dataclass(frozen=True, eq=False)
class RoundMessage:
    """Node ``sender``'s message of fusion round ``round`` for step k: named information pairs ``(Y, y)``.
    ``warm``: the sender has no recent measurement support (it is warming up or coasted too long), so a node
    with fresh pairs leaves this one out of its fusion."""

    k: int
    t: float
    sender: int
    round: int
    blocks: dict[str, tuple[np.ndarray, np.ndarray]]
    t_pub: float
    warm: bool = False

    def encode(self) -> bytes:
        msg = header("prior", self.k, self.t, self.sender)
        msg["round"], msg["blocks"] = int(self.round), pack_blocks(self.blocks)
        msg["t_pub"], msg["warm"] = self.t_pub, bool(self.warm)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_node: int, dims: dict[str, int] | int, lo: int | None = None,
               hi: int | None = None, max_round: int = 1) -> Self:
        """A message from ``prior/<key_node>``: sender, step window, round, the block names and sizes the
        receiver expects (``dims``: name -> n; an int means one block ``state``), finiteness, SPD (PSD for
        :data:`~zentrack.transport.codec.PSD_BLOCKS`)."""
        if isinstance(dims, int):
            dims = {"state": dims}
        msg = node_message(payload, ("prior",), key_node, lo, hi)
        rnd = field(msg, "round", int)
        if not 1 <= rnd <= min(max_round, MAX_ROUNDS):
            raise WireError("schema", f"round {rnd} outside 1..{max_round}")
        raw = field(msg, "blocks", dict)
        if len(raw) > MAX_BLOCKS or not all(isinstance(b, str) and len(b) <= MAX_BLOCK_NAME for b in raw):
            raise WireError("schema", "blocks: too many or badly named")
        if set(raw) != set(dims):
            raise WireError("shape", f"blocks {sorted(raw)} != expected {sorted(dims)}")
        blocks = {}
        for name, n in dims.items():
            pair = raw[name]
            if type(pair) is not dict:
                raise WireError("schema", f"block {name!r}: expected {{Y, y}}")
            y_mat = unpack_symmetric(pair.get("Y"), n, f"{name}.Y")
            y_vec = unpack_array(pair.get("y"), (n,), f"{name}.y")
            (check_psd if name in PSD_BLOCKS else check_pd)(y_mat, f"{name}.Y")
            blocks[name] = (y_mat, y_vec)
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "sender": key_node, "round": rnd, "blocks": blocks,
                           "t_pub": number(msg, "t_pub"), "warm": flag(msg, "warm")})


# ---------------------------------------------------------------- scans exchanged between nodes

@dataclass(frozen=True, eq=False)
class RelayedScan:
    """One scan inside a :class:`Relay`: sensor ``origin``'s returns ``(J, m)``, pose and noise covariance."""

    origin: int
    returns: np.ndarray
    pose: np.ndarray
    noise_cov: np.ndarray

    def packed(self) -> dict:
        return {"origin": int(self.origin), "present": True, "returns": pack_array(np.atleast_2d(self.returns)),
                "pose": pack_array(self.pose), "R": pack_symmetric(self.noise_cov)}


def _scan_parts(obj: dict, m: int, relayed: bool) -> tuple[int, np.ndarray | None, np.ndarray | None,
                                                           np.ndarray | None]:
    """A scan map's ``origin``, and ``returns`` ``(J, m)``, ``pose`` and SPD noise ``R`` (all None without
    returns: not allowed in a relay)."""
    origin = node_id(obj.get("origin"), "origin")
    if not field(obj, "present", bool):
        if relayed:
            raise WireError("schema", f"a relay carries scans with returns only, not origin {origin}'s absent one")
        return origin, None, None, None
    noise = unpack_symmetric(obj.get("R"), m, "R")
    check_pd(noise, "R")
    return origin, unpack_returns(obj.get("returns"), m), unpack_pose(obj.get("pose")), noise


def _relayed_scan(obj: dict, m: int) -> RelayedScan:
    origin, returns, pose, noise = _scan_parts(obj, m, relayed=True)
    assert returns is not None and pose is not None and noise is not None  # a relayed scan without returns raised
    return built(RelayedScan, {"origin": origin, "returns": returns, "pose": pose, "noise_cov": noise})


@dataclass(frozen=True, eq=False)
class ForwardedScan:
    """A scan of sensor ``origin`` at step k forwarded by node ``sender`` (returns ``(J, m)``, pose, noise);
    ``returns=None`` says "no scan this step" (pose and noise None too), so the neighbours need not wait."""

    k: int
    t: float
    sender: int
    origin: int
    returns: np.ndarray | None
    pose: np.ndarray | None
    noise_cov: np.ndarray | None
    t_pub: float

    def encode(self) -> bytes:
        msg = header("scan", self.k, self.t, self.sender)
        msg["origin"], msg["present"], msg["t_pub"] = int(self.origin), self.returns is not None, self.t_pub
        if self.returns is not None:
            if self.pose is None or self.noise_cov is None:
                raise ValueError("a forwarded scan needs the pose and noise of its sensor")
            msg["returns"] = pack_array(np.atleast_2d(self.returns))
            msg["pose"], msg["R"] = pack_array(self.pose), pack_symmetric(self.noise_cov)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> Self:
        return cls.from_map(node_message(payload, ("scan",), key_node, lo, hi), m)

    @classmethod
    def from_map(cls, msg: dict, m: int) -> Self:
        """From an unpacked map whose kind, sender and step are checked."""
        origin, returns, pose, noise = _scan_parts(msg, m, relayed=False)
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "sender": msg["sender"], "origin": origin,
                           "returns": returns, "pose": pose, "noise_cov": noise, "t_pub": number(msg, "t_pub")})


@dataclass(frozen=True, eq=False)
class Relay:
    """Node ``sender``'s relay of the scans it received for step k (only scans with returns: "no scan"
    needs no relay), at most one per origin."""

    k: int
    t: float
    sender: int
    scans: tuple[RelayedScan, ...]
    t_pub: float

    def encode(self) -> bytes:
        """Every scan (a relay past MAX_MESSAGE_BYTES is refused by its receivers: see :meth:`encode_capped`)."""
        return encode("relay", self.k, self.t, self.sender, scans=[s.packed() for s in self.scans], t_pub=self.t_pub)

    def encode_capped(self) -> tuple[bytes, int]:
        """The message and how many scans it left out: scans are kept in order while the message stays within
        MAX_MESSAGE_BYTES (a hub of a cluttered network), so a relay is never refused for its size and the
        receivers never wait for one."""
        entries = [s.packed() for s in self.scans]
        whole = encode("relay", self.k, self.t, self.sender, scans=entries, t_pub=self.t_pub)
        if len(whole) <= MAX_MESSAGE_BYTES:  # the common case: everything fits
            return whole, 0
        budget = MAX_MESSAGE_BYTES - len(encode("relay", self.k, self.t, self.sender, scans=[], t_pub=self.t_pub)) - 16
        kept = []
        for entry in entries:
            size = len(msgpack.packb(entry, use_bin_type=True))
            if size <= budget:
                kept.append(entry)
                budget -= size
        return encode("relay", self.k, self.t, self.sender, scans=kept, t_pub=self.t_pub), len(entries) - len(kept)

    @classmethod
    def decode(cls, payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> Self:
        return cls.from_map(node_message(payload, ("relay",), key_node, lo, hi), m)

    @classmethod
    def from_map(cls, msg: dict, m: int) -> Self:
        """From an unpacked map whose kind, sender and step are checked."""
        raw = field(msg, "scans", list)
        if len(raw) > MAX_RELAYED or not all(type(s) is dict for s in raw):
            raise WireError("schema", f"scans: expected at most {MAX_RELAYED} maps")
        scans = tuple(_relayed_scan(s, m) for s in raw)
        if len({s.origin for s in scans}) != len(scans):
            raise WireError("schema", "scans: an origin relayed twice")
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "sender": msg["sender"], "scans": scans,
                           "t_pub": number(msg, "t_pub")})


def decode_scan_key(payload: bytes, key_node: int, m: int, lo: int | None = None,
                    hi: int | None = None) -> ForwardedScan | Relay:
    """A message on ``scan/<key_node>``: a forwarded scan or a relay, told apart by its kind."""
    msg = node_message(payload, ("scan", "relay"), key_node, lo, hi)
    return (ForwardedScan if msg["kind"] == "scan" else Relay).from_map(msg, m)


# ---------------------------------------------------------------- the truth's messages

@dataclass(frozen=True, eq=False)
class Truth:
    """The true state ``x`` at step k (for viewers)."""

    k: int
    t: float
    x: np.ndarray
    t_pub: float

    def encode(self) -> bytes:
        return encode("truth", self.k, self.t, "truth", x=pack_array(self.x), t_pub=self.t_pub)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        msg = truth_message(payload, "truth")
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "x": unpack_vector(msg.get("x"), "x"),
                           "t_pub": number(msg, "t_pub")})


@dataclass(frozen=True, eq=False)
class Start:
    """The run's start: ``t0`` (wall clock of step 0), the period ``ts``, ``steps``, ``mode`` (realtime or
    lockstep), the ``participants``, the deadline as a fraction of the period, and the initial estimate ``x0``
    every tracker starts from."""

    t0: float
    ts: float
    steps: int
    mode: str
    participants: tuple[int, ...]
    deadline_frac: float
    x0: np.ndarray

    def encode(self) -> bytes:
        return encode("start", 0, 0.0, "truth", t0=self.t0, ts=self.ts, steps=self.steps, mode=self.mode,
                      participants=list(self.participants), deadline_frac=self.deadline_frac, x0=pack_array(self.x0))

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        msg = truth_message(payload, "start")
        t0, ts, steps = number(msg, "t0"), number(msg, "ts"), field(msg, "steps", int)
        mode, parts = field(msg, "mode", str), field(msg, "participants", list)
        frac = number(msg, "deadline_frac")
        if not (ts > 0 and 0 < steps <= MAX_COUNT and 0 < frac < 1):
            raise WireError("schema", "start: ts/steps/deadline_frac out of range")
        if mode not in ("realtime", "lockstep"):
            raise WireError("schema", f"start: bad mode {short(mode)}")
        participants = tuple(node_id(p, "start: participants") for p in parts)
        return cls(t0, ts, steps, mode, participants, frac, unpack_vector(msg.get("x0"), "start: x0"))


@dataclass(frozen=True, eq=False)
class Stop:
    """The run's end (the truth's last step, or the step at which it gave up)."""

    k: int

    def encode(self) -> bytes:
        return encode("stop", self.k, 0.0, "truth")

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        return cls(truth_message(payload, "stop")["k"])
