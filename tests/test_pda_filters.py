"""Paper 1 local filters in clutter: PDA-FPF against the Kalman filter, association probabilities, the flow's
substeps, empty scans, re-seeding from a fused prior, and every comparator tracking a small clutter scenario."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.feedforward import covariance_weighted_fusion
from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext
from zentrack.fusion.filters.pda_common import (
    ClutterFilter,
    ParticleState,
    gate_probability,
    pad_scans,
    particle_moments,
    reseed_cloud,
    summarize,
)
from zentrack.fusion.filters.pda_fpf import PdaFeedbackParticleFilter, pda_fpf_flow
from zentrack.fusion.filters.pdaf_ekf import PdafExtendedKalmanFilter
from zentrack.fusion.linalg import GaussianState, is_spd
from zentrack.fusion.measurement import BearingModel, LinearModel
from zentrack.fusion.motion_cd import ContinuousCV3D
from zentrack.truth.simulation.clutter import ClutterSpec, bearing_windows, generate_clutter_scans

CLUTTER_FILTERS = ("pda-fpf", "pda-pf", "pdaf-ekf", "nn-ekf")


def make(name: str, measurement=None, seed: int = 0, **params) -> ClutterFilter:
    motion = ContinuousCV3D(ts=1.0, q=0.05, em_steps=5)
    ctx = FilterContext(motion, measurement or BearingModel(), np.eye(6), rng=np.random.default_rng(seed))
    filt = FILTER_REGISTRY.create(name, params, ctx)
    assert isinstance(filt, ClutterFilter)
    return filt


def position_model() -> LinearModel:
    return LinearModel(np.hstack([np.eye(3), np.zeros((3, 3))]))


def euler_flow_moments(m, p, h, r, y, steps):
    """The moment map of the constant-gain flow on a linear-Gaussian model (beta = 1), independent of the code:
    per Euler step of size 1/steps, m += dt K (y - H m), P = (I - dt K H / 2) P (I - dt K H / 2)^T."""
    dt = 1.0 / steps
    for _ in range(steps):
        k = p @ h.T @ np.linalg.inv(r)
        m = m + dt * k @ (y - h @ m)
        a = np.eye(len(m)) - 0.5 * dt * k @ h
        p = a @ p @ a.T
    return m, p


def test_fpf_matches_kalman_filter_without_clutter():
    """One return, P_D = 1, no clutter, linear-Gaussian measurement: the FPF posterior is the Kalman posterior up
    to Monte Carlo error of the initial cloud (N = 20000) plus the flow's Euler error (computed, not guessed)."""
    n_part, steps = 20_000, 100
    h = np.hstack([np.eye(3), np.zeros((3, 3))])
    r = np.diag([4.0, 9.0, 1.0])
    m0 = np.array([10.0, -5.0, 3.0, 1.0, 0.0, -1.0])
    a = np.random.default_rng(5).normal(size=(6, 6))
    p0 = a @ a.T / 6 + np.diag([4.0, 6.0, 2.0, 1.0, 1.0, 1.0])  # H P0 H^T comparable to R
    y = np.array([12.0, -9.0, 2.0])
    filt = make("pda-fpf", position_model(), seed=1, particles=n_part, flow_substeps=steps, clutter_density=0.0,
                adaptive_flow=False)  # fixed steps of 1/100, as in the reference moment map
    prior = filt.initial_state(m0[None], p0)
    post = filt.update(prior, y[None, None, :], np.zeros((1, 1, 3)), r)
    assert isinstance(post, ParticleState)
    # exact implementation check: the cloud's moments follow the Euler moment map from its own initial moments
    m_ref, p_ref = euler_flow_moments(prior.mean[0], prior.cov[0], h, r, y, steps)
    np.testing.assert_allclose(post.mean[0], m_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(post.cov[0], p_ref, rtol=1e-8, atol=1e-9)
    # against the Kalman filter
    s = h @ p0 @ h.T + r
    k = p0 @ h.T @ np.linalg.inv(s)
    m_kf, p_kf = m0 + k @ (y - h @ m0), (np.eye(6) - k @ h) @ p0
    m_eu, p_eu = euler_flow_moments(m0, p0, h, r, y, steps)  # discretisation error from the true moments
    se_mean = np.sqrt(np.diag(p0) / n_part)  # the flow contracts deviations, so the prior's SE bounds the mean's
    assert np.all(np.abs(post.mean[0] - m_kf) <= 4 * se_mean + np.abs(m_eu - m_kf) + 1e-12)
    se_cov = np.sqrt((np.outer(np.diag(p0), np.diag(p0)) + p0**2) / n_part)  # SE of a sample covariance entry
    assert np.all(np.abs(post.cov[0] - p_kf) <= 4 * se_cov + np.abs(p_eu - p_kf) + 1e-12)
    assert np.abs(p_eu - p_kf).max() < 0.01 * np.abs(p_kf).max()  # 100 substeps: Euler error below 1 %


@pytest.mark.parametrize("name", ["pda-fpf", "pdaf-ekf", "pda-pf"])
def test_beta_sums_to_one_and_ungated_returns_get_zero(name):
    extra = {"particles": 2000} if name != "pdaf-ekf" else {}
    filt = make(name, position_model(), detection_prob=0.9, clutter_density=1e-3, **extra)
    prior = filt.initial_state(np.zeros((2, 6)), np.diag([1.0, 1, 1, 0.1, 0.1, 0.1]))
    r = np.eye(3)
    returns = [np.array([[0.5, 0.2, -0.3], [1.5, -1.0, 0.5], [40.0, 0.0, 0.0], [0.0, -30.0, 0.0]]),
               np.array([[0.1, 0.1, 0.1], [60.0, 60.0, 60.0]])]
    z, counts = pad_scans(returns, 3)
    z[1, 2:] = 1e6  # padding beyond the count is ignored whatever its value
    filt.update(prior, z, np.zeros((2, 1, 3)), r, counts)
    assoc = filt.last_association
    assert assoc is not None
    np.testing.assert_allclose(assoc.beta.sum(axis=1) + assoc.beta0, 1.0, rtol=1e-12)
    np.testing.assert_array_equal(assoc.gated, [[True, True, False, False], [True, False, False, False]])
    assert np.all(assoc.beta[~assoc.gated] == 0.0)
    assert np.all(assoc.beta[assoc.gated] > 0) and np.all(assoc.beta0 > 0)
    assert assoc.beta[0, 0] > assoc.beta[0, 1]  # the closer return is the likelier


def test_pdaf_betas_match_the_textbook_formula():
    """beta_j = P_D N(nu_j; 0, S) / (lambda (1 - P_D P_G) + sum_i P_D N(nu_i; 0, S)) (Bar-Shalom & Fortmann 6.4)."""
    p_d, lam, gamma = 0.8, 0.01, 9.0
    filt = PdafExtendedKalmanFilter(ContinuousCV3D(), position_model(), gamma, p_d, lam)
    p = np.diag([2.0, 1.0, 3.0, 1.0, 1.0, 1.0])
    ys = np.array([[0.5, 0.5, 0.5], [-1.0, 2.0, 0.0], [3.0, -1.0, 2.0]])
    filt.update(GaussianState(np.zeros((1, 6)), p[None]), ys[None], np.zeros((1, 1, 3)), np.eye(3))
    s = p[:3, :3] + np.eye(3)
    lik = np.exp(-0.5 * np.einsum("jm,mk,jk->j", ys, np.linalg.inv(s), ys)) / np.sqrt(np.linalg.det(2 * np.pi * s))
    d2 = np.einsum("jm,mk,jk->j", ys, np.linalg.inv(s), ys)
    e = np.where(d2 <= gamma, p_d * lik, 0.0)
    b = lam * (1 - p_d * gate_probability(gamma, 3))
    assoc = filt.last_association
    np.testing.assert_allclose(assoc.beta[0], e / (b + e.sum()), rtol=1e-10)
    np.testing.assert_allclose(assoc.beta0[0], b / (b + e.sum()), rtol=1e-10)


def scalar_flow(substeps: int, adaptive: bool, ratio: float):
    """A 1-D measurement of x[0] with prior variance ``ratio`` * R; returns (prior mean, posterior mean and
    variance of x[0])."""
    rng = np.random.default_rng(2)
    model = LinearModel(np.array([[1.0, 0, 0, 0, 0, 0]]))
    cloud = rng.normal(size=(1, 4000, 6)) * np.array([np.sqrt(ratio), 1, 1, 1, 1, 1])
    y = np.array([[[3.0]]])
    moved = pda_fpf_flow(model, cloud, y, np.ones((1, 1)), np.zeros((1, 1, 3)), np.eye(1)[None], substeps, adaptive)
    return cloud[0, :, 0].mean(), moved[0, :, 0].mean(), moved[0, :, 0].var(), cloud[0, :, 0].var()


def test_one_euler_step_overshoots_when_hph_exceeds_r_and_substeps_do_not():
    ratio = 6.0  # H P H^T = 6 R
    m0, m1, v1, v0 = scalar_flow(1, False, ratio)
    assert m1 > 3.0 + 0.5 * (3.0 - m0)  # the mean jumps well past the measurement
    assert v1 > v0  # and the spread grows instead of shrinking
    for substeps, adaptive in ((10, False), (3, True), (10, True)):
        m0, m1, v1, v0 = scalar_flow(substeps, adaptive, ratio)
        assert m0 < m1 < 3.0, (substeps, adaptive)  # towards the measurement, not past it
        assert v1 < v0
        v_kf, m_kf = v0 / (1 + v0), (m0 + v0 * 3.0) / (1 + v0)  # the Kalman posterior (R = 1)
        tol = 0.1 if (substeps, adaptive) == (10, True) else 0.25  # 10 adaptive steps: within 10 % of the KF
        assert abs(v1 / v_kf - 1) < tol and abs((m1 - m0) / (m_kf - m0) - 1) < tol


def test_empty_scan_and_scan_without_gated_returns_leave_the_cloud_untouched():
    filt = make("pda-fpf", particles=300)
    sensors = np.zeros((3, 1, 3))
    prior = filt.predict(filt.initial_state(np.tile([1000.0, 500, 200, 5, 0, 0], (3, 1)), np.diag([25.0] * 3 + [1.0] * 3)))
    az, el = BearingModel().h(prior.mean, sensors)[0]
    z, counts = pad_scans([np.zeros((0, 2)), np.array([[az + 1.0, el]]), np.array([[az, el]])])
    post = filt.update(prior, z, sensors, 1e-6 * np.eye(2), counts)
    assert isinstance(post, ParticleState)
    np.testing.assert_array_equal(post.particles[:2], prior.particles[:2])  # J = 0, and a return far outside the gate
    assert not np.array_equal(post.particles[2], prior.particles[2])  # a gated return moves the cloud
    # a batch whose every scan is empty returns the prior itself
    empty = filt.update(prior, np.zeros((3, 0, 2)), sensors, 1e-6 * np.eye(2), np.zeros(3, dtype=int))
    np.testing.assert_array_equal(empty.particles, prior.particles)


def test_reseeding_moves_the_cloud_onto_the_fused_prior():
    rng = np.random.default_rng(3)
    cloud = np.concatenate([rng.exponential(size=(4, 500, 3)), rng.normal(size=(4, 500, 3)) ** 2], axis=2)
    a = rng.normal(size=(4, 6, 6))
    fused = GaussianState(rng.normal(size=(4, 6)) * 100, a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(6))
    moved = reseed_cloud(cloud, fused.mean, fused.cov)
    mean, cov = particle_moments(moved)
    np.testing.assert_allclose(mean, fused.mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(cov, fused.cov, rtol=1e-9, atol=1e-9)
    # the shape is kept: standardised clouds differ by an orthogonal map only (same sorted Mahalanobis radii)
    def radii(x):
        m, p = particle_moments(x)
        d = x - m[:, None, :]
        return np.sort(np.einsum("bni,bij,bnj->bn", d, np.linalg.inv(p), d), axis=1)
    np.testing.assert_allclose(radii(moved), radii(cloud), rtol=1e-7)
    # through the filter: a ParticleState keeps its cloud's shape, a plain Gaussian is sampled
    filt = make("pda-fpf", particles=500)
    adopted = filt.adopt(fused, summarize(cloud))
    np.testing.assert_allclose(adopted.mean, fused.mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(particle_moments(adopted.particles)[1], fused.cov, rtol=1e-9, atol=1e-9)
    sampled = filt.adopt(fused)
    assert sampled.particles.shape == (4, 500, 6)
    # a degenerate cloud (every particle equal) is re-sampled from the fused prior
    flat = reseed_cloud(np.ones((1, 2000, 6)), fused.mean[:1], fused.cov[:1], rng)
    assert np.all(np.abs(flat.mean(axis=1) - fused.mean[:1]) < 5 * np.sqrt(np.diag(fused.cov[0]) / 2000))


def clutter_scenario(runs: int = 4, steps: int = 25, count: int = 5, seed: int = 11):
    motion = ContinuousCV3D(ts=1.0, q=0.05, em_steps=5)
    sensors = np.array([[0.0, 0, 0], [3000, 0, 0], [0, 3000, 0]])
    truth = motion.simulate(np.array([1500.0, 1500, 800, 10, -5, 1]), runs, steps, np.random.default_rng(seed))
    az, el = bearing_windows(truth, sensors, 0.05)
    r = (2e-3) ** 2 * np.eye(2)
    spec = ClutterSpec(p_d=0.95, mode="fixed", count=count, az_window=az, el_window=el)
    return motion, sensors, truth, r, generate_clutter_scans(truth, sensors, r, spec, seed)


@pytest.mark.parametrize("name", CLUTTER_FILTERS)
def test_comparators_track_a_clutter_scenario(name):
    """Three bearing sensors, 5 clutter returns per scan, P_D = 0.95: each filter's fused track (covariance-weighted
    over the sensors) stays within 6 m of the truth over the last 10 of 25 scans (about 3 m on four seeds tried) (prior: 20 m per axis, 35 m biased)."""
    motion, sensors, truth, r, scans = clutter_scenario()
    runs, steps, m_sens = scans.shape
    p0 = np.diag([20.0**2] * 3 + [2.0**2] * 3)
    ctx = FilterContext(motion, BearingModel(), p0, rng=np.random.default_rng(4))
    params = {"detection_prob": 0.95, **({"particles": 400} if name == "pda-fpf" else {})}
    filt = FILTER_REGISTRY.create(name, params, ctx)
    bias = np.array([10.0, -10, 6, 1, -1, 0.5])
    state = filt.initial_state(np.repeat(truth[:, 0], m_sens, axis=0) + bias, p0)
    sens = np.tile(sensors, (runs, 1))[:, None, :]
    errors = []
    for k in range(steps):
        z, counts = scans.batch(k)
        state = filt.update(state, z, sens, r, counts)
        assert np.all(np.isfinite(state.mean)) and np.all(is_spd(state.cov))
        fused = covariance_weighted_fusion(state.mean.reshape(runs, m_sens, 6), state.cov.reshape(runs, m_sens, 6, 6))
        errors.append(np.linalg.norm(fused.mean[:, :3] - truth[:, k, :3], axis=1))
        state = filt.predict(state)
    rmse = np.sqrt(np.mean(np.square(errors[-10:])))
    assert rmse < 6.0, f"{name}: fused position RMSE over the last 10 scans {rmse:.1f} m"


def test_registry_and_point_target_contract():
    """The clutter filters are registered with their parameters, and accept the plain (B, m) point-target z."""
    assert set(CLUTTER_FILTERS) <= set(FILTER_REGISTRY.names())
    names = {p.name for p in FILTER_REGISTRY.params("pda-fpf")}
    assert {"particles", "flow_substeps", "gate", "detection_prob", "clutter_density"} <= names
    filt = make("pda-fpf", position_model(), particles=200)
    assert isinstance(filt, PdaFeedbackParticleFilter)
    prior = filt.initial_state(np.zeros((2, 6)), np.eye(6))
    post = filt.update(prior, np.ones((2, 3)), np.zeros((2, 1, 3)), np.eye(3))
    assert post.mean.shape == (2, 6) and np.all(post.mean[:, :3] > 0.2)
    with pytest.raises(ValueError, match="particles"):
        FILTER_REGISTRY.create("pda-fpf", {"particles": 1}, FilterContext(ContinuousCV3D(), BearingModel(), np.eye(6)))


@pytest.mark.parametrize("name", CLUTTER_FILTERS)
def test_node_filter_runs_one_tracker_on_scans(name):
    """One tracker: scans with J = 0, 1 and several returns, fusion feedback keeps the particle cloud's shape."""
    from zentrack.fusion.estimates import ParticleEstimate
    from zentrack.fusion.filters.pda_common import make_clutter_node_filter
    from zentrack.fusion.scan import Scan

    motion = ContinuousCV3D(ts=1.0, q=0.05, em_steps=5)
    p0 = np.diag([400.0] * 3 + [4.0] * 3)
    ctx = FilterContext(motion, BearingModel(), p0, rng=np.random.default_rng(0))
    node = make_clutter_node_filter(name, ctx, {"particles": 300} if name.startswith("pda-") else {})
    x0 = np.array([1500.0, 1500, 800, 10, -5, 1])
    est = node.initial(x0)
    pose, r = np.zeros(3), 4e-6 * np.eye(2)
    z = BearingModel().h(x0[None], pose[None, None])[0]
    assert node.update(est, []) is est
    est = node.update(est, [Scan.empty(0, 0, pose, r), Scan.single(0, 0, z, pose, r),
                            Scan(0, 0, np.array([z, z + 0.05, z - 0.3]), pose, r)])
    shared = node.predict(est)
    fused_mean = shared.kinematic().mean + 1.0
    fused = {"state": GaussianState(fused_mean[None, None], (shared.kinematic().cov * 0.5)[None, None])}
    prior = node.from_fused(fused, like=shared)
    np.testing.assert_allclose(prior.kinematic().mean, fused_mean, rtol=1e-9)
    np.testing.assert_allclose(prior.kinematic().cov, fused["state"].cov[0, 0], rtol=1e-8, atol=1e-10)
    assert isinstance(prior, ParticleEstimate) == name.startswith("pda-")
    assert node.from_fused(fused, like=None).kinematic().mean.shape == (6,)
