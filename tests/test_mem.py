"""Paper 4's MEM-EKF* and its information form: the update against an explicit re-derivation, information
form = covariance form, the prediction, the R^p guard, relays and padding, and a Monte Carlo run of the paper's
S2 ellipse."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext
from zentrack.fusion.filters.mem import (
    ExtentPointModel,
    MemEkfFilter,
    MemInformationFilter,
    information_predict,
    kron_cov,
    mem_information_increment,
    mem_linearisation,
    mem_point_update,
    rp_matrix,
    shape_jacobians,
)
from zentrack.fusion.linalg import GaussianState, InformationPair, is_spd
from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.motion_eot import (
    S2_MEAS_NOISE,
    S2_PRIOR_EXTENT,
    S2_PRIOR_KINEMATIC,
    S2_Q_EXTENT,
    S2_Q_KINEMATIC,
    S2_SPEED,
    S2_SPREAD,
    S2_TS,
    ExtendedObjectMotion,
)


# ------------------------------------------------------------------------------------------ reference maths
def reference_mem_ekf(x, cx, p, cp, y, cv, ch):
    """One MEM-EKF* update (Yang & Baum 2019, Table I; paper 4 Props. 1-2) for ONE point, written out with
    plain 2x2/3x3 matrices and np.kron, independently of the package (standard, non-Joseph form)."""
    a, l1, l2 = p
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    s = rot @ np.diag([l1, l2])
    s1, s2 = s[0], s[1]
    j1 = np.array([[-l1 * np.sin(a), np.cos(a), 0.0], [-l2 * np.cos(a), 0.0, -np.sin(a)]])
    j2 = np.array([[l1 * np.cos(a), np.sin(a), 0.0], [-l2 * np.sin(a), 0.0, np.cos(a)]])
    js = (j1, j2)
    c_i = s @ ch @ s.T
    c_ii = np.array([[np.trace(cp @ js[n].T @ ch @ js[m]) for n in range(2)] for m in range(2)])
    h = np.hstack([np.eye(2), np.zeros((2, 2))])
    c_y = h @ cx @ h.T + c_i + c_ii + cv
    gain = cx @ h.T @ np.linalg.inv(c_y)
    x_post = x + gain @ (y - h @ x)
    cx_post = cx - gain @ c_y @ gain.T
    f = np.array([[1.0, 0, 0, 0], [0, 0, 0, 1], [0, 1, 0, 0]])
    f_tilde = np.array([[1.0, 0, 0, 0], [0, 0, 0, 1], [0, 0, 1, 0]])
    e = y - h @ x
    big_y = f @ np.kron(e, e)
    y_bar = f @ c_y.flatten(order="F")  # F vect(C^y), vect stacks columns
    c_yy = f @ np.kron(c_y, c_y) @ (f + f_tilde).T
    m = np.vstack([2 * s1 @ ch @ j1, 2 * s2 @ ch @ j2, s1 @ ch @ j2 + s2 @ ch @ j1])
    c_py = cp @ m.T
    p_post = p + c_py @ np.linalg.solve(c_yy, big_y - y_bar)
    cp_post = cp - c_py @ np.linalg.solve(c_yy, c_py.T)
    return x_post, cx_post, p_post, cp_post


def random_spd(rng, n, scale):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T / n + 0.2 * np.eye(n))


def random_prior(rng, b):
    """Random kinematic/extent priors (S2-like magnitudes), points near the object."""
    x = rng.normal(0.0, 50.0, (b, 4))
    cx = np.stack([random_spd(rng, 4, rng.uniform(5, 200)) for _ in range(b)])
    p = np.column_stack([rng.uniform(-np.pi, np.pi, b), rng.uniform(20, 200, b), rng.uniform(5, 60, b)])
    cp = np.stack([random_spd(rng, 3, 1.0) * np.array([0.3, 30, 30])[:, None] ** 0.5
                   * np.array([0.3, 30, 30])[None, :] ** 0.5 for _ in range(b)])
    cv = np.stack([random_spd(rng, 2, rng.uniform(1, 200)) for _ in range(b)])
    return x, cx, p, cp, cv


def info_to_state(omega, q):
    cov = np.linalg.inv(omega)
    return (cov @ q[..., None])[..., 0], cov


def test_shape_jacobians_match_finite_differences(rng):
    p = np.column_stack([rng.uniform(-3, 3, 5), rng.uniform(1, 200, 5), rng.uniform(1, 60, 5)])

    def s_of(q):
        a, l1, l2 = q
        return np.array([[l1 * np.cos(a), -l2 * np.sin(a)], [l1 * np.sin(a), l2 * np.cos(a)]])

    jac = shape_jacobians(p)
    for b in range(5):
        for k in range(3):
            d = np.zeros(3)
            d[k] = 1e-6
            num = (s_of(p[b] + d) - s_of(p[b] - d)) / 2e-6  # d S / d p_k: row n is d S_n / d p_k
            np.testing.assert_allclose(jac[b, :, :, k], num, rtol=1e-6, atol=1e-6)


def test_pseudo_measurement_covariance_is_the_gaussian_fourth_moment(rng):
    """C_Y = F (C (x) C)(F + Ftilde)^T (eq. 13) against Isserlis' theorem for [e1^2, e2^2, e1 e2], e ~ N(0, C)."""
    cy = np.stack([random_spd(rng, 2, 10.0) for _ in range(4)])
    got = kron_cov(cy)
    for c, g in zip(cy, got):
        a, d, o = c[0, 0], c[1, 1], c[0, 1]
        want = np.array([[2 * a * a, 2 * o * o, 2 * a * o], [2 * o * o, 2 * d * d, 2 * d * o],
                         [2 * a * o, 2 * d * o, a * d + o * o]])
        np.testing.assert_allclose(g, want, rtol=1e-12)


