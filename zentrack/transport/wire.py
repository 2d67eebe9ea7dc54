"""The wire format in one name: :mod:`zentrack.transport.codec` (framing, limits, checks, :class:`WireError`)
and :mod:`zentrack.transport.messages` (one typed class per kind), re-exported.

``from zentrack.transport import wire`` then ``wire.WireError``, ``wire.MAX_ROUNDS``,
``wire.Measurement.decode(...)``, ``wire.RoundMessage(...).encode()`` and so on (the scans neighbours exchange
are in :mod:`zentrack.transport.scan_messages`).
"""
from __future__ import annotations

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
from zentrack.transport.detection_messages import Detection
from zentrack.transport.messages import (
    COUNTER_MAPS,
    EstimateMessage,
    Measurement,
    RoundMessage,
    Start,
    Stop,
    Truth,
    check_counters,
)
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan, decode_scan_key

__all__ = [
    "KINDS", "LOOP_MAX_VALUES", "MAX_BLOCK_NAME", "MAX_BLOCKS", "MAX_COORDINATE", "MAX_COUNT", "MAX_COUNTER_NAME",
    "MAX_COUNTERS", "MAX_DIM", "MAX_MESSAGE_BYTES", "MAX_NODES", "MAX_RELAYED", "MAX_RETURNS", "MAX_ROUNDS",
    "MAX_SAMPLES", "PSD_BLOCKS", "REASONS", "SCHEMA_VERSION", "COUNTER_MAPS",
    "Message", "WireError", "check_pd", "check_psd", "check_step", "check_counters", "encode", "pack_array",
    "pack_blocks", "pack_symmetric", "unpack", "unpack_array", "unpack_returns", "unpack_symmetric", "within_range",
    "Detection", "EstimateMessage", "ForwardedScan", "Measurement", "Relay", "RelayedScan", "RoundMessage", "Start", "Stop",
    "Truth", "decode_scan_key",
]
