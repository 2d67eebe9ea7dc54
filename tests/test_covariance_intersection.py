"""Fusion rules: CI consistency under unknown correlation (property test), renormalisation, naive fusion."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zentrack.fusion.covariance_intersection import ci_fuse, independent_fuse, mix_information, renormalise_rows
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information


def random_joint(rng, count, dim, correlation):
    """A random joint error covariance of ``count`` estimates (correlated through a shared component)."""
    shared = rng.normal(size=(dim, dim))
    blocks = []
    for _ in range(count):
        own = rng.normal(size=(dim, dim))
        blocks.append(np.sqrt(correlation) * shared + np.sqrt(1 - correlation) * own)
    g = np.vstack(blocks)  # (count*dim, dim): e_j = G_j u + independent part below
    joint = g @ g.T + np.kron(np.eye(count), 0.05 * np.eye(dim))
    return joint


def fused_error_cov(weights, bounds, joint):
    """True covariance of the CI-fused error P sum_j w_j P_j^-1 e_j for the joint error covariance."""
    infos = [np.linalg.inv(b) for b in bounds]
    p = np.linalg.inv(sum(w * y for w, y in zip(weights, infos)))
    gains = np.hstack([p @ (w * y) for w, y in zip(weights, infos)])
    return p, gains @ joint @ gains.T


@settings(max_examples=150, deadline=None)
@given(
    st.integers(2, 4), st.integers(1, 4), st.floats(0.0, 0.99), st.integers(0, 10_000),
    st.lists(st.floats(0.05, 1.0), min_size=4, max_size=4),
)
def test_ci_bounds_the_true_error_covariance(count, dim, correlation, seed, raw_w):
    """Paper 0 Lemma 1 / Theorem 3: for any correlation and convex weights, P_CI >= E[e e^T]."""
    rng = np.random.default_rng(seed)
    joint = random_joint(rng, count, dim, correlation)
    bounds = [joint[j * dim:(j + 1) * dim, j * dim:(j + 1) * dim] for j in range(count)]
    # inflate each bound by a random PSD amount: the inputs only need to be consistent, not tight
    bounds = [b + 0.1 * np.diag(rng.uniform(0, 1, dim)) for b in bounds]
    w = np.array(raw_w[:count]) / sum(raw_w[:count])
    p_true, c_true = fused_error_cov(w, bounds, joint)
    pair = to_information(GaussianState(np.zeros((count, dim)), np.array(bounds)))
    fused = ci_fuse(w[None, :], InformationPair(pair.matrix[None], pair.vector[None]))
    np.testing.assert_allclose(fused.cov[0, 0], p_true, rtol=1e-9, atol=1e-12)
    gap = np.linalg.eigvalsh(fused.cov[0, 0] - c_true).min()
    assert gap >= -1e-9 * np.abs(c_true).max()


def test_naive_fusion_is_optimistic_under_correlation():
    """Fully correlated copies: the information sum halves the covariance although the error is the same."""
    p = np.diag([2.0, 3.0])
    pair = to_information(GaussianState(np.zeros((2, 2)), np.stack([p, p])))
    pair = InformationPair(pair.matrix[None], pair.vector[None])
    naive = independent_fuse(np.array([[0, 1], [1, 0]]), pair)
    np.testing.assert_allclose(naive.cov[0, 0], p / 2)  # true error covariance is p: optimistic
    ci = ci_fuse(np.array([[0.5, 0.5], [0.5, 0.5]]), pair)
    np.testing.assert_allclose(ci.cov[0, 0], p)  # CI keeps the honest bound


def test_naive_fusion_is_the_information_sum_for_independent_estimates(rng):
    covs = np.stack([np.diag(rng.uniform(1, 3, 3)) for _ in range(3)])
    means = rng.normal(size=(3, 3))
    pair = to_information(GaussianState(means, covs))
    fused = independent_fuse(np.ones((3, 3)) - np.eye(3), InformationPair(pair.matrix[None], pair.vector[None]))
    info = sum(np.linalg.inv(c) for c in covs)
    np.testing.assert_allclose(fused.cov[0, 1], np.linalg.inv(info))
    np.testing.assert_allclose(fused.mean[0, 1], np.linalg.solve(info, sum(np.linalg.solve(c, m) for c, m in zip(covs, means))))


def test_renormalise_rows_over_present_pairs():
    w = np.array([[0.5, 0.25, 0.25], [0.25, 0.5, 0.25], [0.25, 0.25, 0.5]])
    present = np.array([[1, 0, 1], [1, 1, 1], [0, 0, 1]], dtype=bool)
    out = renormalise_rows(w, present)
    np.testing.assert_allclose(out.sum(axis=1), 1.0)
    np.testing.assert_allclose(out[0], [2 / 3, 0, 1 / 3])
    np.testing.assert_allclose(out[2], [0, 0, 1])
    with pytest.raises(ValueError, match="no positive-weight pair"):
        renormalise_rows(w, np.zeros((3, 3), dtype=bool))


def test_ci_with_missing_neighbour_stays_consistent(rng):
    """Dropping a sender and renormalising the row is CI with fewer terms: still bounds the true error."""
    dim, count = 3, 3
    joint = random_joint(rng, count, dim, 0.7)
    bounds = np.stack([joint[j * dim:(j + 1) * dim, j * dim:(j + 1) * dim] for j in range(count)])
    w = np.array([[0.5, 0.25, 0.25]])
    present = np.array([[True, False, True]])
    pair = to_information(GaussianState(np.zeros((count, dim)), bounds))
    fused = ci_fuse(w, InformationPair(pair.matrix[None], pair.vector[None]), present)
    idx = [0, 2]
    sub = joint[np.ix_(np.r_[0:3, 6:9], np.r_[0:3, 6:9])]
    p_true, c_true = fused_error_cov(np.array([2 / 3, 1 / 3]), [bounds[i] for i in idx], sub)
    np.testing.assert_allclose(fused.cov[0, 0], p_true)
    assert np.linalg.eigvalsh(fused.cov[0, 0] - c_true).min() >= -1e-10


def test_ci_of_identical_estimates_returns_them(rng):
    a = rng.normal(size=(3, 3))
    p = a @ a.T + np.eye(3)
    x = rng.normal(size=3)
    pair = to_information(GaussianState(np.stack([x, x]), np.stack([p, p])))
    fused = ci_fuse(np.array([[0.3, 0.7]]), InformationPair(pair.matrix[None], pair.vector[None]))
    np.testing.assert_allclose(fused.mean[0, 0], x)
    np.testing.assert_allclose(fused.cov[0, 0], p)


def test_mix_information_with_per_run_weights(rng):
    y = rng.normal(size=(2, 3, 2, 2))
    v = rng.normal(size=(2, 3, 2))
    w = np.stack([np.eye(3), np.full((3, 3), 1 / 3)])
    mixed = mix_information(w, InformationPair(y, v))
    np.testing.assert_allclose(mixed.matrix[0], y[0])
    np.testing.assert_allclose(mixed.matrix[1, 2], y[1].mean(axis=0))
    np.testing.assert_allclose(mixed.vector[1, 0], v[1].mean(axis=0))


# ------------------------------------------- one CI, named weight rules (pinned against their formulas)


def _infos(rng, runs, count, n):
    g = rng.normal(size=(runs, count, n, n)) * rng.uniform(0.2, 3.0, size=(runs, count, 1, n))
    return g @ np.swapaxes(g, -1, -2) + 0.1 * np.eye(n)


def test_the_weight_rules_compute_their_formulas(rng):
    """information_trace_weights: omega_i = tr Y_i / sum_j tr Y_j (paper 2 eq. 41);
    inverse_covariance_trace_weights: omega_i = (1 / tr P_i) / sum_j (1 / tr P_j) (Niehsen 2002); both per
    receiver over a support, zero outside it; min_trace_weights without a support is the full support's row."""
    from zentrack.fusion.covariance_intersection import (
        information_trace_weights,
        inverse_covariance_trace_weights,
        min_trace_weights,
    )

    infos = _infos(rng, 3, 4, 3)
    tr_y = np.array([[np.trace(y) for y in run] for run in infos])
    tr_p = np.array([[np.trace(np.linalg.inv(y)) for y in run] for run in infos])
    np.testing.assert_array_equal(information_trace_weights(infos), tr_y / tr_y.sum(axis=-1, keepdims=True))
    np.testing.assert_allclose(inverse_covariance_trace_weights(infos),
                               (1 / tr_p) / (1 / tr_p).sum(axis=-1, keepdims=True), rtol=1e-12)
    support = np.broadcast_to(np.array([[True, True, False, True], [False, True, True, False]]), (3, 2, 4))
    for rule, score in ((information_trace_weights, tr_y), (inverse_covariance_trace_weights, 1 / tr_p)):
        omega = rule(infos, support)
        assert omega.shape == (3, 2, 4) and np.all(omega[~support] == 0)
        expected = np.where(support, score[:, None, :], 0.0)
        np.testing.assert_allclose(omega, expected / expected.sum(axis=-1, keepdims=True), rtol=1e-12)
    # the two rules are different choices: the information trace favours a large Y, 1/tr P a small P
    skewed = np.array([[np.diag([100.0, 0.01]), np.diag([1.0, 1.0])]])
    assert information_trace_weights(skewed)[0, 0] > 0.9 and inverse_covariance_trace_weights(skewed)[0, 0] < 0.1
    full = np.ones((3, 1, 4), dtype=bool)
    np.testing.assert_array_equal(min_trace_weights(infos), min_trace_weights(infos, full)[:, 0])


