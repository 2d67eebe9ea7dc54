"""Inverse covariance intersection and fast CI (zentrack.fusion.ici): consistency, when it holds and when not.

The fused error covariance is computed exactly from the linear fusion gains and a joint error covariance of the
estimates: ``E[e e^T] = K J K^T`` with ``K = [K_1 ... K_N]``. A rule is consistent when ``P - K J K^T >= 0``.
Three correlation models: common information (what ICI is derived for), independent estimates (a special case
of it, C = 0) and arbitrary joint covariances (what CI handles and ICI does not).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from zentrack.fusion.covariance_intersection import ci_combine, information_trace_weights
from zentrack.fusion.ici import (
    check_ici_weights,
    effective_count,
    ici_from_averages,
    ici_fuse,
    ici_fuse_two,
    ici_gains,
    ici_weights_valid,
)

inv = np.linalg.inv


def rand_spd(rng, n):
    g = rng.normal(size=(n, n)) * rng.uniform(0.1, 3.0, size=n)
    return g @ g.T + 1e-3 * np.eye(n)


def common_information(rng, n, count):
    """``P_j^-1 = D_j + C`` with private information ``D_j >= 0`` (random rank 0..n, scales spanning orders of
    magnitude) and common information ``C``; errors ``Cov(e_i, e_j) = P_i C P_j`` (Noack et al. 2017)."""
    c = inv(rand_spd(rng, n))
    covs = []
    for _ in range(count):
        g = rng.normal(size=(n, int(rng.integers(0, n + 1)))) * 10.0 ** rng.uniform(-2, 1)
        covs.append(inv(g @ g.T + c))
    joint = np.block([[covs[i] if i == j else covs[i] @ c @ covs[j] for j in range(count)] for i in range(count)])
    return covs, joint


def arbitrary_joint(rng, n, count):
    """Any joint error covariance: the estimates' covariances are its diagonal blocks."""
    joint = rand_spd(rng, n * count)
    return [joint[i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(count)], joint


def gap(cov, gains, joint):
    """Smallest eigenvalue of ``P - K J K^T`` relative to the size of P (>= -1e-9: consistent)."""
    k = np.hstack(list(gains))
    return np.linalg.eigvalsh(cov - k @ joint @ k.T).min() / np.abs(cov).max()


def two_gains(a_cov, b_cov, omega):
    """Noack et al. 2017: K_A = C (A^-1 - omega Gamma^-1), K_B = C (B^-1 - (1 - omega) Gamma^-1)."""
    g_inv = inv(omega * a_cov + (1 - omega) * b_cov)
    c = inv(inv(a_cov) + inv(b_cov) - g_inv)
    return c, [c @ (inv(a_cov) - omega * g_inv), c @ (inv(b_cov) - (1 - omega) * g_inv)]


def multi_gains(covs, alpha):
    """Ajgl & Straka 2020: K_i = P (P_i^-1 - (N - 1) alpha_i Gamma^-1)."""
    n = len(covs)
    g_inv = inv(sum(a * p for a, p in zip(alpha, covs)))
    p = inv(sum(inv(c) for c in covs) - (n - 1) * g_inv)
    return p, [p @ (inv(c) - (n - 1) * a * g_inv) for a, c in zip(alpha, covs)]


def sample_weights(rng, count, condition):
    """Random weights on the simplex: ``box`` (alpha_i <= 1/(N-1), often on the boundary) or ``ball_only``
    (sum alpha^2 <= 1/(N-1) but some alpha_i > 1/(N-1))."""
    centre = np.full(count, 1.0 / count)
    while True:
        d = rng.dirichlet(np.full(count, rng.choice([0.3, 1.0, 5.0])))
        if condition == "box":  # shrink towards the centre until inside the box, then a random part of the way
            room = (1.0 / (count - 1) - 1.0 / count) / max(d.max() - 1.0 / count, 1e-12)
            return centre + min(1.0, room) * min(1.0, 2.0 * rng.uniform()) * (d - centre)
        box = d.max() <= 1.0 / (count - 1)
        if (d**2).sum() <= 1.0 / (count - 1) and not box:
            return d


def fuse_means(covs, means, alpha):
    return ici_fuse(np.array(means)[None], np.array(covs)[None], np.asarray(alpha)[None], check=False)


# ------------------------------------------------------------------------------------- two-estimate ICI


def test_two_estimate_ici_bounds_common_information_at_optimal_and_random_omega():
    rng = np.random.default_rng(20)
    worst = 0.0
    for _ in range(80):
        n = int(rng.integers(1, 5))
        (a_cov, b_cov), joint = common_information(rng, n, 2)
        a, b = rng.normal(size=n), rng.normal(size=n)
        fused_opt, w_opt = ici_fuse_two(a, a_cov, b, b_cov)
        for omega in (float(w_opt), float(rng.uniform())):
            c, gains = two_gains(a_cov, b_cov, omega)
            fused = fused_opt if omega == float(w_opt) else ici_fuse_two(a, a_cov, b, b_cov, omega)[0]
            np.testing.assert_allclose(fused.cov, c, rtol=1e-7, atol=1e-12 * np.abs(c).max())
            np.testing.assert_allclose(fused.mean, gains[0] @ a + gains[1] @ b, rtol=1e-7,
                                       atol=1e-9 * (1 + np.abs(fused.mean).max()))
            worst = min(worst, gap(c, gains, joint))
    assert worst >= -1e-9


def test_two_estimate_ici_is_not_a_bound_for_arbitrary_correlations_but_ci_is():
    """ICI assumes common information; a general joint covariance can make it inconsistent, CI never."""
    rng = np.random.default_rng(21)
    ici_worst, ci_worst, violations = 0.0, 0.0, 0
    for _ in range(100):
        n = int(rng.integers(2, 4))
        (a_cov, b_cov), joint = arbitrary_joint(rng, n, 2)
        _, w = ici_fuse_two(np.zeros(n), a_cov, np.zeros(n), b_cov)
        g = gap(*two_gains(a_cov, b_cov, float(w)), joint)
        violations += g < -1e-9
        ici_worst = min(ici_worst, g)
        omega = information_trace_weights(np.array([inv(a_cov), inv(b_cov)]))
        p = inv(omega[0] * inv(a_cov) + omega[1] * inv(b_cov))
        ci_worst = min(ci_worst, gap(p, [p @ (omega[0] * inv(a_cov)), p @ (omega[1] * inv(b_cov))], joint))
    assert violations > 20 and ici_worst < -0.05
    assert ci_worst >= -1e-9


def test_optimal_omega_matches_scipy_and_is_batched():
    rng = np.random.default_rng(22)
    batch, n = 40, 3
    a_cov = np.array([rand_spd(rng, n) for _ in range(batch)])
    b_cov = np.array([rand_spd(rng, n) for _ in range(batch)])
    b_cov[:5] = 30.0 * a_cov[:5]  # B much larger than A: the optimum sits at the edge omega = 0
    a, b = rng.normal(size=(batch, n)), rng.normal(size=(batch, n))
    fused, omega = ici_fuse_two(a, a_cov, b, b_cov)
    assert omega.shape == (batch,) and fused.cov.shape == (batch, n, n) and fused.mean.shape == (batch, n)
    for k in range(batch):
        def trace(w, k=k):
            return np.trace(inv(inv(a_cov[k]) + inv(b_cov[k]) - inv(w * a_cov[k] + (1 - w) * b_cov[k])))

        res = minimize_scalar(trace, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-12})
        ref = min([(trace(0.0), 0.0), (trace(1.0), 1.0), (res.fun, res.x)])[1]
        assert abs(omega[k] - ref) < 1e-6, (k, omega[k], ref)
        assert trace(omega[k]) <= trace(ref) * (1 + 1e-12)
        single, w1 = ici_fuse_two(a[k], a_cov[k], b[k], b_cov[k])
        assert abs(float(w1) - omega[k]) < 1e-12
        np.testing.assert_allclose(single.cov, fused.cov[k], rtol=1e-12)
    assert np.all(omega[:5] == 0.0)


