"""The typed wire messages: the bytes of wire v2, exact round trips, and the transition functions' dicts.

The golden digests below are of the bytes the functions of ``zentrack/transport/wire.py`` before the classes
(commit a8f3f0c: ``encode_prior``, ``encode_meas``, ... ``encode_stop``) gave for the same inputs: the classes
must not change the wire format (lockstep runs give the same numbers, old and new nodes interoperate).
"""
from __future__ import annotations

import dataclasses
import hashlib

import msgpack
import numpy as np
import pytest

from zentrack.transport import wire
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Start, Stop, Truth
from zentrack.transport.miss_notes import MissNote
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan, decode_scan_key


def spd(n: int) -> np.ndarray:
    a = np.arange(n * n, dtype=float).reshape(n, n) / (n * n)
    return a @ a.T + np.eye(n)


def exact_spd(n: int) -> np.ndarray:
    """An SPD matrix whose every value is exact in binary (integer products over a power of two): the same bits
    whichever BLAS kernel computes it. (``spd(12)``'s matrix product differs in its last bits between CPUs.)"""
    b = np.arange(n * n, dtype=np.int64).reshape(n, n)
    return (b @ b.T).astype(float) / 2**20 + np.eye(n)


X = np.arange(6.0) - 2.5
POSE = np.array([1.0, 2.0, 3.0])
COUNTERS = {"steps": 8, "misses": 1, "rejected": {"stale": 2}, "dropped": {"prior/rate": 1},
            "refused": {"update": 0, "fusion": 0}, "incarnation": 4242}

#: name -> (message, the decoder's arguments after the payload)
MESSAGES = {
    "prior": (RoundMessage(7, 0.7, 3, 2, {"state": (exact_spd(12), np.arange(12.0))}, 1700000000.25, warm=True),
              (3, 12, None, None, 2)),
    "meas": (Measurement(7, 0.7, 2, np.array([[0.1, -0.2], [0.3, 0.4]]), POSE, 1700000000.5), (2, 2)),
    "meas_none": (Measurement(7, 0.7, 2, None, POSE, 1700000000.5), (2, 2)),  # no scan: the pose is not sent
    "scan": (ForwardedScan(7, 0.7, 1, 1, np.array([0.1, -0.2]), POSE, spd(2), 1700000000.75), (1, 2)),
    "scan_none": (ForwardedScan(7, 0.7, 1, 1, None, None, None, 1700000000.75), (1, 2)),
    "relay": (Relay(7, 0.7, 1, (RelayedScan(4, np.array([0.1, -0.2]), POSE, spd(2)),
                                RelayedScan(6, np.zeros((0, 2)), np.zeros(3), spd(2))), 1700000001.0), (1, 2)),
    "est": (EstimateMessage(7, 0.7, 5, X, spd(6), 1700000000.875, 1700000000.5, 1700000000.625, 41.5, 3, False, True,
                            False, (4, 6), np.array([1.5, 2.25]), np.tile(X, (3, 1)), np.array([0.25, 0.75]), COUNTERS),
            (5,)),
    "est_coasted": (EstimateMessage(8, 0.8, 5, X, spd(6), 1700000000.875, update_us=12.0, fused=1, coasted=True,
                                    miss=True), (5,)),
    "est_missed": (EstimateMessage(9, 0.9, 5, X, spd(6), 1700000000.875, miss=True, miss_notes=(  # issue 36
        MissNote(7, "skipped", "await_meas", 120.5, 2, 340.0, 0.0), MissNote(9, "late_estimate", "await_meas", 3.25,
                                                                            1, 0.0, 41.5))), (5,)),
    "truth": (Truth(7, 0.7, X, 1700000000.5), ()),
    "start": (Start(1700000000.0, 0.1, 500, "lockstep", (0, 1, 2), 0.5, X), ()),
    "stop": (Stop(500), ()),
}
#: sha256 of what the wire functions of commit a8f3f0c (``core/transport/wire.py`` there) encoded for the same inputs
GOLDEN = {
    "prior": "dfcdbe29bc25a20c365c5980ffb52c432c1413058e65dce2b76dc606b72015e4",  # 834 bytes (exact_spd)
    "meas": "b1962a8911d99fbede1a77bb7893e145ee569119a8149a14dbbb2597c0103f70",  # 173 bytes
    "meas_none": "68997fc77b6f52a65cb9571bac785eab777299056c0e45e4c0ef63853a3021b2",  # 71 bytes
    "scan": "11003a510f30a0743fe7c1b0d5508fb868c00be6fd064fdf567f3e03c15fe82b",  # 193 bytes
    "scan_none": "94e9090939889b6949b1b0ec43aa911c098606e3a237437ba3307e7daae209fc",  # 68 bytes
    "relay": "a033f0381af0780170314b97e277f588ee2708ffadfcaa969b78e497c6709d89",  # 329 bytes
    "est": "f980490d873dd5aeca496ed03f007cde7a500fa5ae61eeabcab27065f886a6f9",  # 748 bytes
    "est_coasted": "ee7c98c3b690692cc0245184f3bd425df1513ea2598a538f114d91b3839c7935",  # 380 bytes
    "truth": "c3bf1cfb731ae1d0e43274813f6279b4549d03838fbf29e0f4d34d4fa37940c1",  # 123 bytes
    "start": "1d5ff2f61d940a19b597d22741e84e4099556c9b08db0724968657ccc4ddbac1",  # 196 bytes
    "stop": "7053fd8807696d627f918206712e9dc6b7d809ea52d6c90b230ce010461893f9",  # 43 bytes
}


