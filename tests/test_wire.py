"""Wire messages: round trips and one typed rejection reason for every kind of bad message."""
from __future__ import annotations

import msgpack
import numpy as np
import pytest

from zentrack.transport import wire
from zentrack.transport.keys import Keys, check_run_name
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Start, Truth
from zentrack.transport.scan_messages import ForwardedScan, decode_scan_key


def spd(n, seed=0):
    a = np.random.default_rng(seed).normal(size=(n, n))
    return a @ a.T + np.eye(n)


def est(k=3, t=0.3, sender=2, x=None, cov=None, **fields):
    """An estimate message's bytes (x ones(6), P spd(6) unless given)."""
    return EstimateMessage(k, t, sender, np.ones(6) if x is None else x, spd(6) if cov is None else cov,
                           fields.pop("t_pub", 1.0), **fields).encode()


def test_prior_round_trip_is_exact():
    y_mat, y_vec = spd(12), np.arange(12.0)
    msg = RoundMessage(5, 0.5, 3, 2, {"state": (y_mat, y_vec)}, 123.0).encode()
    out = RoundMessage.decode(msg, 3, 12, 5, 6, max_round=3)
    np.testing.assert_array_equal(out.blocks["state"][0], y_mat)
    np.testing.assert_array_equal(out.blocks["state"][1], y_vec)
    assert (out.k, out.sender, out.t_pub, out.round, out.warm) == (5, 3, 123.0, 2, False)
    assert len(msg) < 1000  # 78 + 12 doubles plus framing: ~ the 90 scalars of paper 0 Table 1


def test_multi_block_prior_round_trip():
    blocks = {"kinematic": (spd(4), np.ones(4)), "extent": (spd(3, 1), np.arange(3.0))}
    out = RoundMessage.decode(RoundMessage(5, 0.5, 3, 1, blocks, 1.0).encode(), 3, {"kinematic": 4, "extent": 3})
    for name, (mat, vec) in blocks.items():
        np.testing.assert_array_equal(out.blocks[name][0], mat)
        np.testing.assert_array_equal(out.blocks[name][1], vec)


def test_meas_est_truth_start_round_trip():
    m = Measurement.decode(Measurement(7, 0.7, 2, np.array([0.1, -0.2]), np.ones(3), 9.0).encode(), 2, 2, 0, 10)
    np.testing.assert_array_equal(m.returns, [[0.1, -0.2]])
    np.testing.assert_array_equal(m.pose, np.ones(3))
    assert Measurement.decode(Measurement(7, 0.7, 2, None, None, 9.0).encode(), 2, 2).returns is None
    empty = Measurement.decode(Measurement(7, 0.7, 2, np.zeros((0, 2)), None, 9.0).encode(), 2, 2)  # looked, saw nothing
    assert empty.returns.shape == (0, 2) and empty.pose is None
    many = np.arange(10.0).reshape(5, 2)
    np.testing.assert_array_equal(Measurement.decode(Measurement(7, 0.7, 2, many, None, 9.0).encode(), 2, 2).returns, many)
    sc = decode_scan_key(ForwardedScan(7, 0.7, 1, 4, many, np.arange(3.0), spd(2), 2.0).encode(), 1, 2, 0, 10)
    assert isinstance(sc, ForwardedScan) and sc.origin == 4 and sc.returns is not None and sc.returns.shape == (5, 2)
    none = ForwardedScan.decode(ForwardedScan(7, 0.7, 1, 1, None, None, None, 2.0).encode(), 1, 2)
    assert none.returns is None and none.origin == 1
    np.testing.assert_array_equal(sc.noise_cov, spd(2))
    e = EstimateMessage.decode(est(4, 0.4, 1, fused=3, counters={"late": 2}), 1)
    np.testing.assert_array_equal(e.P, spd(6))
    assert e.fused == 3 and e.counters == {"late": 2}
    t = Truth.decode(Truth(3, 0.3, np.arange(6.0), 1.0).encode())
    np.testing.assert_array_equal(t.x, np.arange(6.0))
    s = Start.decode(Start(100.0, 0.1, 50, "lockstep", (0, 1, 2), 0.5, np.arange(6.0)).encode())
    assert s.participants == (0, 1, 2) and s.mode == "lockstep"
    np.testing.assert_array_equal(s.x0, np.arange(6.0))