def test_two_estimate_rule_is_the_multi_estimate_rule_with_two():
    rng = np.random.default_rng(23)
    a_cov, b_cov = rand_spd(rng, 3), rand_spd(rng, 3)
    a, b = rng.normal(size=3), rng.normal(size=3)
    two, w = ici_fuse_two(a, a_cov, b, b_cov)
    multi = ici_fuse(np.array([a, b]), np.array([a_cov, b_cov]), np.array([w, 1 - w]))
    np.testing.assert_allclose(multi.cov, two.cov, rtol=1e-10)
    np.testing.assert_allclose(multi.mean, two.mean, rtol=1e-10, atol=1e-12)


# ----------------------------------------------------------------------------------- multi-estimate ICI


@pytest.mark.parametrize("count", [3, 4, 5, 6, 7, 8])
def test_multi_ici_bounds_common_information_with_uniform_and_box_weights(count):
    """Consistent under common information whenever alpha_i <= 1/(N-1) (uniform weights included): the proof
    reduces P - E[ee^T] >= 0 to f(Gamma) >= (N-1) sum alpha_i^2 f(P_i), f(X) = X - X C X matrix concave."""
    rng = np.random.default_rng(100 + count)
    worst = 0.0
    for trial in range(40):
        n = int(rng.integers(1, 4))
        covs, joint = common_information(rng, n, count)
        alpha = np.full(count, 1.0 / count) if trial % 4 == 0 else sample_weights(rng, count, "box")
        check_ici_weights(alpha, condition="box")
        p, gains = multi_gains(covs, alpha)
        means = rng.normal(size=(count, n))
        fused = fuse_means(covs, means, alpha)
        np.testing.assert_allclose(fused.cov[0], p, rtol=1e-7, atol=1e-12 * np.abs(p).max())
        np.testing.assert_allclose(fused.mean[0], sum(k @ x for k, x in zip(gains, means)), rtol=1e-6,
                                   atol=1e-8 * (1 + np.abs(fused.mean).max()))
        cov_g, gains_g = ici_gains(np.array(covs), alpha)
        np.testing.assert_allclose(gains_g, np.array(gains), rtol=1e-6, atol=1e-9 * np.abs(gains).max())
        worst = min(worst, gap(p, gains, joint))
    assert worst >= -1e-9