def test_point_update_equals_an_explicit_mem_ekf_star(rng):
    b = 12
    x, cx, p, cp, cv = random_prior(rng, b)
    ch = np.array([[0.3, 0.05], [0.05, 0.2]])
    y = x[:, :2] + rng.normal(0.0, 60.0, (b, 2))
    lin = mem_linearisation(cx, p, cp, cv, ch)
    assert not rp_matrix(lin.c_yy, lin.m, cp)[1].any()  # the guard is inactive: plain MEM-EKF*
    post = mem_point_update(x, cx, p, cp, y, cv, ch)
    for r in range(b):
        ref = reference_mem_ekf(x[r], cx[r], p[r], cp[r], y[r], cv[r], ch)
        for got, want in zip((post.x[r], post.cx[r], post.p[r], post.cp[r]), ref):
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * np.abs(want).max())
    # a shared (2, 2) C^v is the same as the broadcast stack
    shared = mem_point_update(x, cx, p, cp, y, cv[0], ch)
    stacked = mem_point_update(x, cx, p, cp, y, np.broadcast_to(cv[0], (b, 2, 2)), ch)
    for u, v in zip(shared, stacked):
        np.testing.assert_array_equal(u, v)


# ------------------------------------------------------------------------------------------ information form
def test_one_point_information_increment_equals_the_covariance_update(rng):
    """Kinematic block: the IF of model (6) is the Kalman update with C^y, i.e. MEM-EKF*'s. Extent block: with
    V^p = (C_Y - M C^p M^T)^-1 and Ytilde = Y - F vect(C^y) + M p the IF gives p + C^p M^T C_Y^-1 (Y - F vect(C^y))
    and C^p - C^p M^T C_Y^-1 M C^p (matrix inversion lemma): exactly MEM-EKF*'s extent update as well."""
    b = 20
    x, cx, p, cp, cv = random_prior(rng, b)
    ch = S2_SPREAD
    y = x[:, :2] + rng.normal(0.0, 60.0, (b, 2))
    kin, ext = mem_information_increment(x, cx, p, cp, y[:, None], np.ones((b, 1), bool), cv, ch)
    ox, op = np.linalg.inv(cx), np.linalg.inv(cp)
    xi, cxi = info_to_state(ox + kin.matrix, (ox @ x[..., None])[..., 0] + kin.vector)
    pi, cpi = info_to_state(op + ext.matrix, (op @ p[..., None])[..., 0] + ext.vector)
    post = mem_point_update(x, cx, p, cp, y, cv, ch)
    for r in range(b):
        ref = reference_mem_ekf(x[r], cx[r], p[r], cp[r], y[r], cv[r], ch)
        for got, want in zip((xi[r], cxi[r], pi[r], cpi[r]), ref):
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    for got, want in zip((xi, cxi, pi, cpi), post):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