def state_block(mat=None, vec=None, **over):
    out = {"Y": wire.pack_symmetric(spd(12)) if mat is None else mat,
           "y": wire.pack_array(np.zeros(12)) if vec is None else vec}
    out.update(over)
    return {"state": {k: v for k, v in out.items() if v is not None}}


def good_prior(**overrides):
    msg = {"v": 2, "kind": "prior", "k": 5, "t": 0.5, "sender": 3, "t_pub": 1.0, "round": 1, "warm": False,
           "blocks": state_block()}
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
    (good_prior(v=1), "version"),  # a version 1 message (one pair, no rounds) is refused
    (good_prior(v=3), "version"),
    (good_prior(kind="est"), "kind"),
    (good_prior(kind="bogus"), "kind"),
    (good_prior(k="5"), "schema"),
    (good_prior(t=float("nan")), "nonfinite"),
    (good_prior(sender=4), "sender_mismatch"),
    (good_prior(k=1), "stale"),
    (good_prior(k=10**9), "future"),
    (good_prior(round=0), "schema"),
    (good_prior(round=4), "schema"),
    (good_prior(round="1"), "schema"),
    (good_prior(blocks=None), "schema"),
    (good_prior(blocks=[1, 2]), "schema"),
    (good_prior(blocks={}), "shape"),
    (good_prior(blocks={**state_block(), "extent": state_block()["state"]}), "shape"),
    (good_prior(blocks={"x" * 40: state_block()["state"]}), "schema"),
    (good_prior(blocks={f"b{i}": state_block()["state"] for i in range(9)}), "schema"),
    (good_prior(blocks={"state": 7}), "schema"),
    (good_prior(blocks=state_block(mat=wire.pack_symmetric(spd(6)))), "shape"),
    (good_prior(blocks=state_block(vec=wire.pack_array(np.zeros(11)))), "shape"),
    (good_prior(blocks=state_block(vec={"shape": [12], "data": b"\x00" * 95})), "shape"),
    (good_prior(blocks=state_block(mat=nan_sym())), "nonfinite"),
    (good_prior(blocks=state_block(vec=wire.pack_array(np.full(12, np.inf)))), "nonfinite"),
    (good_prior(blocks=state_block(mat=wire.pack_symmetric(-spd(12)))), "not_pd"),
    (good_prior(blocks=state_block(mat=wire.pack_array(spd(12) + np.triu(np.ones((12, 12)), 1)))), "asymmetric"),
    (good_prior(blocks={"state": {"y": wire.pack_array(np.zeros(12))}}), "schema"),
    (good_prior(t_pub=None), "schema"),
    (good_prior(warm=1), "schema"),
]


@pytest.mark.parametrize("payload, reason", BAD_PRIORS)
def test_bad_priors_are_rejected_with_their_reason(payload, reason):
    with pytest.raises(wire.WireError) as err:
        RoundMessage.decode(payload, 3, 12, 4, 6, max_round=3)
    assert err.value.reason == reason
    assert reason in wire.REASONS


def test_full_symmetric_matrix_is_accepted():
    out = RoundMessage.decode(good_prior(blocks=state_block(mat=wire.pack_array(spd(12)))), 3, 12)
    np.testing.assert_allclose(out.blocks["state"][0], spd(12))


def returns(a):
    return wire.pack_array(np.asarray(a, dtype=float))


@pytest.mark.parametrize(
    "fields, reason",
    [
        ({"v": 1}, "version"),
        ({"sender": "node"}, "sender_mismatch"),
        ({"node": 5}, "sender_mismatch"),
        ({"present": "yes"}, "schema"),
        ({"returns": returns(np.zeros(2))}, "schema"),  # a vector, not a (J, m) scan
        ({"returns": returns(np.zeros((1, 3)))}, "shape"),
        ({"returns": {"shape": [wire.MAX_RETURNS + 1, 2], "data": b""}}, "shape"),
        ({"returns": {"shape": [-1, 2], "data": b""}}, "shape"),
        ({"returns": {"shape": [2, 2], "data": b"\x00" * 24}}, "shape"),
        ({"returns": returns([[np.nan, 0.0]])}, "nonfinite"),
        ({"returns": None}, "schema"),
        ({"pose": returns([0.0, 1.0])}, "shape"),
        ({"pose": returns([0.0, np.inf, 1.0])}, "nonfinite"),
        ({"k": -1}, "stale"),
    ],
)
def test_bad_measurements(fields, reason):
    msg = {"v": 2, "kind": "meas", "k": 3, "t": 0.3, "sender": "truth", "node": 2, "present": True,
           "t_pub": 1.0, "returns": returns(np.zeros((1, 2))), "pose": returns(np.zeros(3))}
    msg.update(fields)
    msg = {k: v for k, v in msg.items() if v is not None}
    with pytest.raises(wire.WireError) as err:
        Measurement.decode(msgpack.packb(msg, use_bin_type=True), 2, 2, 0, 10)
    assert err.value.reason == reason


