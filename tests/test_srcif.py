"""SRCIF (paper 2 Section 2.2): its time update is the CKF's, its measurement update is the Kalman update of
the statistically linearised model (equal to the CKF and the KF for linear measurements), contributions add,
padded scans vanish, and a long bearing-only run stays SPD and consistent."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext, cubature_kalman_filter, make_local_filter
from zentrack.fusion.filters.sigma_point import cubature_points, sigma_points, weighted_cov
from zentrack.fusion.filters.srcif import SquareRootCubatureInformationFilter, sqrt_factor, tria
from zentrack.fusion.linalg import GaussianState, is_spd, mat_vec
from zentrack.fusion.measurement import BearingModel, PointModel, wrap_angle
from zentrack.fusion.motion import ManeuveringCV3D
from zentrack.fusion.motion_ca import ConstantAcceleration3D
from zentrack.study.simulator import run_filter

DEG = np.pi / 180.0


class CA3D:
    """Linear 9-state constant acceleration, state ``[x, y, z, vx, vy, vz, ax, ay, az]`` (paper 2's model with
    the components grouped by derivative order so that positions come first), noise ``Q = s^2 G G^T`` (rank 3)."""

    name = "ca3d-test"
    dim = 9

    def __init__(self, ts: float = 0.5, sigma_w: float = 0.5, with_factor: bool = True) -> None:
        self.ts = ts
        f1 = np.array([[1.0, ts, ts**2 / 2], [0.0, 1.0, ts], [0.0, 0.0, 1.0]])
        g1 = np.array([[ts**2 / 2], [ts], [1.0]])
        self.A = np.kron(f1, np.eye(3))
        self.G = np.kron(g1, np.eye(3))
        self.Q = sigma_w**2 * self.G @ self.G.T
        if with_factor:
            self.noise_factor = sigma_w * self.G

    def f(self, x):
        return x @ self.A.T

    def jacobian(self, x):
        return np.broadcast_to(self.A, (x.shape[0], 9, 9)).copy()


def random_spd(rng, b, n, scales):
    """``b`` SPD matrices with standard deviations of the order of ``scales`` and random correlations."""
    m = rng.normal(size=(b, n, n)) / np.sqrt(n)
    core = m @ np.swapaxes(m, -1, -2) + 0.2 * np.eye(n)
    d = np.asarray(scales, dtype=float)
    return core * d[:, None] * d[None, :]


CA_SCALES = [100.0] * 3 + [10.0] * 3 + [1.0] * 3


def prior_near(rng, b, centre, scales):
    cov = random_spd(rng, b, len(centre), scales)
    mean = centre + rng.normal(size=(b, len(centre))) * np.asarray(scales)
    return GaussianState(mean, cov)


def block_diag_noise(blocks):
    """``(B, S*m, S*m)`` from per-sensor blocks ``(B, S, m, m)``."""
    b, s, m, _ = blocks.shape
    out = np.zeros((b, s * m, s * m))
    for i in range(s):
        out[:, i * m : (i + 1) * m, i * m : (i + 1) * m] = blocks[:, i]
    return out


def assert_close(actual, desired, rtol=1e-9):
    """Elementwise to ``rtol`` relative to the largest entry of each matrix/vector (covariances mix units)."""
    axes = tuple(range(1, desired.ndim))
    err = (np.abs(actual - desired).max(axis=axes) / np.abs(desired).max(axis=axes)).max()
    assert err < rtol, f"relative error {err:.3g} >= {rtol:.3g}"


# 1. time update ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("motion, centre, scales", [
    (CA3D(), np.r_[5000.0, 3000, 1000, -20, 10, 0, 0.5, -0.2, 0], CA_SCALES),
    (CA3D(with_factor=False), np.r_[5000.0, 3000, 1000, -20, 10, 0, 0.5, -0.2, 0], CA_SCALES),
    (ConstantAcceleration3D(sigma_w=0.05), np.r_[5000.0, 3000, 1000, -20, 10, 0, 0.5, -0.2, 0], CA_SCALES),
    (ManeuveringCV3D(), np.r_[10.0, -20, 5, 2, 1, 1.5], [5.0] * 3 + [1.0] * 3),
])
def test_time_update_equals_ckf(motion, centre, scales):
    """S- = Tria([Xcal*, S_Q]) gives the CKF's predicted moments, with the rank-3 factor of the CA plant, with
    its singular Q alone (eigen square root), with the package's ca9 plant and on the nonlinear paper 0 plant
    with full-rank Q."""
    rng = np.random.default_rng(7)
    prior = prior_near(rng, 6, centre, scales)
    srcif = SquareRootCubatureInformationFilter(motion, BearingModel())
    ckf = cubature_kalman_filter(motion, BearingModel())
    got, ref = srcif.predict(prior), ckf.predict(prior)
    assert_close(got.mean, ref.mean)
    assert_close(got.cov, ref.cov)
    assert is_spd(got.cov).all()


def test_tria_and_sqrt_factor():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(4, 5, 12))
    s = tria(a)
    np.testing.assert_allclose(s, np.linalg.cholesky(a @ np.swapaxes(a, -1, -2)), rtol=1e-10, atol=1e-12)
    s_short = tria(a[..., :3])  # fewer columns than rows: rank-deficient, still S S^T = A A^T
    np.testing.assert_allclose(s_short @ np.swapaxes(s_short, -1, -2), a[..., :3] @ np.swapaxes(a[..., :3], -1, -2),
                               atol=1e-12)
    cov = random_spd(rng, 3, 4, [1.0] * 4)
    cov[1] = -np.eye(4)  # not positive definite: floored eigen square root, the others still their Cholesky
    cov[2, 0, 0] = np.nan  # not finite: NaN factor (the simulator's divergence guard flags it)
    f = sqrt_factor(cov)
    np.testing.assert_allclose(f[0], np.linalg.cholesky(cov[0]), rtol=1e-10)
    assert np.all(np.isfinite(f[1])) and np.all(np.diag(f[1]) > 0) and np.all(np.isnan(f[2]))


# 2. linear measurements ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_sens", [1, 3])
def test_point_update_equals_ckf_and_kalman(n_sens):
    rng = np.random.default_rng(11 + n_sens)
    motion, meas = CA3D(), PointModel()
    b = 5
    prior = prior_near(rng, b, np.r_[5000.0, 3000, 1000, -20, 10, 0, 0.5, -0.2, 0], CA_SCALES)
    sensors = rng.normal(0, 1000, (b, n_sens, 3))
    blocks = random_spd(rng, b * n_sens, 3, [30.0, 20.0, 10.0]).reshape(b, n_sens, 3, 3)
    blocks *= rng.uniform(0.1, 10.0, (b, n_sens, 1, 1))  # each sensor its own noise level
    r = block_diag_noise(blocks)
    z = np.tile(prior.mean[:, :3], n_sens) + rng.normal(0, 50, (b, 3 * n_sens))
    got = SquareRootCubatureInformationFilter(motion, meas).update(prior, z, sensors, r)
    ckf = cubature_kalman_filter(motion, meas).update(prior, z, sensors, r)
    h = np.tile(np.eye(3, 9), (n_sens, 1))
    p = prior.cov
    s = h @ p @ h.T + r
    k = p @ h.T @ np.linalg.inv(s)
    kf_mean = prior.mean + mat_vec(k, z - mat_vec(h, prior.mean))
    kf_cov = p - k @ s @ np.swapaxes(k, -1, -2)
    for ref_mean, ref_cov in ((ckf.mean, ckf.cov), (kf_mean, kf_cov)):
        assert_close(got.mean, ref_mean)
        assert_close(got.cov, ref_cov)
    shared = SquareRootCubatureInformationFilter(motion, meas).update(prior, z, sensors, r[0])  # (S*m, S*m) noise
    ref_shared = cubature_kalman_filter(motion, meas).update(prior, z, sensors, r[0])
    assert_close(shared.mean, ref_shared.mean)
    assert_close(shared.cov, ref_shared.cov)


# 3. bearing measurements --------------------------------------------------------------------------------------


def statistically_linearised_update(prior, z, sensors, noise_cov, meas=BearingModel()):
    """The SRCIF's covariance-form twin: cubature moments, H = P_xz^T P^-1, Pzz = H P H^T + R (not the sampled
    Pzz of the CKF), K = P_xz Pzz^-1, x+ = x + K nu, P+ = P - K Pzz K^T (angles averaged as in the CKF)."""
    pts_set = cubature_points(prior.mean.shape[1])
    pts = sigma_points(prior, pts_set)
    b, p, n = pts.shape
    zs = meas.h(pts.reshape(b * p, n), np.repeat(sensors, p, axis=0)).reshape(b, p, -1)
    ref = meas.h(prior.mean, sensors)
    z_mean = ref + np.einsum("p,bpm->bm", pts_set.wm, meas.residual(zs, ref[:, None, :]))
    dz = meas.residual(zs, z_mean[:, None, :])
    cross = weighted_cov(pts_set.wc, pts - prior.mean[:, None, :], dz)
    h = np.swapaxes(np.linalg.solve(prior.cov, cross), -1, -2)
    pzz = h @ prior.cov @ np.swapaxes(h, -1, -2) + noise_cov
    gain = cross @ np.linalg.inv(pzz)
    mean = prior.mean + mat_vec(gain, meas.residual(z, z_mean))
    return GaussianState(mean, prior.cov - gain @ pzz @ np.swapaxes(gain, -1, -2))


def bearing_case(rng, b, n_sens):
    """A CA target about 6 km from sensors spread over a few km, each sensor 0.1 or 0.5 deg."""
    target = np.r_[5000.0, 3000, 1000, -20, 10, 0, 0.5, -0.2, 0]
    prior = prior_near(rng, b, target, CA_SCALES)
    sensors = rng.uniform(-2000, 2000, (b, n_sens, 3)) * np.r_[1.0, 1.0, 0.1]
    sigma = rng.choice([0.1 * DEG, 0.5 * DEG], (b, n_sens))
    r = block_diag_noise(sigma[..., None, None] ** 2 * np.eye(2))
    truth = prior.mean + mat_vec(np.linalg.cholesky(prior.cov), rng.normal(size=(b, 9)))
    z = wrap_angle(BearingModel().h(truth, sensors) + np.repeat(sigma, 2, axis=1) * rng.normal(size=(b, 2 * n_sens)))
    return prior, z, sensors, r


@pytest.mark.parametrize("n_sens", [1, 4])
def test_bearing_update_equals_its_covariance_form_twin(n_sens):
    rng = np.random.default_rng(23 + n_sens)
    prior, z, sensors, r = bearing_case(rng, 6, n_sens)
    got = SquareRootCubatureInformationFilter(CA3D(), BearingModel()).update(prior, z, sensors, r)
    twin = statistically_linearised_update(prior, z, sensors, r)
    assert_close(got.mean, twin.mean)
    assert_close(got.cov, twin.cov)
    assert is_spd(got.cov).all()
    # not the CKF: its sampled Pzz exceeds H P H^T + R by what H does not explain, so it is less confident
    ckf = cubature_kalman_filter(CA3D(), BearingModel()).update(prior, z, sensors, r)
    gap = np.abs(ckf.cov - got.cov).max() / np.abs(ckf.cov).max()
    assert gap > 1e-6
    excess = np.linalg.eigvalsh(ckf.cov - got.cov)  # P_ckf - P_srcif is positive semidefinite
    assert np.all(excess[:, 0] > -1e-9 * np.abs(ckf.cov).max()) and np.all(excess[:, -1] > 0)


# 4. contributions add ------------------------------------------------------------------------------------------


def test_stacked_sensors_add_their_information_contributions():
    """Y after [a, b] = Y- + I_a + I_b with I_a, I_b from single-sensor updates of the same prior (and y alike)."""
    rng = np.random.default_rng(5)
    prior, z, sensors, r = bearing_case(rng, 4, 3)
    filt = SquareRootCubatureInformationFilter(CA3D(), BearingModel())

    def info(state):
        y_mat = np.linalg.inv(state.cov)
        return y_mat, mat_vec(y_mat, state.mean)

    both = filt.update(prior, z, sensors, r)
    only_a = filt.update(prior, z[:, :2], sensors[:, :1], r[:, :2, :2])
    only_b = filt.update(prior, z[:, 2:], sensors[:, 1:], r[:, 2:, 2:])  # b: the other two sensors
    (y_ab, v_ab), (y_a, v_a), (y_b, v_b), (y0, v0) = (info(s) for s in (both, only_a, only_b, prior))
    assert_close(y_ab, y_a + y_b - y0, rtol=1e-8)
    assert_close(v_ab, v_a + v_b - v0, rtol=1e-8)
    contrib = filt.contributions(prior, z, sensors, r)
    assert contrib.matrix.shape == (4, 3, 9, 9) and contrib.vector.shape == (4, 3, 9)
    assert_close(y0 + contrib.matrix.sum(axis=1), y_ab, rtol=1e-8)
    assert_close(v0 + contrib.vector.sum(axis=1), v_ab, rtol=1e-8)
    # each I_s is H_s^T R_s^-1 H_s with H_s = P_xz,s^T Y-: symmetric, positive semidefinite, rank m = 2
    eig = np.linalg.eigvalsh(contrib.matrix)
    assert np.all(eig[..., :-2] < 1e-9 * eig[..., -1:]) and np.all(eig[..., -2:] > 0)


# 5. padded sensors -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("meas", [BearingModel(), PointModel()])
def test_padded_sensor_changes_nothing(meas):
    rng = np.random.default_rng(9)
    prior, _, sensors, r_bearing = bearing_case(rng, 5, 2)
    m = meas.dim
    r = r_bearing if m == 2 else block_diag_noise(np.broadcast_to(25.0 * np.eye(3), (5, 2, 3, 3)))
    z = meas.h(prior.mean + rng.normal(0, 30, prior.mean.shape), sensors)
    filt = SquareRootCubatureInformationFilter(CA3D(), meas)
    ref = filt.update(prior, z, sensors, r)
    padded_r = np.zeros((5, 3 * m, 3 * m))
    padded_r[:, : 2 * m, : 2 * m] = r
    padded_r[:, 2 * m :, 2 * m :] = 1e16 * np.eye(m)
    padded_sensors = np.concatenate([sensors, np.zeros((5, 1, 3))], axis=1)  # pose of the padding: the origin
    got = filt.update(prior, np.concatenate([z, np.zeros((5, m))], axis=1), padded_sensors, padded_r)
    assert_close(got.mean, ref.mean)
    assert_close(got.cov, ref.cov)
    alone = filt.update(prior, np.zeros((5, m)), np.zeros((5, 1, 3)), 1e16 * np.eye(m)[None])  # only padding
    assert_close(alone.mean, prior.mean)
    assert_close(alone.cov, prior.cov)
    none = filt.update(prior, np.zeros((5, 0)), np.zeros((5, 0, 3)), np.zeros((5, 0, 0)))  # no scan at all
    np.testing.assert_array_equal(none.mean, prior.mean)
    np.testing.assert_array_equal(none.cov, prior.cov)


# 6. a long bearing-only run --------------------------------------------------------------------------------------


def bearing_only_run(runs=20, steps=400, noise_scale=1.0, seed=2024):
    """A CA target (sigma_w 0.5 m/s^2, T 0.5 s) ~6 km away, seen by 4 UAVs on circular orbits, each 0.1 or
    0.5 deg; the filter assumes ``noise_scale`` times the true bearing variance. Returns the NEES ``(steps, runs)``
    and whether every posterior and prior was SPD."""
    rng = np.random.default_rng(seed)
    motion, meas = CA3D(), BearingModel()
    filt = SquareRootCubatureInformationFilter(motion, meas)
    n_sens, ts = 4, motion.ts
    sigma = np.array([0.1, 0.5, 0.1, 0.5]) * DEG
    r_true = block_diag_noise(np.broadcast_to(sigma[:, None, None] ** 2 * np.eye(2), (1, 4, 2, 2)))[0]
    centres = np.array([[0.0, 0, 500], [1500, -1000, 800], [-1000, 1500, 600], [500, 2000, 700]])
    phase = rng.uniform(0, 2 * np.pi, (runs, n_sens))
    x0 = np.r_[6000.0, 3000, 1500, -25, 10, 0, 0.2, -0.1, 0]
    p0 = np.diag(np.square(CA_SCALES))
    truth = x0 + rng.normal(size=(runs, 9)) * np.sqrt(np.diag(p0))
    state = filt.initial_state(np.broadcast_to(x0, (runs, 9)), p0)
    nees = np.empty((steps, runs))
    spd = True
    for k in range(steps):
        ang = phase + 0.02 * k * ts  # 300 m orbits at 6 m/s
        sensors = centres + 300.0 * np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=-1)
        z = wrap_angle(meas.h(truth, sensors) + rng.normal(size=(runs, 2 * n_sens)) * np.repeat(sigma, 2))
        state = filt.update(state, z, sensors, noise_scale * r_true)
        err = truth - state.mean
        nees[k] = np.einsum("bi,bi->b", err, np.linalg.solve(state.cov, err[..., None])[..., 0])
        spd &= bool(is_spd(state.cov).all())
        state = filt.predict(state)
        spd &= bool(is_spd(state.cov).all())
        truth = truth @ motion.A.T + rng.normal(0, 0.5, (runs, 3)) @ motion.G.T
    return nees, spd


#: the average NEES of a consistent 9-state filter is 9; the band is tight enough to catch a 3x noise mistuning
ANEES_BAND = (9.0 / 1.5, 9.0 * 1.5)


def test_long_bearing_only_run_stays_spd_and_consistent():
    """400 steps, 12 runs: every prior and posterior SPD, NEES averaged over the last 200 steps near 9
    (about 8.7 with this seed)."""
    nees, spd = bearing_only_run(runs=12)
    assert spd
    anees = nees[200:].mean()
    assert ANEES_BAND[0] < anees < ANEES_BAND[1], anees


@pytest.mark.parametrize("noise_scale", [0.01, 0.3])
def test_consistency_band_catches_a_mistuned_filter(noise_scale):
    """The band of the test above can fail: the same run with the bearing variance understated 100x (ANEES in
    the hundreds) or only 3.3x (about 19) falls outside it."""
    nees, _ = bearing_only_run(runs=8, steps=240, noise_scale=noise_scale)
    assert nees[200:].mean() > ANEES_BAND[1]


def test_runs_in_the_simulator_like_the_ckf(exp2_small):
    """Paper 0 Experiment 2 through the batched simulator (shared (S*m, S*m) noise, CI diffusion): no
    divergence, SPD, and the position RMSE of the CKF within a few percent (bearing noise is small there)."""
    for arch in "cd":
        res, ref = run_filter(exp2_small, f"{arch}srcif"), run_filter(exp2_small, f"{arch}ckf")
        assert (res.diverged_at < 0).all()
        assert is_spd(res.cov.reshape((-1, 6, 6))).all()
        rmse = [np.sqrt((r.errors(exp2_small)[..., :3] ** 2).sum(-1).mean()) for r in (res, ref)]
        assert abs(rmse[0] - rmse[1]) < 0.05 * rmse[1], rmse


# 7. registry -----------------------------------------------------------------------------------------------------


def test_registry_builds_srcif_and_rejects_unknown_params():
    motion, meas = CA3D(), BearingModel()
    ctx = FilterContext(motion, meas, np.eye(9))
    filt = FILTER_REGISTRY.create("srcif", {}, ctx)
    assert isinstance(filt, SquareRootCubatureInformationFilter)
    assert filt.state_dim == filt.kinematic_dim == 9 and filt.name == "srcif"
    assert "srcif" in FILTER_REGISTRY.names()
    with pytest.raises(ValueError, match="has no parameter 'qbar'"):
        FILTER_REGISTRY.create("srcif", {"qbar": 1e-6}, ctx)
    with pytest.raises(ValueError, match="measurement model"):
        FILTER_REGISTRY.create("srcif", {}, FilterContext(motion, None, np.eye(9)))
    wrapped = make_local_filter("srcif", ManeuveringCV3D(), meas, np.eye(6), 1.0, qbar=1e-5, theta=None)
    assert isinstance(wrapped, SquareRootCubatureInformationFilter) and wrapped.state_dim == 6