def payload_of(name: str) -> bytes:
    msg = MESSAGES[name][0]
    return msg.encode_capped()[0] if isinstance(msg, Relay) else msg.encode()


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_every_class_encodes_the_bytes_of_wire_version_2(name):
    assert hashlib.sha256(payload_of(name)).hexdigest() == GOLDEN[name]


def test_an_estimate_is_the_map_the_schedule_sent_in_its_order():
    """The estimate's fields in the order encode_est wrote them (the schedule's keyword order, then the
    optional arrays): the map msgpack packs, by hand."""
    e = MESSAGES["est"][0]
    packed = wire.pack_array
    expected = {"v": 2, "kind": "est", "k": 7, "t": 0.7, "sender": 5, "x": packed(X), "P": wire.pack_symmetric(spd(6)),
                "t_meas_pub": 1700000000.5, "t_recv": 1700000000.625, "t_pub": 1700000000.875, "update_us": 41.5,
                "fused": 3, "coasted": False, "warm": True, "miss": False, "neighbours": [4, 6], "counters": COUNTERS,
                "round_ms": packed(np.array([1.5, 2.25])), "samples": packed(np.tile(X, (3, 1))),
                "beta": packed(np.array([0.25, 0.75]))}
    assert e.encode() == msgpack.packb(expected, use_bin_type=True)


def decoded(name: str):
    msg, args = MESSAGES[name]
    payload = payload_of(name)
    if isinstance(msg, (ForwardedScan, Relay)):
        return decode_scan_key(payload, *args)
    return type(msg).decode(payload, *args)


@pytest.mark.parametrize("name", sorted(MESSAGES))
def test_decoding_gives_back_the_message(name):
    """Decoded, every field is set (the decoders build instances without __init__) and equal to the sent one's
    (arrays bit for bit; a ``(m,)`` return comes back as ``(1, m)``, a pose without returns as None); encoded
    again, the same bytes."""
    sent, got = MESSAGES[name][0], decoded(name)
    assert type(got) is type(sent)
    assert set(vars(got)) == {f.name for f in dataclasses.fields(sent)}
    assert got.encode() == sent.encode()
    for f in dataclasses.fields(sent):
        a, b = getattr(sent, f.name), getattr(got, f.name)
        if name == "meas_none" and f.name == "pose":
            assert b is None
        elif isinstance(a, np.ndarray):
            assert b.dtype == np.float64 and b.flags.writeable and np.array_equal(np.atleast_2d(a) if f.name == "returns" else a, b)
        elif f.name == "blocks":
            assert all(np.array_equal(a[n][0], b[n][0]) and np.array_equal(a[n][1], b[n][1]) for n in a)
        elif f.name == "scans":
            assert [s.origin for s in a] == [s.origin for s in b]
            assert all(np.array_equal(np.atleast_2d(s.returns), r.returns) for s, r in zip(a, b))
        else:
            assert a == b, f.name
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.k = 3  # type: ignore[misc]


def test_a_relay_too_big_for_one_message_leaves_scans_out_and_encode_keeps_them_all():
    rng = np.random.default_rng(1)
    relay = Relay(0, 0.0, 1, tuple(RelayedScan(j, rng.normal(size=(wire.MAX_RETURNS, 3)), POSE, spd(3))
                                   for j in range(8)), 1.0)  # ~50 KB each
    payload, left_out = relay.encode_capped()
    assert len(payload) <= wire.MAX_MESSAGE_BYTES and 0 < left_out < 8
    assert len(Relay.decode(payload, 1, 3).scans) == 8 - left_out
    assert len(relay.encode()) > wire.MAX_MESSAGE_BYTES
    with pytest.raises(wire.WireError) as err:
        Relay.decode(relay.encode(), 1, 3)
    assert err.value.reason == "size"


def test_a_scan_key_carries_both_kinds_and_each_class_decodes_only_its_own():
    scan, relay = payload_of("scan"), payload_of("relay")
    assert isinstance(decode_scan_key(scan, 1, 2), ForwardedScan) and isinstance(decode_scan_key(relay, 1, 2), Relay)
    for cls, other in ((ForwardedScan, relay), (Relay, scan)):
        with pytest.raises(wire.WireError) as err:
            cls.decode(other, 1, 2)
        assert err.value.reason == "kind"
    with pytest.raises(wire.WireError) as err:
        decode_scan_key(payload_of("meas"), 1, 2)
    assert err.value.reason == "kind"