def test_ball_weights_alone_do_not_guarantee_consistency():
    """The paper's condition sum alpha^2 <= 1/(N-1) admits weights with some alpha_i > 1/(N-1); those can be
    inconsistent even for independent estimates (the common information C = 0): there the condition is
    sum_i alpha_i (1 - (N-1) alpha_i) P_i >= 0, broken by a large P_j under alpha_j > 1/(N-1)."""
    alpha = np.array([0.55, 0.30, 0.15])
    check_ici_weights(alpha)  # valid under the paper's ("ball") condition ...
    with pytest.raises(ValueError, match="alpha_i <= 1/\\(N-1\\)"):
        check_ici_weights(alpha, condition="box")  # ... but not the box
    covs = [np.array([[10.0]]), np.array([[1.0]]), np.array([[1.0]])]
    p, gains = multi_gains(covs, alpha)
    true = sum(k @ c @ k.T for k, c in zip(gains, covs))  # independent errors
    assert p[0, 0] == pytest.approx(0.5669, abs=1e-4) and true[0, 0] == pytest.approx(0.5728, abs=1e-4)
    assert p[0, 0] < true[0, 0]
    # and, measured over random common information with ball-but-not-box weights, the violation recurs
    rng = np.random.default_rng(31)
    gaps = []
    for _ in range(120):
        covs, joint = common_information(rng, int(rng.integers(1, 4)), 3)
        gaps.append(gap(*multi_gains(covs, sample_weights(rng, 3, "ball_only")), joint))
    assert min(gaps) < -1e-3 and sum(g < -1e-9 for g in gaps) >= 3


