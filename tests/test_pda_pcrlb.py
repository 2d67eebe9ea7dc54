"""Paper 1 posterior Cramér–Rao bound: the Kalman closed form without clutter, the information reduction factor
(its closed form without clutter, its Monte Carlo evaluation, monotonicity), bearing sensors adding information."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from zentrack.fusion.measurement import LinearModel
from zentrack.fusion.motion_cd import ContinuousCV3D
from zentrack.study.pcrlb import bound_rmse, information_reduction_factor, measurement_information, pcrlb

H = np.hstack([np.eye(3), np.zeros((3, 3))])


def kalman_covariances(f, q, h_stack, r_stack, p0, steps):
    """Textbook KF posterior covariances (update with every sensor, then predict), independent of the package."""
    out, p = [], p0
    for _ in range(steps):
        info = np.linalg.inv(p) + sum(h.T @ np.linalg.inv(r) @ h for h, r in zip(h_stack, r_stack))
        p = np.linalg.inv(info)
        out.append(p)
        p = f @ p @ f.T + q
    return np.array(out)


def test_pcrlb_equals_the_kalman_covariance_for_a_linear_gaussian_measurement():
    motion = ContinuousCV3D(ts=0.5, q=0.2, em_steps=4)
    truth = motion.simulate(np.zeros(6), 3, 30, np.random.default_rng(0))
    r = np.diag([4.0, 1.0, 9.0])
    p0 = np.diag([100.0, 100, 100, 4, 4, 4])
    sensors = np.zeros((2, 3))  # two position sensors (the linear model ignores the pose)
    bound = pcrlb(truth, sensors, motion.A, motion.Q, p0, r, q2=1.0, measurement=LinearModel(H))
    ref = kalman_covariances(motion.A, motion.Q, [H, H], [r, r], p0, 30)
    np.testing.assert_allclose(bound, ref, rtol=1e-9, atol=1e-12)
    # an IRF q2 scales the measurement information: the KF with R / q2
    half = pcrlb(truth, sensors, motion.A, motion.Q, p0, r, q2=np.array([0.5, 0.25]), measurement=LinearModel(H))
    np.testing.assert_allclose(half, kalman_covariances(motion.A, motion.Q, [H, H], [r / 0.5, r / 0.25], p0, 30),
                               rtol=1e-9, atol=1e-12)
    assert np.all(bound_rmse(half, [0, 1, 2]) > bound_rmse(bound, [0, 1, 2]))
    np.testing.assert_allclose(bound_rmse(bound, [0, 1, 2]), np.sqrt(np.trace(ref[:, :3, :3], axis1=1, axis2=2)))


def test_motion_q_is_the_exact_covariance_of_the_euler_maruyama_truth():
    motion = ContinuousCV3D(ts=1.0, q=0.3, em_steps=5)
    x = motion.euler_maruyama(np.zeros((40_000, 6)), np.random.default_rng(1))
    se = np.sqrt((np.outer(np.diag(motion.Q), np.diag(motion.Q)) + motion.Q**2) / len(x))
    assert np.all(np.abs(np.cov(x.T) - motion.Q) < 4 * se + 1e-15)
    assert np.allclose(ContinuousCV3D(ts=1.0, q=0.3, em_steps=2000).Q, motion.exact_q(), rtol=2e-3)


def test_information_reduction_factor():
    r = np.diag([2e-3, 3e-3]) ** 2
    gamma = 16.0
    # no clutter: closed form P_D F_chi2(m + 2)(gamma), 1 in the limit of a full gate and P_D = 1
    assert information_reduction_factor(1.0, 0.0, r, 1e3) == pytest.approx(1.0)
    assert information_reduction_factor(0.7, 0.0, r, gamma) == pytest.approx(0.7 * chi2.cdf(gamma, 4))
    # the Monte Carlo evaluation agrees with it when the clutter is negligible
    lam_tiny = 1e-6 / np.sqrt(np.linalg.det(r))  # 1e-6 clutter returns per whitened unit area
    mc = information_reduction_factor(0.7, lam_tiny, r, gamma, samples=50_000, rng=2)
    assert mc == pytest.approx(0.7 * chi2.cdf(gamma, 4), rel=0.02)
    # more clutter, less information; in [0, 1]; the density is per rad^2 (whitened by sqrt(det R))
    q = [information_reduction_factor(0.9, lam, r, gamma, samples=20_000, rng=3) for lam in (1e3, 1e4, 1e5)]
    assert 0.9 > q[0] > q[1] > q[2] > 0
    same = information_reduction_factor(0.9, 1e4 * 4, r / 4, gamma, samples=20_000, rng=3)
    assert same == pytest.approx(q[1], rel=1e-12)  # lambda sqrt(det R) is all that matters


def test_bearing_information_adds_over_sensors():
    x = np.array([[1500.0, 1500, 800, 10, -5, 1], [1400.0, 1600, 700, 10, -5, 1]])
    sensors = np.array([[0.0, 0, 0], [3000, 0, 0]])
    r = np.eye(2) * 1e-6
    both = measurement_information(x, sensors, r, q2=np.array([0.5, 1.0]))
    first = measurement_information(x, sensors[:1], r)
    second = measurement_information(x, sensors[1:], r)
    np.testing.assert_allclose(both, 0.5 * first + second, rtol=1e-12)
    one = measurement_information(x[:1], sensors[:1], r)  # one bearing of one state: no range information
    assert np.linalg.matrix_rank(one[:3, :3]) == 2
    assert np.linalg.matrix_rank(measurement_information(x[:1], sensors, r)[:3, :3]) == 3  # two views triangulate
    assert np.all(both[3:, :] == 0)  # bearings carry no direct velocity information