@pytest.mark.parametrize(
    "fields, reason",
    [
        ({"sender": 2}, "sender_mismatch"),
        ({"kind": "meas"}, "kind"),
        ({"origin": -3}, "schema"),
        ({"origin": "x"}, "schema"),
        ({"R": wire.pack_symmetric(-spd(2))}, "not_pd"),
        ({"R": wire.pack_symmetric(spd(3))}, "shape"),
        ({"returns": returns(np.zeros((2, 3)))}, "shape"),
        ({"pose": returns([1.0, 2.0])}, "shape"),
        ({"k": 99}, "future"),
        ({"present": 1}, "schema"),
    ],
)
def test_bad_forwarded_scans(fields, reason):
    msg = {"v": 2, "kind": "scan", "k": 3, "t": 0.3, "sender": 1, "origin": 4, "t_pub": 1.0, "present": True,
           "returns": returns(np.zeros((2, 2))), "pose": returns(np.zeros(3)), "R": wire.pack_symmetric(spd(2))}
    msg.update(fields)
    with pytest.raises(wire.WireError) as err:
        decode_scan_key(msgpack.packb(msg, use_bin_type=True), 1, 2, 0, 10)
    assert err.value.reason == reason


@pytest.mark.parametrize("x0", [None, wire.pack_array(np.zeros((2, 3))), {"shape": [0], "data": b""},
                                wire.pack_array(np.array([np.nan, 1.0]))])
def test_start_needs_a_finite_initial_estimate(x0):
    msg = msgpack.unpackb(Start(100.0, 0.1, 50, "lockstep", (0,), 0.5, np.zeros(6)).encode())
    if x0 is None:
        del msg["x0"]
    else:
        msg["x0"] = x0
    with pytest.raises(wire.WireError):
        Start.decode(msgpack.packb(msg, use_bin_type=True))


def test_no_pickle_or_extension_types():
    payload = msgpack.packb({"v": 2, "kind": "prior", "k": 1, "t": 0.0, "sender": 3,
                             "x": msgpack.ExtType(42, b"boom")}, use_bin_type=True)
    with pytest.raises(wire.WireError) as err:
        RoundMessage.decode(payload, 3, 12)
    assert err.value.reason == "undecodable"


def test_keys_scheme():
    keys = Keys("exp-1")
    assert keys.prior(3) == "zentrack/exp-1/prior/3"
    assert keys.meas(0) == "zentrack/exp-1/meas/0" and keys.scan(2) == "zentrack/exp-1/scan/2"
    assert keys.alive("truth") == "zentrack/exp-1/alive/truth"
    assert keys.kind_of("zentrack/exp-1/est/4") == "est" and keys.last_segment(keys.est(4)) == "4"
    for bad in ("", "a/b", "x*", "a" * 65):
        with pytest.raises(ValueError):
            check_run_name(bad)


def test_an_estimate_carries_a_particle_subsample_and_association_probabilities():
    samples, beta = np.arange(60.0).reshape(10, 6), np.array([0.1, 0.7, 0.0, 0.2])
    e = EstimateMessage.decode(est(samples=samples, beta=beta), 2)
    np.testing.assert_array_equal(e.samples, samples)
    np.testing.assert_array_equal(e.beta, beta)
    plain = EstimateMessage.decode(est(), 2)
    assert plain.samples is None and plain.beta is None