def test_every_rule_combines_with_the_one_ci(rng):
    """ci, ci-fast, ci-trace, local: combine is ci_fuse with the rule's weights, bit for bit; diff-fci (consensus
    on trace-weighted pairs) is ci_fuse with the information-trace weights to rounding; diff-ici is inverse CI
    of the neighbourhood (ici_fuse, uniform weights) to rounding; ci_combine (viewer, bench centres) is ci_fuse
    with weights per run bit for bit, and ci_fuse_one (shared weights) to rounding."""
    from zentrack.fusion.covariance_intersection import (
        ci_combine,
        ci_fuse_one,
        information_trace_weights,
        inverse_covariance_trace_weights,
        min_trace_weights,
    )
    from zentrack.fusion.ici import ici_fuse
    from zentrack.fusion.linalg import from_information
    from zentrack.fusion.rules import make_rule

    runs, m, n = 2, 4, 3
    adj = np.array([[0, 1, 0, 1], [1, 0, 1, 0], [0, 1, 0, 1], [1, 0, 1, 0]])
    weights = np.where(adj | np.eye(m, dtype=int), 1.0 / 3, 0.0)
    infos = _infos(rng, runs, m, n)
    pair = InformationPair(infos, np.einsum("rmij,rmj->rmi", infos, rng.normal(size=(runs, m, n))))
    support = np.broadcast_to(weights > 0, (runs, m, m))

    def combined(name, w=weights):
        return make_rule(name).combine(1, w, {"state": pair})["state"]

    for name, omega in (("ci", weights), ("ci-fast", inverse_covariance_trace_weights(infos, support)),
                        ("ci-trace", min_trace_weights(infos, support))):
        got, want = combined(name), ci_fuse(omega, pair)
        np.testing.assert_array_equal(got.mean, want.mean)
        np.testing.assert_array_equal(got.cov, want.cov)
    local = combined("local", np.eye(m))
    np.testing.assert_array_equal(local.cov, from_information(pair).cov)

    for name in ("diff-fci", "diff-ici"):
        rule = make_rule(name)
        w = rule.network_weights(weights, adj)
        got = rule.combine(1, w, rule.share(1, {"state": pair}).blocks)["state"]
        if name == "diff-fci":
            want = ci_fuse(information_trace_weights(infos, support), pair)
        else:
            state = from_information(pair)
            near = [np.flatnonzero(row) for row in support[0]]
            want = GaussianState(np.stack([np.stack([ici_fuse(state.mean[r, j], state.cov[r, j]).mean for j in near])
                                           for r in range(runs)]),
                                 np.stack([np.stack([ici_fuse(state.mean[r, j], state.cov[r, j]).cov for j in near])
                                           for r in range(runs)]))
        np.testing.assert_allclose(got.cov, want.cov, rtol=1e-9)
        np.testing.assert_allclose(got.mean, want.mean, rtol=1e-9, atol=1e-9)

    omega = information_trace_weights(infos[0])
    checked = ci_combine(infos[0], pair.vector[0], omega)
    per_run = ci_fuse(omega[None, None], InformationPair(infos[:1], pair.vector[:1]))  # weights per run: einsum
    np.testing.assert_array_equal(checked.mean, per_run.mean[0, 0])
    np.testing.assert_array_equal(checked.cov, per_run.cov[0, 0])
    one = ci_fuse_one(omega, list(infos[0]), list(pair.vector[0]))  # shared weights: the matrix product
    np.testing.assert_allclose(checked.mean, one.mean[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(checked.cov, one.cov[0], rtol=1e-12)
    batched = ci_combine(infos, pair.vector, information_trace_weights(infos))
    for r in range(runs):
        np.testing.assert_allclose(batched.cov[r], ci_combine(infos[r], pair.vector[r], omega if r == 0 else
                                                              information_trace_weights(infos[r])).cov, rtol=1e-12)
    with pytest.raises(ValueError, match="non-negative and sum to 1"):
        ci_combine(infos[0], pair.vector[0], np.full(m, 0.5))
