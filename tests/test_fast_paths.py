"""The tracker's cheaper step gives what the general code gives.

- decoding: plain-loop and direct-LAPACK checks refuse exactly what the numpy versions they replaced refuse,
  with the same reason, and return the same bits otherwise (the numpy versions are kept here as the
  reference);
- the gate: one Cholesky factor gives the same estimate, and the same verdicts, as ``numpy.linalg``;
- CI for one receiver (:func:`ci_fuse_one`, :meth:`FusionRule.combine_one`) and the Joseph update for a batch
  of one equal the batched code bit for bit;
- estimates carry counters every ``COUNTERS_EVERY_STEPS`` steps, and the recorder and viewer read them so.
"""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion import linalg
from zentrack.fusion.covariance_intersection import ci_fuse, ci_fuse_one
from zentrack.fusion.gate import ci_gate_passes, information_mean_cov
from zentrack.fusion.linalg import GaussianState, InformationPair
from zentrack.fusion.rules import RULE_REGISTRY, make_rule
from zentrack.transport import wire
from zentrack.transport.codec import Message, WireError
from zentrack.transport.messages import EstimateMessage, RoundMessage

# ---------------------------------------------------------------- the numpy decoders that were replaced


def ref_unpack_array(obj, shape, name):
    if not isinstance(obj, dict) or not isinstance(obj.get("data"), bytes) or not isinstance(obj.get("shape"), list):
        raise WireError("schema", name)
    if tuple(obj["shape"]) != shape:
        raise WireError("shape", name)
    if len(obj["data"]) != 8 * int(np.prod(shape, dtype=int)):
        raise WireError("shape", name)
    a = np.frombuffer(obj["data"], dtype="<f8").reshape(shape).astype(float)
    if not np.all(np.isfinite(a)):
        raise WireError("nonfinite", name)
    return a


def ref_unpack_symmetric(obj, n, name):
    if isinstance(obj, dict) and "sym" in obj:
        if obj.get("sym") != n or not isinstance(obj.get("data"), bytes):
            raise WireError("shape", name)
        if len(obj["data"]) != 8 * n * (n + 1) // 2:
            raise WireError("shape", name)
        tri = np.frombuffer(obj["data"], dtype="<f8").astype(float)
        if not np.all(np.isfinite(tri)):
            raise WireError("nonfinite", name)
        m = np.zeros((n, n))
        iu = np.triu_indices(n)
        m[iu] = tri
        m[(iu[1], iu[0])] = tri
        return m
    m = ref_unpack_array(obj, (n, n), name)
    if not np.allclose(m, m.T, rtol=1e-12, atol=0.0):
        raise WireError("asymmetric", name)
    return 0.5 * (m + m.T)


def ref_check_pd(m, name):
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        raise WireError("not_pd", name) from None


def outcome(fn, *args):
    """The value a decoder returns, or the reason it refuses."""
    try:
        return fn(*args)
    except WireError as err:
        return err.reason


def same(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b) and a.flags.writeable


def corrupted(rng: np.random.Generator, values: np.ndarray) -> np.ndarray:
    """``values`` with, at random, a NaN, an infinity, huge finite values (which overflow a sum of squares)
    or nothing changed."""
    v = values.copy()
    kind = rng.integers(5)
    pos = rng.integers(v.size)
    if kind == 0:
        v.flat[pos] = np.nan
    elif kind == 1:
        v.flat[pos] = rng.choice([np.inf, -np.inf])
    elif kind == 2:
        v.flat[rng.integers(v.size, size=max(1, v.size // 3))] = rng.choice([1e200, -1e300, 1.7e308])
    return v


@pytest.mark.parametrize("count", [1, 2, 3, 12, 16, 17, 40, 78, 300])
def test_array_decoding_refuses_and_returns_what_the_numpy_decoder_did(count):
    rng = np.random.default_rng(count)
    for _ in range(200):
        shape = (count,) if rng.random() < 0.5 else (1, count)
        values = corrupted(rng, rng.standard_normal(count) * 10.0 ** rng.integers(-3, 6))
        obj = {"shape": list(shape), "data": values.astype("<f8").tobytes()}
        if rng.random() < 0.15:
            obj["data"] = obj["data"][: 8 * rng.integers(count)]  # truncated
        if rng.random() < 0.1:
            obj["shape"] = [count + 1]
        assert same(outcome(wire.unpack_array, obj, shape, "a"), outcome(ref_unpack_array, obj, shape, "a"))


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6, 12, 14])
def test_symmetric_decoding_and_the_pd_check_refuse_and_return_what_numpy_did(n):
    rng = np.random.default_rng(100 + n)
    iu = np.triu_indices(n)
    verdicts = set()
    for _ in range(200):
        a = rng.standard_normal((n, n))
        m = a @ a.T + rng.choice([1e-3, 1.0, -0.5 * n]) * np.eye(n)  # SPD, or indefinite
        obj = {"sym": n, "data": corrupted(rng, m[iu]).astype("<f8").tobytes()}
        if rng.random() < 0.1:
            obj["sym"] = n + 1
        new, ref = outcome(wire.unpack_symmetric, obj, n, "Y"), outcome(ref_unpack_symmetric, obj, n, "Y")
        assert same(new, ref)
        if not isinstance(new, str):
            pd = outcome(wire.check_pd, new, "Y")
            assert pd == outcome(ref_check_pd, ref, "Y")
            verdicts.add(pd)
        full = {"shape": [n, n], "data": (m + (rng.random() < 0.3) * 1e-6 * rng.standard_normal((n, n))).tobytes()}
        assert same(outcome(wire.unpack_symmetric, full, n, "P"), outcome(ref_unpack_symmetric, full, n, "P"))
    assert verdicts == {None, "not_pd"}  # both verdicts were exercised


def test_a_decoded_prior_is_what_the_reference_decoders_give():
    rng = np.random.default_rng(7)
    a = rng.standard_normal((12, 12))
    mat, vec = a @ a.T + np.eye(12), rng.standard_normal(12)
    msg = RoundMessage.decode(RoundMessage(4, 0.4, 2, 1, {"state": (mat, vec)}, 0.0).encode(), 2, 12)
    got_mat, got_vec = msg.blocks["state"]
    packed = wire.pack_blocks({"state": (mat, vec)})["state"]
    assert np.array_equal(got_mat, ref_unpack_symmetric(packed["Y"], 12, "Y"))
    assert np.array_equal(got_vec, ref_unpack_array(packed["y"], (12,), "y"))


# ---------------------------------------------------------------- the gate


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T + 0.1 * np.eye(n))


