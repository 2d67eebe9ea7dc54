"""Measurement models: Jacobians against finite differences, angle wrapping, small inverses."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from zentrack.fusion.linalg import small_inverse
from zentrack.fusion.measurement import BearingModel, LinearModel, PointModel, bearing, bearing_jacobian, wrap_angle

coords = st.floats(-500, 500, allow_nan=False)


def finite_difference(fn, x, eps=1e-6):
    cols = []
    for j in range(x.shape[1]):
        dx = np.zeros_like(x)
        dx[:, j] = eps
        cols.append(wrap_angle(fn(x + dx) - fn(x - dx)) / (2 * eps))
    return np.stack(cols, axis=-1)


@settings(max_examples=200, deadline=None)
@given(st.lists(coords, min_size=6, max_size=6), st.lists(coords, min_size=3, max_size=3))
def test_bearing_jacobian_matches_finite_differences(xs, ss):
    x = np.array([xs])
    sensors = np.array([[ss]])
    d = x[0, :3] - sensors[0, 0]
    if np.hypot(d[0], d[1]) < 1.0:  # the elevation is singular straight above the sensor
        return
    fd = finite_difference(lambda v: bearing(v, sensors), x)
    jac = bearing_jacobian(x, sensors)
    scale = 1.0 / np.hypot(d[0], d[1])
    np.testing.assert_allclose(jac, fd, atol=1e-6 * scale + 1e-9, rtol=1e-5)
    assert np.all(jac[..., 3:] == 0.0)


def test_bearing_jacobian_several_sensors_and_padding(rng):
    x = rng.normal(0, 100, (4, 6))
    sensors = rng.normal(0, 300, (4, 3, 3))
    z, jac = BearingModel().linearize(x, sensors, n_state=12)
    assert z.shape == (4, 6) and jac.shape == (4, 6, 12)
    np.testing.assert_array_equal(jac[..., :6], bearing_jacobian(x, sensors))
    assert np.all(jac[..., 6:] == 0.0)
    np.testing.assert_allclose(z, bearing(x, sensors))


def test_point_and_linear_jacobians(rng):
    x = rng.normal(size=(3, 6))
    sensors = np.zeros((3, 2, 3))
    for model in (PointModel(), LinearModel(np.array([[1.0, 0, 0, 0, 0, 0], [0, 0, 2.0, 0, 0, 0]]))):
        fd = finite_difference(lambda v, model=model: model.h(v, sensors), x)
        np.testing.assert_allclose(model.jacobian(x, sensors), fd, atol=1e-8)


def test_wrap_angle_is_half_open_interval():
    assert wrap_angle(np.array(np.pi)) == np.pi
    assert wrap_angle(np.array(-np.pi)) == np.pi
    np.testing.assert_allclose(wrap_angle(np.array([3 * np.pi / 2, -3 * np.pi / 2, 7.0])), [-np.pi / 2, np.pi / 2, 7.0 - 2 * np.pi])


def test_residual_wraps_across_pi_only_for_angles():
    z = np.array([[np.pi - 0.01, 0.2]])
    z_pred = np.array([[-np.pi + 0.01, 0.1]])
    np.testing.assert_allclose(BearingModel().residual(z, z_pred), [[-0.02, 0.1]], atol=1e-12)
    np.testing.assert_allclose(PointModel().residual(z, z_pred), z - z_pred)


@given(st.integers(1, 4), st.integers(1, 30))
def test_small_inverse_matches_lapack(m, b):
    rng = np.random.default_rng(m * 100 + b)
    a = rng.normal(size=(b, m, m))
    s = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(m)
    np.testing.assert_allclose(small_inverse(s), np.linalg.inv(s), rtol=1e-8, atol=1e-10)
