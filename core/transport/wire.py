"""The wire format in one name: :mod:`zentrack.transport.codec` (framing, limits, checks, :class:`WireError`)
and :mod:`zentrack.transport.messages` (one typed class per kind), re-exported.

``from zentrack.transport import wire`` then ``wire.WireError``, ``wire.MAX_ROUNDS``,
``wire.Measurement.decode(...)``, ``wire.RoundMessage(...).encode()`` and so on. The block at the end keeps
the dict-returning functions the node's schedule still calls while it moves to the classes; nothing else
uses them.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from zentrack.transport.codec import (
    KINDS,
    LOOP_MAX_VALUES,
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
    PSD_BLOCKS,
    REASONS,
    SCHEMA_VERSION,
    Message,
    WireError,
    check_pd,
    check_psd,
    check_step,
    encode,
    pack_array,
    pack_blocks,
    pack_symmetric,
    unpack,
    unpack_array,
    unpack_returns,
    unpack_symmetric,
    within_range,
)
from zentrack.transport.estimate_message import COUNTER_MAPS, check_counters
from zentrack.transport.messages import (
    EstimateMessage,
    ForwardedScan,
    Measurement,
    Relay,
    RelayedScan,
    RoundMessage,
    Start,
    Stop,
    Truth,
    decode_scan_key,
)

__all__ = [
    "KINDS", "LOOP_MAX_VALUES", "MAX_BLOCK_NAME", "MAX_BLOCKS", "MAX_COORDINATE", "MAX_COUNT", "MAX_COUNTER_NAME",
    "MAX_COUNTERS", "MAX_DIM", "MAX_MESSAGE_BYTES", "MAX_NODES", "MAX_RELAYED", "MAX_RETURNS", "MAX_ROUNDS",
    "MAX_SAMPLES", "PSD_BLOCKS", "REASONS", "SCHEMA_VERSION", "COUNTER_MAPS",
    "Message", "WireError", "check_pd", "check_psd", "check_step", "check_counters", "encode", "pack_array",
    "pack_blocks", "pack_symmetric", "unpack", "unpack_array", "unpack_returns", "unpack_symmetric", "within_range",
    "EstimateMessage", "ForwardedScan", "Measurement", "Relay", "RelayedScan", "RoundMessage", "Start", "Stop",
    "Truth", "decode_scan_key",
    # TRANSITION
    "encode_prior", "decode_prior", "encode_meas", "decode_meas", "encode_scan", "decode_scan", "encode_relay",
    "encode_est", "decode_est", "encode_start", "decode_start", "encode_stop",
]


# TRANSITION: removed once node/ uses the message classes
# The functions node/schedule.py (and tests/test_node_schedule.py, which drives it) call today: each is the
# class's encode or decode, returning the dicts the schedule reads.

def encode_prior(k: int, t: float, sender: int, blocks: dict[str, tuple[np.ndarray, np.ndarray]], t_pub: float,
                 warm: bool = False, round: int = 1) -> bytes:
    return RoundMessage(k, t, sender, round, blocks, t_pub, warm).encode()


def decode_prior(payload: bytes, key_node: int, dims: dict[str, int] | int, lo: int | None = None,
                 hi: int | None = None, max_round: int = 1) -> dict:
    p = RoundMessage.decode(payload, key_node, dims, lo, hi, max_round)
    return {"k": p.k, "t": p.t, "sender": p.sender, "round": p.round, "blocks": p.blocks, "t_pub": p.t_pub,
            "warm": p.warm}


def encode_meas(k: int, t: float, node: int, returns: np.ndarray | None, t_pub: float,
                pose: np.ndarray | None = None) -> bytes:
    return Measurement(k, t, node, returns, pose, t_pub).encode()


def decode_meas(payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> dict:
    s = Measurement.decode(payload, key_node, m, lo, hi)
    return {"k": s.k, "t": s.t, "returns": s.returns, "pose": s.pose, "t_pub": s.t_pub}


def encode_scan(k: int, t: float, sender: int, origin: int, returns: np.ndarray | None, pose: np.ndarray | None,
                noise_cov: np.ndarray | None, t_pub: float) -> bytes:
    return ForwardedScan(k, t, sender, origin, returns, pose, noise_cov, t_pub).encode()


def decode_scan(payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> dict:
    sc = decode_scan_key(payload, key_node, m, lo, hi)
    out: dict[str, Any] = {"kind": "scan" if isinstance(sc, ForwardedScan) else "relay", "k": sc.k, "t": sc.t,
                           "sender": sc.sender, "t_pub": sc.t_pub}
    if isinstance(sc, ForwardedScan):
        out.update(origin=sc.origin, returns=sc.returns, pose=sc.pose, noise_cov=sc.noise_cov)
    else:
        out["scans"] = [{"origin": s.origin, "returns": s.returns, "pose": s.pose, "noise_cov": s.noise_cov}
                        for s in sc.scans]
    return out


def encode_relay(k: int, t: float, sender: int, scans: Sequence[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
                 t_pub: float) -> tuple[bytes, int]:
    return Relay(k, t, sender, tuple(RelayedScan(*s) for s in scans), t_pub).encode_capped()


def encode_est(k: int, t: float, sender: int, mean: np.ndarray, cov: np.ndarray,
               samples: np.ndarray | None = None, beta: np.ndarray | None = None,
               round_ms: Sequence[float] | None = None, **fields: Any) -> bytes:
    """``fields``: the other :class:`EstimateMessage` fields by name (``t_pub`` 0.0 when not given)."""
    fields.setdefault("t_pub", 0.0)
    return EstimateMessage(k, t, sender, mean, cov, samples=samples, beta=beta,
                           round_ms=np.asarray(round_ms, dtype=float) if round_ms is not None and len(round_ms) else None, **fields).encode()


def decode_est(payload: bytes, key_node: int) -> dict:
    e = EstimateMessage.decode(payload, key_node)
    return {name: getattr(e, name) for name in EstimateMessage.__dataclass_fields__}


def encode_start(t0: float, ts: float, steps: int, mode: str, participants: list[int], deadline_frac: float,
                 x0: np.ndarray) -> bytes:
    return Start(t0, ts, steps, mode, tuple(participants), deadline_frac, x0).encode()


def decode_start(payload: bytes) -> dict:
    s = Start.decode(payload)
    return {"t0": s.t0, "ts": s.ts, "steps": s.steps, "mode": s.mode, "participants": list(s.participants),
            "deadline_frac": s.deadline_frac, "x0": s.x0}


def encode_stop(k: int) -> bytes:
    return Stop(k).encode()