def test_sequential_increment_equals_sequential_mem_ekf_and_differs_from_summing_at_the_prior(rng):
    b, j = 6, 8
    x, cx, p, cp, cv = random_prior(rng, b)
    pts = x[:, None, :2] + rng.normal(0.0, 60.0, (b, j, 2))
    valid = np.ones((b, j), bool)
    kin, ext = mem_information_increment(x, cx, p, cp, pts, valid, cv, S2_SPREAD)  # the paper: sequential
    est = (x, cx, p, cp)
    for i in range(j):
        est = mem_point_update(*est, pts[:, i], cv, S2_SPREAD)
    ox, op = np.linalg.inv(cx), np.linalg.inv(cp)
    xi, cxi = info_to_state(ox + kin.matrix, (ox @ x[..., None])[..., 0] + kin.vector)
    pi, cpi = info_to_state(op + ext.matrix, (op @ p[..., None])[..., 0] + ext.vector)
    for got, want in zip((xi, cxi, pi, cpi), est):
        np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-8 * np.abs(want).max())
    # summed at the prior: the sum of the one-point increments, all linearised at the prior
    kin0, ext0 = mem_information_increment(x, cx, p, cp, pts, valid, cv, S2_SPREAD, sequential=False)
    singles = [mem_information_increment(x, cx, p, cp, pts[:, i:i + 1], valid[:, :1], cv, S2_SPREAD) for i in range(j)]
    np.testing.assert_allclose(kin0.matrix, sum(s[0].matrix for s in singles), rtol=1e-12)
    np.testing.assert_allclose(ext0.vector, sum(s[1].vector for s in singles), rtol=1e-10)
    assert not np.allclose(ext0.matrix, ext.matrix, rtol=1e-3)  # a different filter


