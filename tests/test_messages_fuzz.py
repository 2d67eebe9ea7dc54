"""Nothing but ``WireError`` escapes a decoder, and nothing ill-typed comes out of one.

Every decoder of every kind gets random bytes, random msgpack maps (random and known field names, values of
every msgpack type), and valid messages (those of ``test_messages``) with each field, at any depth (arrays'
shapes and data, blocks, relayed scans, counters), replaced by every wrong type and extreme value, or removed:
exhaustively over the fields and a list of hostile values, and by hypothesis over random values. A decoder
either raises :class:`WireError` or returns its class whose every field has its declared type: finite floats,
ints (never bools), bools, float64 arrays of finite values, counters of counts. That is what lets the
recorder and the viewer read a decoded message without guarding each field.
"""
from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_messages import MESSAGES, payload_of

from zentrack.transport import wire
from zentrack.transport.codec import MAX_COUNT, WireError
from zentrack.transport.messages import COUNTER_MAPS, EstimateMessage, Measurement, RoundMessage, Start, Stop, Truth
from zentrack.transport.miss_notes import MissNote
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan, decode_scan_key

#: every decoder, with the arguments a receiver passes (those the messages of test_messages were made for)
DECODERS: dict[str, Callable[[bytes], object]] = {
    "meas": lambda p: Measurement.decode(p, 2, 2, 0, 10),
    "prior": lambda p: RoundMessage.decode(p, 3, 12, 0, 10, max_round=3),
    "prior_psd": lambda p: RoundMessage.decode(p, 3, {"prior": 12, "increment": 12}, max_round=3),
    "scan": lambda p: ForwardedScan.decode(p, 1, 2, 0, 10),
    "relay": lambda p: Relay.decode(p, 1, 2, 0, 10),
    "scan_key": lambda p: decode_scan_key(p, 1, 2, 0, 10),
    "est": lambda p: EstimateMessage.decode(p, 5),
    "truth": Truth.decode,
    "start": Start.decode,
    "stop": Stop.decode,
}
#: the decoders that read each message of test_messages
READERS = {"prior": ["prior"], "meas": ["meas"], "meas_none": ["meas"], "scan": ["scan", "scan_key"],
           "scan_none": ["scan", "scan_key"], "relay": ["relay", "scan_key"], "est": ["est"], "est_coasted": ["est"], "est_missed": ["est"],
           "truth": ["truth"], "start": ["start"], "stop": ["stop"]}
#: an increment block (PSD) and a prior block in one message, for the PSD path
PSD_PRIOR = RoundMessage(7, 0.7, 3, 1, {"prior": (np.eye(12), np.zeros(12)), "increment": (np.zeros((12, 12)),
                                                                                          np.zeros(12))}, 1.0)

NAN, INF = math.nan, math.inf
#: wrong types and extreme values of every msgpack type
HOSTILE = [
    None, True, False, 0, -1, 1, 7, 999, 1000, 2**31, 2**63 - 1, -(2**63), 2**64 - 1,
    0.0, -0.0, 0.5, -2.5, NAN, INF, -INF, 1e308, -1e308, 1.7976931348623157e308, 5e-324,
    "", "x", "state", "truth", "est", "\u00b2", "x" * 4000,
    b"", b"\x00" * 7, b"\x00" * 8, b"\xff" * 48, b"\x00" * 4096,
    [], [0], [1.5], ["a"], [None], [[]], [True], [0, 0], [2, 2], list(range(4000)), [1e308] * 3, [NAN],
    {}, {"a": 1}, {"": 0}, {"x" * 100: 1}, {"stale": -1}, {"shape": [2], "data": b"\x00" * 16},
    {"shape": [6], "data": b"\x00" * 48}, {"sym": 2, "data": b"\x00" * 24}, {"sym": 6, "data": b"\x00" * 168},
    {"Y": {}, "y": {}}, {"origin": 2, "present": True}, {"rejected": [1]},
]
#: what a decoded field holds (name -> check); every field of every class is listed
FIELD_TYPES: dict[str, str] = {
    "k": "count", "node": "count", "sender": "count", "round": "count", "origin": "count", "fused": "count",
    "steps": "count", "t": "float", "t_pub": "float", "t0": "float", "ts": "float", "deadline_frac": "float",
    "t_meas_pub": "float?", "t_recv": "float?", "update_us": "float?", "warm": "bool", "coasted": "bool",
    "miss": "bool", "returns": "array?", "pose": "array?", "noise_cov": "array?", "x": "array", "P": "array",
    "x0": "array", "round_ms": "array?", "samples": "array?", "beta": "array?", "blocks": "blocks",
    "scans": "scans", "neighbours": "ids", "participants": "ids", "counters": "counters?", "mode": "mode",
    "miss_notes": "notes",
}