@pytest.mark.parametrize("extra, reason", [
    ({"samples": np.ones((4, 3))}, "shape"),  # not the estimate's dimension
    ({"samples": np.ones((wire.MAX_SAMPLES + 1, 6))}, "shape"),
    ({"samples": np.full((2, 6), np.nan)}, "nonfinite"),
    ({"beta": np.array([0.5, 1.5])}, "schema"),
    ({"beta": np.array([-0.1])}, "schema"),
    ({"beta": np.ones((2, 2))}, "schema"),
    ({"beta": np.full(wire.MAX_RETURNS + 1, 0.1)}, "shape"),
    ({"round_ms": np.array([1.0, -1.0])}, "schema"),
    ({"round_ms": np.ones(wire.MAX_ROUNDS + 1)}, "shape"),
    ({"cov": -spd(6)}, "not_pd"),
    ({"cov": np.zeros((6, 6))}, "not_pd"),  # a recorder solves with it: a singular covariance is refused
    ({"x": np.ones(wire.MAX_DIM + 1), "cov": np.eye(wire.MAX_DIM + 1)}, "shape"),
    ({"t_pub": float("nan")}, "nonfinite"),
    ({"t_meas_pub": float("inf")}, "nonfinite"),
    ({"update_us": "fast"}, "schema"),
    ({"fused": -1}, "schema"),
    ({"fused": wire.MAX_NODES + 1}, "schema"),
    ({"neighbours": (0, 1000)}, "schema"),
    ({"counters": {"steps": -1}}, "schema"),
    ({"counters": {"steps": 1.5}}, "schema"),
    ({"counters": {"rejected": 3}}, "schema"),  # a map of reasons
    ({"counters": {"rejected": {"stale": True}}}, "schema"),
    ({"counters": {"x" * (wire.MAX_COUNTER_NAME + 1): 1}}, "schema"),
    ({"counters": {f"c{i}": 1 for i in range(wire.MAX_COUNTERS + 1)}}, "schema"),
    ({"k": -1}, "stale"),
])
def test_bad_estimates_are_rejected_with_a_reason(extra, reason):
    with pytest.raises(wire.WireError) as err:
        EstimateMessage.decode(est(**extra), 2)
    assert err.value.reason == reason


@pytest.mark.parametrize("field, value", [
    ("fused", "3"), ("fused", 2.0), ("fused", True), ("coasted", 1), ("warm", "yes"), ("miss", None),
    ("counters", [1, 2]), ("counters", {"steps": "3"}), ("counters", {"dropped": [1]}), ("neighbours", [1, 2.0]),
    ("neighbours", [True]), ("neighbours", 3), ("t_recv", "now"), ("t_pub", None), ("round_ms", [1.0]),
    ("samples", 7), ("x", {"shape": ["6"], "data": b""}), ("x", {"shape": [6.0], "data": b"\0" * 48}),
])
def test_an_estimate_field_of_the_wrong_type_is_refused(field, value):
    """Ill-typed fields never reach the recorder or the viewer (they did when decode returned the map)."""
    msg = msgpack.unpackb(est(counters={"steps": 1}, round_ms=np.array([1.0])))
    msg[field] = value
    with pytest.raises(wire.WireError) as err:
        EstimateMessage.decode(msgpack.packb(msg, use_bin_type=True), 2)
    assert err.value.reason in ("schema", "shape")


def test_an_estimate_without_its_optional_fields_takes_their_defaults():
    bare = {"v": 2, "kind": "est", "k": 3, "t": 0.3, "sender": 2, "x": wire.pack_array(np.ones(6)),
            "P": wire.pack_symmetric(spd(6)), "t_pub": 1.0, "t_meas_pub": None}
    e = EstimateMessage.decode(msgpack.packb(bare, use_bin_type=True), 2)
    assert (e.t_meas_pub, e.t_recv, e.update_us, e.fused, e.coasted, e.warm, e.miss, e.neighbours) == \
        (None, None, None, 0, False, False, False, ())
    assert e.round_ms is None and e.samples is None and e.beta is None and e.counters is None
    del bare["t_pub"]
    with pytest.raises(wire.WireError) as err:  # every estimate says when it was published
        EstimateMessage.decode(msgpack.packb(bare, use_bin_type=True), 2)
    assert err.value.reason == "schema"


def test_a_scan_at_the_cap_round_trips_and_one_more_return_is_refused():
    full = np.random.default_rng(1).uniform(-3, 3, (wire.MAX_RETURNS, 2))
    back = Measurement.decode(Measurement(5, 0.5, 0, full, None, 1.0).encode(), 0, 2)
    np.testing.assert_array_equal(back.returns, full)
    with pytest.raises(wire.WireError) as err:
        Measurement.decode(Measurement(5, 0.5, 0, np.zeros((wire.MAX_RETURNS + 1, 2)), None, 1.0).encode(), 0, 2)
    assert err.value.reason == "shape"