def test_filters_update_agree_and_information_increment_is_block_diagonal(rng):
    motion, meas = ExtendedObjectMotion.paper("s2"), ExtentPointModel(S2_SPREAD, S2_MEAS_NOISE)
    ctx = FilterContext(motion, meas, S2_PRIOR_KINEMATIC)
    ekf, inf = FILTER_REGISTRY.create("mem-ekf", {}, ctx), FILTER_REGISTRY.create("mem-if", {}, ctx)
    assert isinstance(ekf, MemEkfFilter) and isinstance(inf, MemInformationFilter)
    assert (ekf.state_dim, ekf.kinematic_dim, meas.name, meas.dim) == (7, 7, "extent-point", 2)
    b = 5
    x, cx, p, cp, _ = random_prior(rng, b)
    cov = np.zeros((b, 7, 7))
    cov[:, :4, :4], cov[:, 4:, 4:] = cx, cp
    state = inf.initial_state(np.hstack([x, p]), cov)
    pts = x[:, None, :2] + rng.normal(0.0, 60.0, (b, 6, 2))
    counts = np.array([6, 3, 1, 0, 5])
    a, c = ekf.update(state, pts, None, S2_MEAS_NOISE, counts), inf.update(state, pts, None, S2_MEAS_NOISE, counts)
    np.testing.assert_allclose(c.mean, a.mean, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(c.cov, a.cov, rtol=1e-8, atol=1e-8 * np.abs(a.cov).max())
    inc = inf.information_increment(state, pts, None, S2_MEAS_NOISE, counts)
    assert inc.matrix.shape == (b, 7, 7) and inc.vector.shape == (b, 7)
    assert np.all(inc.matrix[:, :4, 4:] == 0) and np.all(inc.matrix[:, 4:, :4] == 0)
    assert np.all(inc.matrix[:, 2:4, :] == 0)  # points observe the centre only (H = [I 0])
    assert is_spd(a.cov).all() and np.all(a.cov[:, :4, 4:] == 0)
    # a (B, 2) single point is a scan of one
    one_a = inf.update(state, pts[:, 0], None, S2_MEAS_NOISE)
    one_b = inf.update(state, pts[:, :1], None, S2_MEAS_NOISE, np.ones(b, int))
    np.testing.assert_array_equal(one_a.mean, one_b.mean)
    with pytest.raises(ValueError, match="7 components"):
        inf.initial_state(x, cx)


# ------------------------------------------------------------------------------------------ prediction
def test_information_prediction_equals_the_covariance_prediction(rng):
    motion = ExtendedObjectMotion.paper("s2")
    b = 7
    x, cx, p, cp, _ = random_prior(rng, b)
    for sl, m, c in ((slice(0, 4), x, cx), (slice(4, 7), p, cp)):
        f, q = motion.A[sl, sl], motion.Q[sl, sl]
        omega = np.linalg.inv(c)
        pred = information_predict(InformationPair(omega, (omega @ m[..., None])[..., 0]), f, q)
        mean, cov = info_to_state(pred.matrix, pred.vector)
        np.testing.assert_allclose(mean, m @ f.T, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(cov, f @ c @ f.T + q, rtol=1e-10, atol=1e-9)
        # the paper's eq. (20b): W - W F (Omega + F^T W F)^-1 F^T W, W = C_w^-1
        w = np.linalg.inv(q)
        paper = w - w @ f @ np.linalg.inv(omega + f.T @ w @ f) @ f.T @ w
        np.testing.assert_allclose(pred.matrix, paper, rtol=1e-8, atol=1e-10 * np.abs(paper).max())
    # the filters: mem-if predicts in information form, mem-ekf in covariance form
    meas = ExtentPointModel(S2_SPREAD, S2_MEAS_NOISE)
    cov = np.zeros((b, 7, 7))
    cov[:, :4, :4], cov[:, 4:, 4:] = cx, cp
    state = GaussianState(np.hstack([x, p]), cov)
    a = MemEkfFilter(motion, meas).predict(state)
    c = MemInformationFilter(motion, meas).predict(state)
    np.testing.assert_allclose(c.mean, a.mean, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(c.cov, a.cov, rtol=1e-10, atol=1e-9)


def test_motion_model_blocks():
    m = ExtendedObjectMotion(2.0, S2_Q_KINEMATIC, S2_Q_EXTENT)
    assert (m.name, m.dim, m.lumped_dim) == ("eot", 7, 0)
    x = np.array([[1.0, 2.0, 3.0, -4.0, 0.5, 10.0, 5.0]])
    np.testing.assert_allclose(m.f(x), [[7.0, -6.0, 3.0, -4.0, 0.5, 10.0, 5.0]])
    np.testing.assert_allclose(m.noise_factor @ m.noise_factor.T, m.Q)
    assert m.jacobian(np.zeros((3, 7))).shape == (3, 7, 7) and m.lumped_nominal(x) is None
    assert m.true_lumped(np.zeros((3, 7)), 0).shape == (3, 0) and m.B.shape == (7, 0)
    assert np.all(m.Q[:4, 4:] == 0) and np.all(m.A[:4, 4:] == 0)
    with pytest.raises(ValueError):
        ExtendedObjectMotion(1.0, -np.eye(4), S2_Q_EXTENT)


# ------------------------------------------------------------------------------------------ R^p guard
def test_rp_stays_spd_over_10000_random_updates():
    rng = np.random.default_rng(4)
    b = 10_000
    x = rng.normal(0.0, 100.0, (b, 4))
    a = rng.normal(size=(b, 4, 4))
    cx = a @ np.swapaxes(a, 1, 2) * 10 ** rng.uniform(-1, 3, (b, 1, 1)) + 1e-3 * np.eye(4)
    p = np.column_stack([rng.uniform(-10, 10, b), 10 ** rng.uniform(-0.5, 2.5, b), 10 ** rng.uniform(-0.5, 2.5, b)])
    a = rng.normal(size=(b, 3, 3))
    cp = a @ np.swapaxes(a, 1, 2) * 10 ** rng.uniform(-3, 2, (b, 1, 1)) + 1e-6 * np.eye(3)
    a = rng.normal(size=(b, 2, 2))
    cv = a @ np.swapaxes(a, 1, 2) * 10 ** rng.uniform(-2, 2, (b, 1, 1)) + 1e-3 * np.eye(2)
    y = x[:, :2] + rng.normal(size=(b, 2)) * p[:, 1:]
    lin = mem_linearisation(cx, p, cp, cv, S2_SPREAD)
    rp, clipped = rp_matrix(lin.c_yy, lin.m, cp)
    assert is_spd(rp).all()
    np.linalg.cholesky(rp)
    assert clipped.mean() < 0.01  # the guard is for rounding, not the normal case
    raw = lin.c_yy - lin.m @ cp @ np.swapaxes(lin.m, 1, 2)
    np.testing.assert_array_equal(rp[~clipped], (0.5 * (raw + np.swapaxes(raw, 1, 2)))[~clipped])
    # and along sequential updates: 5 more points per prior (50,000 updates in all)
    est = (x, cx, p, cp)
    for _ in range(5):
        est = mem_point_update(*est, y, cv, S2_SPREAD)
        assert is_spd(est.cx).all() and is_spd(est.cp).all()
        nxt = mem_linearisation(est.cx, est.p, est.cp, cv, S2_SPREAD)
        rp_k, clipped_k = rp_matrix(nxt.c_yy, nxt.m, est.cp)
        assert is_spd(rp_k).all() and clipped_k.mean() < 0.01
        y = est.x[:, :2] + rng.normal(size=(b, 2)) * np.abs(est.p[:, 1:])
    # an inconsistent input (a prior C^p much wider than the one C_Y was built with): R^p is indefinite and
    # the guard lifts it to R^p >= floor C_Y, still SPD
    wide = cp * 1e4
    bad, clipped = rp_matrix(lin.c_yy, lin.m, wide, rel_floor=1e-6)
    assert clipped.mean() > 0.5 and is_spd(bad).all()
    w, u = np.linalg.eigh(lin.c_yy[clipped])
    inv_root = (u / np.sqrt(w)[:, None, :]) @ np.swapaxes(u, 1, 2)
    whitened = np.linalg.eigvalsh(inv_root @ bad[clipped] @ inv_root)
    assert whitened.min() > 0.99e-6


# ------------------------------------------------------------------------------------------ relays, padding
def test_relay_gets_a_zero_increment_and_padding_contributes_nothing(rng):
    motion, meas = ExtendedObjectMotion.paper("s2"), ExtentPointModel(S2_SPREAD, S2_MEAS_NOISE)
    inf = MemInformationFilter(motion, meas)
    ekf = MemEkfFilter(motion, meas)
    b, j = 4, 5
    x, cx, p, cp, _ = random_prior(rng, b)
    cov = np.zeros((b, 7, 7))
    cov[:, :4, :4], cov[:, 4:, 4:] = cx, cp
    state = GaussianState(np.hstack([x, p]), cov)
    pts = x[:, None, :2] + rng.normal(0.0, 60.0, (b, j, 2))
    counts = np.array([0, 2, 5, 0])
    padded = pts.copy()
    padded[0] = np.nan
    padded[1, 2:] = 1e300
    padded[3] = -7.0
    inc = inf.information_increment(state, padded, None, S2_MEAS_NOISE, counts)
    assert np.all(np.isfinite(inc.matrix)) and np.all(np.isfinite(inc.vector))
    for relay in (0, 3):
        assert np.all(inc.matrix[relay] == 0.0) and np.all(inc.vector[relay] == 0.0)
        for f in (inf, ekf):
            post = f.update(state, padded, None, S2_MEAS_NOISE, counts)
            np.testing.assert_array_equal(post.mean[relay], state.mean[relay])
            np.testing.assert_array_equal(post.cov[relay], state.cov[relay])
    zero = inf.information_increment(state, pts, None, S2_MEAS_NOISE, np.zeros(b, int))
    assert np.all(zero.matrix == 0.0) and np.all(zero.vector == 0.0)
    # each row equals the increment of its real points alone
    for r in (1, 2):
        alone = inf.information_increment(GaussianState(state.mean[r:r + 1], state.cov[r:r + 1]),
                                          pts[r:r + 1, : counts[r]], None, S2_MEAS_NOISE)
        np.testing.assert_allclose(inc.matrix[r], alone.matrix[0], rtol=1e-12, atol=0)
        np.testing.assert_allclose(inc.vector[r], alone.vector[0], rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------------------ S2 Monte Carlo
def simulate_s2(runs, steps, lam, seed, q_extent=S2_Q_EXTENT):
    """The paper's S2 ellipse on a straight path: heading -pi/4 at 50 km/h, aligned with the object; the
    kinematics follow the model (C^x_w process noise) so a consistent filter has NEES ~ 4; the extent is fixed.
    Points y = H x + S h + v, h uniform on the unit disc (C^h = I/4), Poisson(lam) points per scan."""
    rng = np.random.default_rng(seed)
    motion = ExtendedObjectMotion(S2_TS, S2_Q_KINEMATIC, q_extent)
    heading = -np.pi / 4
    x = np.tile([0.0, 0.0, S2_SPEED * np.cos(heading), S2_SPEED * np.sin(heading)], (runs, 1))
    p = np.array([heading, 170.0, 40.0])
    s = np.array([[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]]) @ np.diag(p[1:])
    truth, scans, counts = [], [], []
    for _ in range(steps):
        truth.append(x)
        n = rng.poisson(lam, runs)
        jmax = max(int(n.max()), 1)
        r, th = np.sqrt(rng.uniform(size=(runs, jmax))), rng.uniform(0, 2 * np.pi, (runs, jmax))
        h = np.stack([r * np.cos(th), r * np.sin(th)], -1)
        v = rng.multivariate_normal(np.zeros(2), S2_MEAS_NOISE, (runs, jmax))
        scans.append(x[:, None, :2] + h @ s.T + v)
        counts.append(n)
        x = x @ motion.F_kinematic.T + rng.multivariate_normal(np.zeros(4), S2_Q_KINEMATIC, runs)
    prior = np.hstack([truth[0] + rng.multivariate_normal(np.zeros(4), S2_PRIOR_KINEMATIC, runs),
                       p + rng.multivariate_normal(np.zeros(3), S2_PRIOR_EXTENT, runs)])
    return motion, np.array(truth), p, scans, counts, prior


def run_s2(name, runs, steps=40, lam=10, seed=0, q_extent=S2_Q_EXTENT):
    motion, truth, p, scans, counts, prior = simulate_s2(runs, steps, lam, seed, q_extent)
    ctx = FilterContext(motion, ExtentPointModel(S2_SPREAD, S2_MEAS_NOISE), S2_PRIOR_KINEMATIC)
    filt = FILTER_REGISTRY.create(name, {}, ctx)
    cov0 = np.zeros((7, 7))
    cov0[:4, :4], cov0[4:, 4:] = S2_PRIOR_KINEMATIC, S2_PRIOR_EXTENT
    state = filt.initial_state(prior, cov0)
    means, covs = [], []
    for k in range(steps):
        state = filt.update(state, scans[k], None, S2_MEAS_NOISE, counts[k])
        means.append(state.mean)
        covs.append(state.cov)
        state = filt.predict(state)
    return truth, p, np.array(means), np.array(covs)


def test_s2_ellipse_extent_converges_and_kinematic_nees_is_consistent():
    """200 runs x 40 scans (lambda = 10). Measured (seeds 0-3, 300 runs): kinematic NEES 3.96-4.07 averaged
    over scans 20-39, l1 169.1-169.6, l2 36.3-36.7, median orientation error 0.05-0.06 rad.

    l2 is biased low by design of MEM-EKF*: C^II puts l1^2 var(alpha) C^h into the predicted spread along the
    minor axis, and the paper's orientation process noise (0.05 rad^2 per scan) keeps var(alpha) ~ 0.01, so
    ~170^2 * 0.01 / 4 of the minor-axis spread (40^2 / 4 = 400) is attributed to orientation:
    l2 ~ sqrt(4 (400 - 70)) ~ 36.  With a small orientation process noise the bias goes (next test)."""
    truth, p, mean, cov = run_s2("mem-if", runs=200)
    err = mean[..., :4] - truth
    nees = np.einsum("kbi,kbij,kbj->kb", err, np.linalg.inv(cov[..., :4, :4]), err)
    assert 3.6 < nees[10:].mean() < 4.4, nees.mean(axis=1)
    assert np.all((nees.mean(axis=1)[5:] > 3.0) & (nees.mean(axis=1)[5:] < 5.2)), nees.mean(axis=1)
    l1, l2 = mean[-1, :, 5], mean[-1, :, 6]
    assert abs(l1.mean() - 170.0) < 3.0 and 34.0 < l2.mean() < 39.0, (l1.mean(), l2.mean())
    # orientation: an angle, and an ellipse is the same under alpha + pi
    d_alpha = np.mod(wrap_angle(mean[-1, :, 4] - p[0]) + np.pi / 2, np.pi) - np.pi / 2
    assert np.median(np.abs(d_alpha)) < 0.1
    # the estimates improve on the prior: final extent errors well below the prior spread
    assert np.sqrt(np.mean((l1 - 170.0) ** 2)) < 0.7 * np.sqrt(S2_PRIOR_EXTENT[1, 1])
    assert np.all(np.isfinite(mean)) and is_spd(cov.reshape(-1, 7, 7)).all()


def test_s2_minor_axis_bias_comes_from_the_orientation_process_noise():
    q_extent = np.diag([1e-3, 1.0, 1.0])
    _, _, mean, _ = run_s2("mem-if", runs=150, seed=1, q_extent=q_extent)
    assert abs(mean[-1, :, 6].mean() - 40.0) < 1.5 and abs(mean[-1, :, 5].mean() - 170.0) < 2.0


def test_s2_information_filter_equals_mem_ekf_over_a_run():
    _, _, m_ekf, c_ekf = run_s2("mem-ekf", runs=20, steps=25, lam=5, seed=3)
    _, _, m_if, c_if = run_s2("mem-if", runs=20, steps=25, lam=5, seed=3)
    np.testing.assert_allclose(m_if, m_ekf, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(c_if, c_ekf, rtol=1e-7, atol=1e-7 * np.abs(c_ekf).max())