def finite_array(a) -> bool:
    return isinstance(a, np.ndarray) and a.dtype == np.float64 and bool(np.isfinite(a).all())


def is_count(v) -> bool:
    return type(v) is int and 0 <= v <= MAX_COUNT


def counts(d) -> bool:
    return type(d) is dict and all(type(n) is str and is_count(c) for n, c in d.items())


CHECKS: dict[str, Callable[[object], bool]] = {
    "count": is_count,
    "float": lambda v: type(v) is float and math.isfinite(v),
    "float?": lambda v: v is None or (type(v) is float and math.isfinite(v)),
    "bool": lambda v: type(v) is bool,
    "array": finite_array,
    "array?": lambda v: v is None or finite_array(v),
    "blocks": lambda v: type(v) is dict and all(type(n) is str and len(p) == 2 and finite_array(p[0]) and finite_array(p[1])
                                                for n, p in v.items()),
    "scans": lambda v: type(v) is tuple and all(type(s) is RelayedScan and well_typed(s) for s in v),
    "ids": lambda v: type(v) in (tuple, list) and all(type(j) is int and 0 <= j < wire.MAX_NODES for j in v),
    "counters?": lambda v: v is None or (type(v) is dict and all(
        type(n) is str and (counts(c) if n in COUNTER_MAPS else is_count(c)) for n, c in v.items())),
    "mode": lambda v: v in ("realtime", "lockstep"),
    "notes": lambda v: type(v) is tuple and all(
        type(n) is MissNote and is_count(n.k) and is_count(n.steps) and n.steps >= 1 and type(n.kind) is str
        and type(n.phase) is str and all(type(x) is float and math.isfinite(x) and x >= 0
                                         for x in (n.late_ms, n.idle_ms, n.work_ms)) for n in v),
}


def well_typed(obj) -> bool:
    """Every field of a decoded message has its declared type ."""
    values = obj if isinstance(obj, dict) else {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict) and "scans" in values:  # a relay as a dict: its scans as dicts
        return all(well_typed(s) for s in values["scans"]) and CHECKS["count"](values["k"])
    bad = [name for name, value in values.items() if name != "kind" and not CHECKS[FIELD_TYPES[name]](value)]
    return not bad


def outcome(name: str, payload: bytes) -> str:
    """'ok' (a well-typed message) or the WireError's reason; anything else raised fails the test."""
    try:
        got = DECODERS[name](payload)
    except WireError as err:
        assert err.reason in wire.REASONS
        return err.reason
    assert well_typed(got), (name, got)
    return "ok"


def paths(obj, prefix: tuple = ()) -> list[tuple]:
    """Every key path into a message map (arrays' shape and data, blocks, scans and counters included)."""
    out = []
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for key, value in items:
        out.append(prefix + (key,))
        out += paths(value, prefix + (key,))
    return out


def replaced(msg: dict, path: tuple, value, remove: bool = False) -> bytes:
    out = copy.deepcopy(msg)
    parent = out
    for key in path[:-1]:
        parent = parent[key]
    if remove:
        parent.pop(path[-1]) if isinstance(parent, dict) else parent.__delitem__(path[-1])
    else:
        parent[path[-1]] = value
    return msgpack.packb(out, use_bin_type=True)


BASES = {name: (msgpack.unpackb(payload_of(name), raw=False), READERS[name]) for name in MESSAGES}
BASES["prior_psd"] = (msgpack.unpackb(PSD_PRIOR.encode(), raw=False), ["prior_psd"])


