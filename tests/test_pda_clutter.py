"""Paper 1 clutter scans and fusion centre: detection and clutter statistics, layout, reproducibility, gate volume,
and the covariance-weighted (feed-forward) fusion."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.feedforward import covariance_weighted_fusion
from zentrack.fusion.gate import expected_gate_clutter, gate_volume
from zentrack.fusion.linalg import GaussianState, from_information, to_information
from zentrack.fusion.measurement import bearing, wrap_angle
from zentrack.fusion.motion_cd import ContinuousCV3D
from zentrack.truth.simulation.clutter import ClutterSpec, bearing_windows, generate_clutter_scans

SENSORS = np.array([[0.0, 0, 0], [3000, 0, 0], [0, 3000, 100]])
R_NOISE = np.diag([2e-3, 3e-3]) ** 2


def truth(runs=50, steps=40, seed=0):
    return ContinuousCV3D(ts=1.0, q=0.05).simulate(np.array([1500.0, 1500, 800, 10, -5, 1]), runs, steps,
                                                  np.random.default_rng(seed))


def test_poisson_clutter_and_detection_match_their_rates():
    x = truth()
    az, el = bearing_windows(x, SENSORS, 0.05)
    spec = ClutterSpec(p_d=0.8, mode="poisson", density=300.0, az_window=az, el_window=el)
    scans = generate_clutter_scans(x, SENSORS, R_NOISE, spec, 1)
    detected = scans.target_index >= 0
    n_scans = detected.size  # 50 runs x 40 steps x 3 sensors = 6000
    se = np.sqrt(0.8 * 0.2 / n_scans)
    assert abs(detected.mean() - 0.8) < 4 * se
    clutter = scans.counts - detected  # per sensor: Poisson(lambda * area)
    for i, mean in enumerate(spec.mean_clutter(3)):
        c = clutter[:, :, i].ravel()
        assert abs(c.mean() - mean) < 4 * np.sqrt(mean / c.size)
        assert abs(c.var() / mean - 1) < 0.15  # Poisson: variance = mean
    # the target's return is h(x) + v, v ~ N(0, R); clutter lies in the window
    r_, k_, s_ = np.nonzero(detected)
    z_t = scans.returns[r_, k_, s_, scans.target_index[r_, k_, s_]]
    h = bearing(x[r_, k_], SENSORS[s_][:, None, :])
    err = wrap_angle(z_t - h)
    assert np.all(np.abs(err.mean(axis=0)) < 4 * np.sqrt(np.diag(R_NOISE) / len(err)))
    se_cov = np.sqrt((np.outer(np.diag(R_NOISE), np.diag(R_NOISE)) + R_NOISE**2) / len(err))  # SE per entry
    assert np.all(np.abs(np.cov(err.T) - R_NOISE) < 4 * se_cov)
    j = np.arange(scans.returns.shape[3])
    is_clutter = (j < scans.counts[..., None]) & (j != scans.target_index[..., None])
    for i in range(3):
        c = scans.returns[:, :, i][is_clutter[:, :, i]]
        assert np.all(c[:, 1] >= el[i, 0]) and np.all(c[:, 1] <= el[i, 1])
        az_c = wrap_angle(c[:, 0] - az[i].mean()) + az[i].mean()
        assert np.all(az_c >= az[i, 0] - 1e-12) and np.all(az_c <= az[i, 1] + 1e-12)
        # uniform: the mean is the window centre (SE of a uniform mean: width / sqrt(12 n))
        assert abs(az_c.mean() - az[i].mean()) < 4 * (az[i, 1] - az[i, 0]) / np.sqrt(12 * len(c))
    # padding is zero and the target's slot is uniform over the scan (not always first)
    assert np.all(scans.returns[~(j < scans.counts[..., None])] == 0.0)
    slots = scans.target_index[detected]
    expected_first = np.mean(1.0 / scans.counts[detected])  # P(slot 0) = 1/J for a uniform slot
    assert abs(np.mean(slots == 0) - expected_first) < 4 * np.sqrt(expected_first / len(slots))


def test_fixed_clutter_count_layout_and_reproducibility():
    x = truth(runs=5, steps=10)
    spec = ClutterSpec(p_d=1.0, mode="fixed", count=4, az_window=np.array([0.5, 1.0]), el_window=np.array([0.1, 0.4]))
    scans = generate_clutter_scans(x, SENSORS, R_NOISE, spec, 7)
    assert np.all(scans.counts == 5) and scans.returns.shape == (5, 10, 3, 5, 2)
    one = scans.scan(2, 3, 1)
    np.testing.assert_array_equal(one, scans.returns[2, 3, 1])
    z, counts = scans.batch(3)
    assert z.shape == (15, 5, 2) and counts.shape == (15,)
    np.testing.assert_array_equal(z[2 * 3 + 1], one)  # batch index r * M + i
    # an int seed: run r is the same whatever the number of runs
    fewer = generate_clutter_scans(x[:2], SENSORS, R_NOISE, spec, 7)
    np.testing.assert_array_equal(fewer.returns, scans.returns[:2])
    # P_D = 0 and no clutter: every scan empty
    empty = generate_clutter_scans(x, SENSORS, R_NOISE, ClutterSpec(p_d=0.0), 1)
    assert empty.returns.shape[3] == 0 and np.all(empty.counts == 0) and empty.scan(0, 0, 0).shape == (0, 2)
    with pytest.raises(ValueError, match="mode"):
        ClutterSpec(mode="uniform")


def test_gate_volume_and_expected_clutter_in_the_gate():
    s = np.array([[4e-6, 1e-6], [1e-6, 9e-6]])
    gamma = 9.21
    assert gate_volume(s, gamma) == pytest.approx(np.pi * gamma * np.sqrt(np.linalg.det(s)))
    assert gate_volume(np.eye(3), 4.0) == pytest.approx(4 / 3 * np.pi * 8.0)
    density = 2000.0
    expected = expected_gate_clutter(s, gamma, density)
    # Monte Carlo: uniform clutter in a window around the gate; count those inside it
    rng = np.random.default_rng(3)
    half = 0.02
    n = rng.poisson(density * (2 * half) ** 2, 20_000)
    pts = rng.uniform(-half, half, (n.sum(), 2))
    inside = np.einsum("ni,ij,nj->n", pts, np.linalg.inv(s), pts) <= gamma
    per_scan = np.bincount(np.repeat(np.arange(len(n)), n), weights=inside, minlength=len(n))
    assert abs(per_scan.mean() - expected) < 4 * np.sqrt(expected / len(n))


def test_covariance_weighted_fusion_is_the_information_sum():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(4, 3, 6, 6))
    covs = a @ np.swapaxes(a, -1, -2) + np.eye(6)
    means = rng.normal(size=(4, 3, 6))
    fused = covariance_weighted_fusion(means, covs)
    info = np.linalg.inv(covs).sum(axis=1)
    np.testing.assert_allclose(fused.cov, np.linalg.inv(info), rtol=1e-9)
    np.testing.assert_allclose(fused.mean, np.einsum("rij,rj->ri", fused.cov,
                                                     np.einsum("rsij,rsj->ri", np.linalg.inv(covs), means)), rtol=1e-9)
    # two identical estimates: same mean, half the covariance; eps regularises (P + eps I)
    same = covariance_weighted_fusion(np.stack([means[:, 0]] * 2, 1), np.stack([covs[:, 0]] * 2, 1), eps=0.5)
    np.testing.assert_allclose(same.mean, means[:, 0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(same.cov, (covs[:, 0] + 0.5 * np.eye(6)) / 2, rtol=1e-9)
    # present: a missing sensor is left out; one estimate alone is returned as is
    part = covariance_weighted_fusion(means, covs, present=np.array([True, False, True]))
    ref = from_information(to_information(GaussianState(means[:, [0, 2]].reshape(-1, 6), covs[:, [0, 2]].reshape(-1, 6, 6))))
    assert ref.mean.shape == (8, 6)
    alone = covariance_weighted_fusion(means[:, :1], covs[:, :1])
    np.testing.assert_allclose(alone.cov, covs[:, 0], rtol=1e-9)
    np.testing.assert_allclose(part.cov, np.linalg.inv(np.linalg.inv(covs[:, [0, 2]]).sum(axis=1)), rtol=1e-9)
    with pytest.raises(ValueError, match="no estimate"):
        covariance_weighted_fusion(means, covs, present=np.zeros(3, dtype=bool))