def test_the_gates_information_estimate_matches_numpy_and_refuses_what_is_not_positive_definite():
    rng = np.random.default_rng(11)
    for n in (1, 2, 6, 12):
        for _ in range(50):
            mat, vec = random_spd(rng, n, 10.0 ** rng.integers(-4, 4)), rng.standard_normal(n)
            mean, cov = information_mean_cov(mat, vec)
            ref_cov = np.linalg.inv(mat)
            assert np.allclose(cov, ref_cov, rtol=1e-8, atol=0) and np.allclose(mean, ref_cov @ vec, rtol=1e-7, atol=1e-12 * np.abs(ref_cov @ vec).max())
        assert information_mean_cov(-random_spd(rng, n), np.zeros(n)) is None


def ref_gate_half(x_a, cov_a, x_b, cov_b) -> float:
    """``q`` at omega = 1/2 with numpy: ``d^T (2 (P_a + P_b))^-1 d``."""
    d = x_a - x_b
    return float(d @ np.linalg.solve(2.0 * (cov_a + cov_b), d))


def test_the_gates_common_case_gives_numpys_verdicts():
    rng = np.random.default_rng(12)
    threshold = 21.0
    seen = set()
    for _ in range(400):
        n = int(rng.choice([2, 6, 12]))
        cov_a, cov_b = random_spd(rng, n), random_spd(rng, n)
        x_a = rng.standard_normal(n)
        x_b = x_a + rng.standard_normal(n) * rng.choice([0.5, 2.0, 6.0])
        q = ref_gate_half(x_a, cov_a, x_b, cov_b)
        if abs(q - threshold) < 1e-6 * threshold:
            continue
        passes = ci_gate_passes(x_a, cov_a, x_b, cov_b, threshold)
        if q <= threshold:
            assert passes  # the common case decides alone
        seen.add(q <= threshold)
    assert seen == {True, False}
    x, p = np.zeros(3), np.eye(3)
    assert not ci_gate_passes(x, p, x * np.nan, p, threshold)
    assert not ci_gate_passes(x, p, x, np.full((3, 3), np.inf), threshold)


# ---------------------------------------------------------------- CI for one receiver, Joseph for a batch of one


