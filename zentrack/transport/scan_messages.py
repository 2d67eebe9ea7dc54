"""Typed wire messages of the scans neighbours exchange (fusion rules with ``share_scans`` / ``relay_scans``).

- :class:`ForwardedScan` (``scan``, node -> neighbours, on ``scan/<i>``): the node's own scan forwarded with the
  pose and noise of its sensor (no returns: "no scan this step", so the neighbours need not wait);
- :class:`Relay` (``relay``, on the same key): the neighbours' scans it received for step k
  (:class:`RelayedScan` each); :func:`decode_scan_key` reads that key, which carries both kinds.

Same conventions as :mod:`zentrack.transport.messages`: frozen classes, ``encode()`` beside a ``decode()`` that
returns the class or raises :class:`~zentrack.transport.codec.WireError` and nothing else.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Self

import msgpack
import numpy as np

from zentrack.transport.codec import (
    MAX_MESSAGE_BYTES,
    MAX_RELAYED,
    WireError,
    built,
    check_pd,
    encode,
    field,
    header,
    node_id,
    node_message,
    number,
    pack_array,
    pack_symmetric,
    packed,
    unpack_pose,
    unpack_returns,
    unpack_symmetric,
    wire_kind,
)

__all__ = ["RelayedScan", "ForwardedScan", "Relay", "decode_scan_key"]


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


@wire_kind("scan")
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

    def check_origin(self, sender: int) -> None:
        """A forwarded scan is its sender's own (relays carry others'): WireError if it claims another origin."""
        if self.origin != sender:
            raise WireError("sender_mismatch", f"scan from node {sender} claims origin {self.origin}: a "
                                               f"forwarded scan is the sender's own (relays carry others')")


@wire_kind("relay")
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