def test_multi_ici_is_not_a_bound_for_arbitrary_correlations_even_uniform():
    rng = np.random.default_rng(32)
    gaps = []
    for _ in range(60):
        covs, joint = arbitrary_joint(rng, 2, 4)
        gaps.append(gap(*multi_gains(covs, np.full(4, 0.25)), joint))
    assert min(gaps) < -0.05


def test_ici_is_not_a_bound_for_common_noise_either():
    """The dual model, a common noise w plus independent parts (e_i = w + u_i, Cov(e_i, e_j) = Cov(w)), is not
    the common information ICI is built for: uniform weights violate the bound there too."""
    rng = np.random.default_rng(34)
    gaps = []
    for count in (2, 4):
        for _ in range(40):
            n = int(rng.integers(1, 4))
            g = rng.normal(size=(n, n))
            common = g @ g.T
            covs = [common + rand_spd(rng, n) for _ in range(count)]
            joint = np.kron(np.ones((count, count)), common)
            for i, c in enumerate(covs):
                joint[i * n:(i + 1) * n, i * n:(i + 1) * n] = c
            gaps.append(gap(*multi_gains(covs, np.full(count, 1.0 / count)), joint))
    assert min(gaps) < -0.05


def test_distributed_form_with_exact_averages_is_centralised_uniform_ici():
    rng = np.random.default_rng(33)
    batch, count, n = 5, 6, 3
    covs = np.array([[rand_spd(rng, n) for _ in range(count)] for _ in range(batch)])
    means = rng.normal(size=(batch, count, n))
    infos = np.linalg.inv(covs)
    pair = ici_from_averages(infos.mean(axis=1), np.einsum("bkij,bkj->bi", infos, means) / count,
                             covs.mean(axis=1), means.mean(axis=1), count)
    central = ici_fuse(means, covs)
    np.testing.assert_allclose(np.linalg.inv(pair.matrix), central.cov, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.linalg.solve(pair.matrix, pair.vector[..., None])[..., 0], central.mean,
                               rtol=1e-9, atol=1e-10)
    assert np.all(effective_count(np.full((batch, count), 1.0 / count)) == pytest.approx(count))


# ----------------------------------------------------------------------------------------- weight checks


@pytest.mark.parametrize("alpha, message", [
    ([0.6, 0.6, -0.2], "non-negative.*-0.2"),
    ([0.3, 0.3, 0.3], "sum to 1.*0.9"),
    ([0.7, 0.2, 0.1], r"sum alpha\^2 <= 1/\(N-1\) = 0.5 \(N = 3\).*0.54"),
    ([0.5, np.nan, 0.5], "finite"),
])
def test_weight_conditions_are_enforced_with_clear_errors(alpha, message):
    with pytest.raises(ValueError, match=message):
        check_ici_weights(np.array(alpha))
    assert not ici_weights_valid(np.array(alpha))
    with pytest.raises(ValueError, match=message):
        ici_fuse(np.zeros((3, 2)), np.broadcast_to(np.eye(2), (3, 2, 2)), np.array(alpha))


def test_weight_checks_name_the_offending_row_and_accept_valid_ones():
    rows = np.array([[0.4, 0.3, 0.3], [0.8, 0.1, 0.1]])
    with pytest.raises(ValueError, match=r"weights \(1,\)"):
        check_ici_weights(rows)
    assert ici_weights_valid(rows).tolist() == [True, False]
    check_ici_weights(np.array([1.0]))  # one estimate: trivially valid
    check_ici_weights(np.array([1.0, 0.0]))  # two estimates: any convex weights
    check_ici_weights(np.full(8, 1 / 8), condition="box")
    with pytest.raises(ValueError, match="condition"):
        check_ici_weights(rows, condition="disc")