@pytest.mark.parametrize("name", sorted(BASES))
def test_every_field_replaced_by_every_hostile_value_gives_a_wire_error_or_a_well_typed_message(name):
    msg, readers = BASES[name]
    assert all(outcome(r, msgpack.packb(msg, use_bin_type=True)) == "ok" for r in readers)  # the valid one passes
    refused = 0
    for path in paths(msg):
        variants = [replaced(msg, path, value) for value in HOSTILE] + [replaced(msg, path, None, remove=True)]
        if path[-1] == "data":  # the array's own length, full of NaN, inf, the largest finite double
            count = len(msg_at(msg, path)) // 8
            variants += [replaced(msg, path, np.full(count, v).tobytes()) for v in (NAN, -INF, 1e308, -1.7e308)]
        for payload in variants:
            for reader in readers:
                refused += outcome(reader, payload) != "ok"
    assert refused > len(paths(msg)) * len(HOSTILE) // 2  # most of them are refused


def msg_at(msg: dict, path: tuple):
    for key in path:
        msg = msg[key]
    return msg


def test_a_wrong_estimate_is_refused_whatever_field_is_wrong():
    """The issue's cases: ``fused`` a string, counters a list, neighbours holding a float (before, decoding
    returned the map and the recorder's ``int(e.get("fused") or 0)`` raised outside its error handler)."""
    msg = BASES["est"][0]
    for path, value in [(("fused",), "3"), (("counters",), [1, 2]), (("neighbours",), [4, 6.0]),
                        (("counters", "rejected"), 3), (("counters", "steps"), -1), (("round_ms",), [1.0]),
                        (("update_us",), NAN), (("coasted",), "no"), (("t_meas_pub",), INF)]:
        assert outcome("est", replaced(msg, path, value)) != "ok", path


def msgpack_values(extremes: bool = True) -> st.SearchStrategy:
    leaves = (st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1)
              | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=40) | st.binary(max_size=200))
    if extremes:
        leaves = leaves | st.sampled_from([x for x in HOSTILE if not isinstance(x, (list, dict))])
    arrays = st.builds(lambda shape, data: {"shape": shape, "data": data},
                       st.lists(st.integers(-2, 70), max_size=3), st.binary(max_size=400))
    packed = st.builds(lambda n, data: {"sym": n, "data": data}, st.integers(-1, 14), st.binary(max_size=400))
    return st.recursive(leaves | arrays | packed,
                        lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=8), inner, max_size=6),
                        max_leaves=12)


VALUES = msgpack_values()
FIELD_NAMES = sorted({p[-1] for msg, _ in BASES.values() for p in paths(msg) if isinstance(p[-1], str)})
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(st.binary(max_size=3000))
def test_random_bytes_give_a_wire_error(payload):
    for name in DECODERS:
        outcome(name, payload)


@FUZZ
@given(header=st.fixed_dictionaries({}, optional={
           "v": st.sampled_from([2, 2, 1, "2"]), "kind": st.sampled_from([*wire.KINDS, "bogus"]),
           "k": st.integers(-5, 12) | st.just(2**63 - 1), "t": st.floats(allow_nan=True, allow_infinity=True),
           "sender": st.sampled_from([1, 2, 3, 5, "truth", True, 1.0, None])}),
       fields=st.dictionaries(st.sampled_from(FIELD_NAMES) | st.text(max_size=6), VALUES, max_size=20))
def test_random_maps_give_a_wire_error_or_a_well_typed_message(header, fields):
    payload = msgpack.packb({**fields, **header}, use_bin_type=True)
    for name in DECODERS:
        outcome(name, payload)


@FUZZ
@given(st.sampled_from(sorted(BASES)), st.data())
def test_a_valid_message_with_a_random_field_made_random_gives_a_wire_error_or_a_well_typed_message(name, data):
    msg, readers = BASES[name]
    for _ in range(data.draw(st.integers(1, 3))):  # up to three fields at once
        path = data.draw(st.sampled_from(paths(msg)))
        msg = msgpack.unpackb(replaced(msg, path, data.draw(VALUES)), raw=False, strict_map_key=False)
    payload = msgpack.packb(msg, use_bin_type=True)
    for reader in readers:
        outcome(reader, payload)
