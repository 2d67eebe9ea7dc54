"""Wire codec: round trips and one typed rejection reason for every kind of bad message."""
from __future__ import annotations

import msgpack
import numpy as np
import pytest

from zentrack.transport import wire
from zentrack.transport.keys import Keys, check_run_name


def spd(n, seed=0):
    a = np.random.default_rng(seed).normal(size=(n, n))
    return a @ a.T + np.eye(n)


def test_prior_round_trip_is_exact():
    y_mat, y_vec = spd(12), np.arange(12.0)
    msg = wire.encode_prior(5, 0.5, 3, y_mat, y_vec, 123.0)
    out = wire.decode_prior(msg, 3, 12, 5, 6)
    np.testing.assert_array_equal(out["Y"], y_mat)
    np.testing.assert_array_equal(out["y"], y_vec)
    assert (out["k"], out["sender"], out["t_pub"]) == (5, 3, 123.0)
    assert len(msg) < 1000  # 78 + 12 doubles plus framing: ~ the 90 scalars of seed 000 Table 1


def test_meas_est_truth_start_round_trip():
    m = wire.decode_meas(wire.encode_meas(7, 0.7, 2, np.array([0.1, -0.2]), 9.0), 2, 2, 0, 10)
    np.testing.assert_array_equal(m["z"], [0.1, -0.2])
    assert wire.decode_meas(wire.encode_meas(7, 0.7, 2, None, 9.0), 2, 2)["z"] is None
    e = wire.decode_est(wire.encode_est(4, 0.4, 1, np.ones(6), spd(6), fused=3, counters={"late": 2}), 1)
    np.testing.assert_array_equal(e["P"], spd(6))
    assert e["fused"] == 3 and e["counters"] == {"late": 2}
    t = wire.decode_truth(wire.encode_truth(3, 0.3, np.arange(6.0), 1.0))
    np.testing.assert_array_equal(t["x"], np.arange(6.0))
    s = wire.decode_start(wire.encode_start(100.0, 0.1, 50, "lockstep", [0, 1, 2], 0.5))
    assert s["participants"] == [0, 1, 2] and s["mode"] == "lockstep"


def good_prior(**overrides):
    msg = {"v": 1, "kind": "prior", "k": 5, "t": 0.5, "sender": 3, "t_pub": 1.0,
           "Y": wire.pack_symmetric(spd(12)), "y": wire.pack_array(np.zeros(12))}
    msg.update(overrides)
    return msgpack.packb({k: v for k, v in msg.items() if v is not None}, use_bin_type=True)


def nan_sym():
    m = spd(12)
    m[0, 0] = np.nan
    return wire.pack_symmetric(m)


BAD_PRIORS = [
    (b"\xc1\xff garbage", "undecodable"),
    (good_prior()[:-7], "undecodable"),
    (msgpack.packb([1, 2, 3]), "undecodable"),
    (b"x" * (wire.MAX_MESSAGE_BYTES + 1), "size"),
    (good_prior(v=2), "version"),
    (good_prior(kind="est"), "kind"),
    (good_prior(kind="bogus"), "kind"),
    (good_prior(k="5"), "schema"),
    (good_prior(t=float("nan")), "nonfinite"),
    (good_prior(sender=4), "sender_mismatch"),
    (good_prior(k=1), "stale"),
    (good_prior(k=10**9), "future"),
    (good_prior(Y=wire.pack_symmetric(spd(6))), "shape"),
    (good_prior(y=wire.pack_array(np.zeros(11))), "shape"),
    (good_prior(y={"shape": [12], "data": b"\x00" * 95}), "shape"),
    (good_prior(Y=nan_sym()), "nonfinite"),
    (good_prior(y=wire.pack_array(np.full(12, np.inf))), "nonfinite"),
    (good_prior(Y=wire.pack_symmetric(-spd(12))), "not_pd"),
    (good_prior(Y=wire.pack_array(spd(12) + np.triu(np.ones((12, 12)), 1))), "asymmetric"),
    (good_prior(Y=None), "schema"),
    (good_prior(t_pub=None), "schema"),
]


@pytest.mark.parametrize("payload, reason", BAD_PRIORS)
def test_bad_priors_are_rejected_with_their_reason(payload, reason):
    with pytest.raises(wire.WireError) as err:
        wire.decode_prior(payload, 3, 12, 4, 6)
    assert err.value.reason == reason
    assert reason in wire.REASONS


def test_full_symmetric_matrix_is_accepted():
    out = wire.decode_prior(good_prior(Y=wire.pack_array(spd(12))), 3, 12)
    np.testing.assert_allclose(out["Y"], spd(12))


@pytest.mark.parametrize(
    "fields, reason",
    [
        ({"sender": "node"}, "sender_mismatch"),
        ({"node": 5}, "sender_mismatch"),
        ({"present": "yes"}, "schema"),
        ({"z": wire.pack_array(np.zeros(3))}, "shape"),
        ({"z": wire.pack_array(np.array([np.nan, 0.0]))}, "nonfinite"),
        ({"k": -1}, "stale"),
    ],
)
def test_bad_measurements(fields, reason):
    msg = {"v": 1, "kind": "meas", "k": 3, "t": 0.3, "sender": "truth", "node": 2, "present": True,
           "t_pub": 1.0, "z": wire.pack_array(np.zeros(2))}
    msg.update(fields)
    with pytest.raises(wire.WireError) as err:
        wire.decode_meas(msgpack.packb(msg, use_bin_type=True), 2, 2, 0, 10)
    assert err.value.reason == reason


def test_no_pickle_or_extension_types():
    payload = msgpack.packb({"v": 1, "kind": "prior", "k": 1, "t": 0.0, "sender": 3,
                             "x": msgpack.ExtType(42, b"boom")}, use_bin_type=True)
    with pytest.raises(wire.WireError) as err:
        wire.decode_prior(payload, 3, 12)
    assert err.value.reason == "undecodable"


def test_keys_scheme():
    keys = Keys("exp-1")
    assert keys.prior(3) == "zentrack/exp-1/prior/3"
    assert keys.meas(0) == "zentrack/exp-1/meas/0"
    assert keys.alive("truth") == "zentrack/exp-1/alive/truth"
    assert keys.kind_of("zentrack/exp-1/est/4") == "est" and keys.last_segment(keys.est(4)) == "4"
    for bad in ("", "a/b", "x*", "a" * 65):
        with pytest.raises(ValueError):
            check_run_name(bad)
