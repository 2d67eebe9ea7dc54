"""Fusion rules: CI consistency under unknown correlation (property test), renormalisation, naive fusion."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zentrack.fusion.fusion_rules import ci_fuse, independent_fuse, mix_information, renormalise_rows
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
    """Seed 000 Lemma 1 / Theorem 3: for any correlation and convex weights, P_CI >= E[e e^T]."""
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