def test_bad_inputs_raise_instead_of_returning_garbage():
    covs = np.broadcast_to(np.eye(2), (3, 2, 2)).copy()
    means = np.zeros((3, 2))
    bad_mean = means.copy()
    bad_mean[1, 0] = np.inf
    with pytest.raises(ValueError, match="means has non-finite"):
        ici_fuse(bad_mean, covs)
    not_spd = covs.copy()
    not_spd[2] = np.diag([1.0, -1.0])
    with pytest.raises(ValueError, match="covs is not symmetric positive definite"):
        ici_fuse(means, not_spd)
    skewed = covs.copy()
    skewed[0] = [[1.0, 0.5], [0.0, 1.0]]
    with pytest.raises(ValueError, match="not symmetric positive definite"):
        ici_fuse(means, skewed)
    # alpha = (1, 0, 0) violates the conditions; unchecked, the fused information Y2 + Y3 - Y1 is indefinite
    big = np.array([np.eye(2) * 0.01, np.eye(2), np.eye(2)])
    with pytest.raises(ValueError, match="fused ICI information matrix is not symmetric positive definite"):
        ici_fuse(means, big, np.array([1.0, 0.0, 0.0]), check=False)
    with pytest.raises(ValueError, match="omega must lie in"):
        ici_fuse_two(np.zeros(2), np.eye(2), np.zeros(2), np.eye(2), omega=1.5)
    with pytest.raises(ValueError, match="b has non-finite"):
        ici_fuse_two(np.zeros(2), np.eye(2), np.array([np.nan, 0.0]), np.eye(2))
    with pytest.raises(ValueError, match="fused ICI information matrix"):
        ici_from_averages(0.1 * np.eye(2), np.zeros(2), 0.1 * np.eye(2), np.zeros(2), 8)
    with pytest.raises(ValueError, match="Pbar"):
        ici_from_averages(np.eye(2), np.zeros(2), -np.eye(2), np.zeros(2), 8)


# ------------------------------------------------------------------ CI with the information-trace weights


def test_information_trace_weights_are_normalised_traces():
    rng = np.random.default_rng(40)
    infos = np.array([[inv(rand_spd(rng, 3)) for _ in range(4)] for _ in range(6)])
    w = information_trace_weights(infos)
    tr = np.trace(infos, axis1=-2, axis2=-1)
    np.testing.assert_allclose(w.sum(axis=-1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(w / tr, (w / tr)[:, :1] * np.ones((1, 4)), rtol=1e-12)
    assert np.all(w > 0)
    with pytest.raises(ValueError, match="not symmetric positive definite"):  # the checked combination refuses it
        ci_combine(np.array([np.eye(2), -np.eye(2)]), np.zeros((2, 2)), np.array([0.5, 0.5]))


def test_ci_with_information_trace_weights_is_consistent_for_correlated_estimates():
    rng = np.random.default_rng(41)
    worst = 0.0
    for _ in range(80):
        count, n = int(rng.integers(2, 5)), int(rng.integers(1, 4))
        covs, joint = arbitrary_joint(rng, n, count)
        infos = np.array([inv(c) for c in covs])
        means = rng.normal(size=(count, n))
        w = information_trace_weights(infos)
        fused = ci_combine(infos, np.einsum("kij,kj->ki", infos, means), w)
        gains = [fused.cov @ (wi * y) for wi, y in zip(w, infos)]
        np.testing.assert_allclose(fused.mean, sum(k @ x for k, x in zip(gains, means)), rtol=1e-8, atol=1e-10)
        worst = min(worst, gap(fused.cov, gains, joint))
    assert worst >= -1e-9
    with pytest.raises(ValueError, match="non-negative and sum to 1"):
        ci_combine(np.array([np.eye(2)] * 2), np.zeros((2, 2)), np.array([0.7, 0.7]))