def pairs(rng: np.random.Generator, senders: int, n: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    mats = [np.linalg.inv(random_spd(rng, n, 10.0 ** rng.integers(-2, 3))) for _ in range(senders)]
    return mats, [rng.standard_normal(n) for _ in range(senders)]


@pytest.mark.parametrize("n", [2, 6, 12])
def test_ci_for_one_receiver_is_bit_for_bit_the_batched_ci(n):
    rng = np.random.default_rng(n)
    for senders in range(1, 7):
        mats, vecs = pairs(rng, senders, n)
        w = rng.random(senders) + 0.01
        one = ci_fuse_one(w, mats, vecs)
        batched = ci_fuse(w[None, :], InformationPair(np.stack(mats)[None], np.stack(vecs)[None]),
                          np.ones((1, senders), dtype=bool))
        assert one.mean.shape == (1, n) and one.cov.shape == (1, n, n)
        assert np.array_equal(one.mean, batched.mean[0]) and np.array_equal(one.cov, batched.cov[0])
    with pytest.raises(ValueError, match="no positive-weight"):
        ci_fuse_one(np.zeros(2), *pairs(rng, 2, n))


@pytest.mark.parametrize("name", RULE_REGISTRY.names())
def test_every_rules_single_receiver_combine_equals_its_batched_combine(name):
    rule = make_rule(name, {})
    rng = np.random.default_rng(len(name))
    dims = rule.message_dims({"state": 6})
    senders = 3
    messages = []
    for _ in range(senders):
        blocks = {}
        for block, n in dims.items():
            mats, vecs = pairs(rng, 1, n)
            blocks[block] = (mats[0], vecs[0])
        messages.append(blocks)
    # receiver 0 of a 3-node complete graph, with the weight row the rule makes of it (as a tracker does)
    diffusion = np.array([[0.5, 0.3, 0.2], [0.3, 0.4, 0.3], [0.2, 0.3, 0.5]])
    w = np.asarray(rule.network_weights(diffusion, np.ones((3, 3)) - np.eye(3)))[0]
    batched = rule.combine(1, w[None, :], {b: InformationPair(np.stack([m[b][0] for m in messages])[None],
                                                              np.stack([m[b][1] for m in messages])[None])
                                           for b in dims}, np.ones((1, senders), dtype=bool))
    one = rule.combine_one(1, w, messages)
    assert set(one) == set(batched)
    for block in one:
        assert np.array_equal(one[block].mean.reshape(-1), batched[block].mean.reshape(-1))
        assert np.array_equal(one[block].cov.reshape(-1), batched[block].cov.reshape(-1))


def test_a_joseph_update_of_a_batch_of_one_is_bit_for_bit_its_row_in_a_batch():
    rng = np.random.default_rng(5)
    for _ in range(200):
        n, m, b = int(rng.integers(2, 13)), int(rng.integers(1, 4)), 3
        state = GaussianState(rng.standard_normal((b, n)), np.stack([random_spd(rng, n) for _ in range(b)]))
        jac, innovation = rng.standard_normal((b, m, n)), rng.standard_normal((b, m))
        noise = random_spd(rng, m)
        for noise_cov in (noise, np.stack([noise] * b)):
            full = linalg.joseph_update(state, jac, innovation, noise_cov)
            row = linalg.joseph_update(GaussianState(state.mean[1:2], state.cov[1:2]), jac[1:2], innovation[1:2],
                                       noise_cov if noise_cov.ndim == 2 else noise_cov[1:2])
            assert np.array_equal(row.mean, full.mean[1:2]) and np.array_equal(row.cov, full.cov[1:2])


# ---------------------------------------------------------------- counters every k steps


class _FakeSession:
    """What the recorder declares on a Zenoh session, without Zenoh."""

    def declare_subscriber(self, key, handler):
        return self

    def liveliness(self):
        return self

    def declare_token(self, key):
        return self

    def undeclare(self):
        pass


def test_estimates_carry_counters_every_k_steps_and_the_recorder_counts_restarts_once():
    from test_node_schedule import T0, Net, run_steps

    from zentrack.cluster.recording.core import Recorder
    from zentrack.cluster.recording.estimates import Estimates
    from zentrack.node.counters import COUNTERS_EVERY_STEPS

    net = Net(nodes=3, steps=40)
    net.start()
    log = run_steps(net, 0, 34)
    est = [(i, m) for i, ch, m in log if ch == "est"]
    carried = sorted({m["k"] for i, m in est if i == 0 and "counters" in m})
    assert carried == [0, 10, 20, 30] and COUNTERS_EVERY_STEPS == 10
    def estimate(k: int, x: np.ndarray, counters: dict | None = None, i: int = 0) -> Message:
        payload = EstimateMessage(k, 0.1 * k, i, x, np.eye(6), T0 + 0.1 * k, counters=counters).encode()
        return Message("est", net.keys.est(i), payload, T0)

    rec = Recorder(_FakeSession(), net.keys, Estimates(net.scn))
    for i, m in est:
        rec._record(estimate(m["k"], wire.unpack_array(m["x"], (6,), "x"), m.get("counters"), i))
    assert not rec.counters.restarts.any()  # estimates without counters are not a restart
    assert rec.counters.last[0]["steps"] == 31  # the counters of step 30
    # a restarted node: its first estimate carries its new incarnation's counters at once
    fresh = {"steps": 1, "misses": 0, "incarnation": 999}
    rec._record(estimate(35, np.zeros(6), fresh))
    rec._record(estimate(36, np.zeros(6)))
    # the killed incarnation published steps 0..34; its last counters (step 30) said 31: the four received
    # since were published too, so the bank holds 35 and none of them counts as lost
    assert rec.counters.restarts[0] == 1 and rec.counters.total[0]["steps"] == 35 and rec.counters.last[0] == fresh
    node0 = rec.summary()["nodes"][0]
    assert node0["estimates_published"] == 37 and node0["steps_estimated"] == 37 and node0["estimates_lost"] == 0
    # an estimate the transport lost after the restart: published by the node's count, never received
    rec._record(estimate(39, np.zeros(6), {**fresh, "steps": 5}))
    node0 = rec.summary()["nodes"][0]
    assert node0["estimates_published"] == 35 + 5 and node0["steps_estimated"] == 38 and node0["estimates_lost"] == 2
