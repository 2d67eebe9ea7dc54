"""Paper 4 extended-object geometry, metrics, truth path, point sampling and network placement."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from zentrack.fusion.extent import (
    acee,
    ellipse_outline,
    gaussian_wasserstein,
    rectangle_corners,
    rectangle_outline,
    shape_factor,
    shape_matrix,
    sqrtm_2x2,
)
from zentrack.fusion.graphs import is_connected, radius_adjacency
from zentrack.truth.simulation.eot_scenario import place_network, s2_trajectory, sample_extent_points


def random_ellipses(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    m = rng.normal(scale=50.0, size=(n, 2))
    p = np.column_stack([rng.uniform(-np.pi, np.pi, n), rng.uniform(1.0, 200.0, n), rng.uniform(1.0, 60.0, n)])
    return m, p


def gw_reference(m_a, p_a, m_b, p_b) -> float:
    xa, xb = shape_matrix(p_a), shape_matrix(p_b)
    ra = np.real(scipy.linalg.sqrtm(xa))
    inner = np.real(scipy.linalg.sqrtm(ra @ xb @ ra))
    return float(np.sqrt(np.sum((m_a - m_b) ** 2) + np.trace(xa + xb - 2.0 * inner)))


# ---------------------------------------------------------------------------------------------- geometry


def test_shape_matrix_eigen_structure():
    rng = np.random.default_rng(0)
    _, p = random_ellipses(rng, 20)
    x = shape_matrix(p)
    assert x.shape == (20, 2, 2)
    np.testing.assert_allclose(x, np.swapaxes(x, -1, -2))
    np.testing.assert_allclose(np.linalg.det(x), (p[:, 1] * p[:, 2]) ** 2, rtol=1e-9)
    np.testing.assert_allclose(np.trace(x, axis1=1, axis2=2), p[:, 1] ** 2 + p[:, 2] ** 2, rtol=1e-12)
    # the first semi-axis points along alpha
    axis = np.column_stack([np.cos(p[:, 0]), np.sin(p[:, 0])])
    np.testing.assert_allclose(np.einsum("nij,nj->ni", x, axis), axis * p[:, 1:2] ** 2, rtol=1e-9, atol=1e-9)


def test_sqrtm_2x2_matches_scipy():
    rng = np.random.default_rng(1)
    _, p = random_ellipses(rng, 10)
    x = shape_matrix(p)
    r = sqrtm_2x2(x)
    for xi, ri in zip(x, r):
        np.testing.assert_allclose(ri, np.real(scipy.linalg.sqrtm(xi)), rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(sqrtm_2x2(np.zeros((2, 2))), 0.0)


def test_gw_zero_for_equal_ellipses():
    rng = np.random.default_rng(2)
    m, p = random_ellipses(rng, 50)
    np.testing.assert_allclose(gaussian_wasserstein(m, p, m, p), 0.0, atol=1e-5)
    np.testing.assert_allclose(gaussian_wasserstein(m, p, m, p, squared=True), 0.0, atol=1e-9)


def test_gw_symmetric_and_matches_sqrtm_reference():
    rng = np.random.default_rng(3)
    m_a, p_a = random_ellipses(rng, 40)
    m_b, p_b = random_ellipses(rng, 40)
    d_ab = gaussian_wasserstein(m_a, p_a, m_b, p_b)
    np.testing.assert_allclose(d_ab, gaussian_wasserstein(m_b, p_b, m_a, p_a), rtol=1e-10)
    ref = [gw_reference(*args) for args in zip(m_a, p_a, m_b, p_b)]
    np.testing.assert_allclose(d_ab, ref, rtol=1e-7)
    np.testing.assert_allclose(gaussian_wasserstein(m_a, p_a, m_b, p_b, squared=True), d_ab**2, rtol=1e-12)


def test_gw_shift_of_equal_shapes_is_centre_distance():
    rng = np.random.default_rng(4)
    m, p = random_ellipses(rng, 30)
    dm = rng.normal(scale=20.0, size=(30, 2))
    d2 = gaussian_wasserstein(m, p, m + dm, p, squared=True)
    np.testing.assert_allclose(d2, np.sum(dm**2, axis=-1), rtol=1e-6, atol=1e-6)


def test_gw_invariant_under_half_turn_and_broadcasts():
    rng = np.random.default_rng(5)
    m_a, p_a = random_ellipses(rng, 25)
    m_b, p_b = random_ellipses(rng, 25)
    flipped = p_a + np.array([np.pi, 0.0, 0.0])
    np.testing.assert_allclose(
        gaussian_wasserstein(m_a, flipped, m_b, p_b), gaussian_wasserstein(m_a, p_a, m_b, p_b), rtol=1e-9
    )
    # swapping the axes and rotating by pi/2 is the same ellipse
    swapped = np.column_stack([p_a[:, 0] + np.pi / 2, p_a[:, 2], p_a[:, 1]])
    np.testing.assert_allclose(gaussian_wasserstein(m_a, swapped, m_a, p_a), 0.0, atol=1e-5)
    # batched over leading axes: one reference ellipse against a (5, 5) grid
    grid = gaussian_wasserstein(m_a.reshape(5, 5, 2), p_a.reshape(5, 5, 3), m_b[0], p_b[0])
    assert grid.shape == (5, 5)
    np.testing.assert_allclose(grid.ravel(), gaussian_wasserstein(m_a, p_a, m_b[:1], p_b[:1]))


def test_gw_pure_scaling_of_circles():
    # circles of radii r1, r2 at one centre: W2^2 = 2 (r1 - r2)^2
    d2 = gaussian_wasserstein(np.zeros(2), np.array([0.3, 3.0, 3.0]), np.zeros(2), [1.0, 5.0, 5.0], squared=True)
    assert d2 == pytest.approx(2 * 2.0**2)


def test_rectangle_corners_and_outlines():
    m = np.array([10.0, -5.0])
    p = np.array([np.pi / 2, 4.0, 2.0])
    c = rectangle_corners(m, p)
    assert c.shape == (4, 2)
    np.testing.assert_allclose(c.mean(axis=0), m, atol=1e-12)
    # with alpha = pi/2 the long side (2 * l1) runs along y
    np.testing.assert_allclose(np.ptp(c, axis=0), [4.0, 8.0], atol=1e-12)
    out = rectangle_outline(m, p)
    assert out.shape == (5, 2)
    np.testing.assert_allclose(out[0], out[-1])
    e = ellipse_outline(np.zeros((3, 2)), np.tile(p, (3, 1)), points=33)
    assert e.shape == (3, 33, 2)
    # every outline point satisfies z^T X^-1 z = 1
    xinv = np.linalg.inv(shape_matrix(p))
    np.testing.assert_allclose(np.einsum("...i,ij,...j->...", e, xinv, e), 1.0, rtol=1e-9)


# ---------------------------------------------------------------------------------------------- metrics


def test_acee_definition():
    rng = np.random.default_rng(8)
    est = rng.normal(size=(3, 5, 6, 4))  # runs, steps, nodes, state
    a = acee(est)
    assert a.shape == (3, 5)
    m = est.shape[2]
    brute = np.zeros((3, 5))
    for s in range(m):
        for j in range(m):
            brute += np.linalg.norm(est[:, :, s] - est[:, :, j], axis=-1)
    np.testing.assert_allclose(a, brute / (m * (m - 1)))
    # all nodes agree -> 0, whatever the common estimate
    same = np.broadcast_to(est[:, :, :1], est.shape)
    np.testing.assert_allclose(acee(same), 0.0)
    # two nodes: the distance between them
    np.testing.assert_allclose(acee(est[:, :, :2]), np.linalg.norm(est[:, :, 0] - est[:, :, 1], axis=-1))
    # the node axis can sit elsewhere
    np.testing.assert_allclose(acee(np.moveaxis(est, 2, 0), node_axis=0), a)


# ---------------------------------------------------------------------------------------------- truth path


def test_s2_trajectory_schedule():
    centres, vel, heading = s2_trajectory()
    assert centres.shape == (103, 2) and vel.shape == (103, 2) and heading.shape == (103,)
    np.testing.assert_allclose(centres[0], 0.0)
    np.testing.assert_allclose(heading[:20], -np.pi / 4)
    np.testing.assert_allclose(heading[31:41], 0.0)
    np.testing.assert_allclose(heading[52:72], np.pi / 2)
    np.testing.assert_allclose(heading[83:103], np.pi)
    # turns: 11 samples, linear, both end headings included
    for start, a, b in ((20, -np.pi / 4, 0.0), (41, 0.0, np.pi / 2), (72, np.pi / 2, np.pi)):
        np.testing.assert_allclose(heading[start : start + 11], np.linspace(a, b, 11), atol=1e-12)
    assert np.all(np.diff(heading) >= -1e-12)  # only left turns
    # constant speed 50 km/h, velocity along the heading, m_k = m_{k-1} + T v_k
    speed = np.linalg.norm(vel, axis=-1)
    np.testing.assert_allclose(speed, 500 / 36)
    np.testing.assert_allclose(np.arctan2(vel[:, 1], vel[:, 0]), np.where(np.isclose(heading, np.pi), np.pi, heading))
    np.testing.assert_allclose(np.diff(centres, axis=0), 10.0 * vel[1:], atol=1e-9)


def test_s2_trajectory_options():
    c, v, h = s2_trajectory(steps=30, ts=1.0, speed=2.0, start=(5.0, 6.0))
    full_h = s2_trajectory()[2]
    np.testing.assert_allclose(h, full_h[:30])
    np.testing.assert_allclose(c[0], [5.0, 6.0])
    np.testing.assert_allclose(np.linalg.norm(np.diff(c, axis=0), axis=-1), 2.0)
    c2, _, h2 = s2_trajectory(steps=110)
    assert len(c2) == 110 and np.allclose(h2[103:], np.pi)


# ---------------------------------------------------------------------------------------------- points


@pytest.mark.parametrize(("shape", "ch"), [("ellipse", 0.25), ("rectangle", 1.0 / 3.0)])
def test_sampler_counts_and_spread(shape, ch):
    rng = np.random.default_rng(9)
    n_scans, rate, max_points = 4000, 5.0, 40
    centre = np.array([100.0, -50.0])
    p = np.array([0.6, 17.0, 4.0])
    cv = np.array([[2.0, 0.5], [0.5, 1.0]])
    centres = np.broadcast_to(centre, (n_scans, 2))
    pts, counts = sample_extent_points(rng, centres, p, rate, shape, cv, max_points)
    assert pts.shape == (n_scans, max_points, 2) and counts.shape == (n_scans,)
    # Poisson mean and variance ~ rate (4000 scans: standard error of the mean ~ 0.035)
    assert abs(counts.mean() - rate) < 0.15
    assert abs(counts.var() - rate) < 0.6
    valid = np.arange(max_points) < counts[:, None]
    assert np.all(pts[~valid] == 0.0)
    y = pts[valid]  # ~20000 points
    np.testing.assert_allclose(y.mean(axis=0), centre, atol=0.4)
    s = shape_factor(p)
    expected = ch * s @ s.T + cv
    emp = np.cov(y.T)
    # whitened, the sample covariance of ~20000 points is I up to ~1-2 % (C^h ellipse vs rectangle: 33 %)
    w = np.linalg.inv(np.linalg.cholesky(expected))
    np.testing.assert_allclose(w @ emp @ w.T, np.eye(2), atol=0.05)
    # shape support: without noise every point lies inside the object
    pts0, counts0 = sample_extent_points(rng, centre, np.tile(p, (500, 1)), rate, shape, np.zeros((2, 2)), max_points)
    z = np.einsum("ij,...j->...i", np.linalg.inv(s), pts0 - centre)[np.arange(max_points) < counts0[:, None]]
    if shape == "ellipse":
        assert np.all(np.sum(z**2, axis=-1) <= 1.0 + 1e-9)
    else:
        assert np.all(np.abs(z) <= 1.0 + 1e-9)


def test_sampler_clips_and_is_deterministic():
    args = (np.zeros((7, 3, 2)), np.array([0.0, 2.0, 1.0]), 50.0, "ellipse", np.eye(2), 10)
    pts, counts = sample_extent_points(np.random.default_rng(10), *args)
    assert pts.shape == (7, 3, 10, 2) and counts.shape == (7, 3)
    assert counts.max() == 10
    pts2, counts2 = sample_extent_points(np.random.default_rng(10), *args)
    np.testing.assert_array_equal(pts, pts2)
    np.testing.assert_array_equal(counts, counts2)
    with pytest.raises(ValueError):
        sample_extent_points(np.random.default_rng(0), np.zeros(2), np.ones(3), 1.0, "hexagon", np.eye(2), 3)


# ---------------------------------------------------------------------------------------------- network


def test_place_network_connected_sensors_deterministic():
    centres = s2_trajectory()[0]
    pos, is_sensor, adj = place_network(np.random.default_rng(11), centres)
    assert pos.shape == (20, 2) and is_sensor.shape == (20,) and adj.shape == (20, 20)
    assert is_sensor.dtype == bool and is_sensor.sum() == 6
    assert is_connected(adj)
    np.testing.assert_array_equal(adj, radius_adjacency(pos, 2000.0))
    assert np.all(adj == adj.T) and not adj.diagonal().any()
    # nodes lie around the path (bounding box enlarged by half the link range)
    assert np.all(pos >= centres.min(axis=0) - 1000.0) and np.all(pos <= centres.max(axis=0) + 1000.0)
    # deterministic for a seed, different for another
    pos2, is_sensor2, adj2 = place_network(np.random.default_rng(11), centres)
    np.testing.assert_array_equal(pos, pos2)
    np.testing.assert_array_equal(is_sensor, is_sensor2)
    np.testing.assert_array_equal(adj, adj2)
    assert not np.array_equal(pos, place_network(np.random.default_rng(12), centres)[0])


def test_place_network_sensors_spread_along_path():
    centres = s2_trajectory()[0]
    for seed in range(5):
        pos, is_sensor, _ = place_network(np.random.default_rng(seed), centres)
        # the first anchor is the path start: its nearest node is always a sensor
        assert is_sensor[np.argmin(np.linalg.norm(pos - centres[0], axis=-1))]
        # the last anchor is the path end: at most 5 nodes are taken before it, so one of the 6 nodes
        # nearest to the end is a sensor
        nearest_end = np.argsort(np.linalg.norm(pos - centres[-1], axis=-1))[:6]
        assert is_sensor[nearest_end].any()


def test_place_network_raises_when_impossible():
    centres = s2_trajectory()[0]
    with pytest.raises(ValueError):
        place_network(np.random.default_rng(0), centres, link_range=10.0, tries=5)
    with pytest.raises(ValueError):
        place_network(np.random.default_rng(0), centres, nodes=4, sensors=6)
