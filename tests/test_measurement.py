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


def test_one_state_and_sensor_linearize_to_their_row_of_the_stacked_code_bit_for_bit():
    """The tracker's case (one state, one sensor: Python floats and one arctan2 call) against the same row of a
    stack, over scales from centimetres to thousands of kilometres and the degenerate geometries (straight
    above the sensor, on it, NaN) that the stacked code answers with infinities or NaN."""
    rng = np.random.default_rng(9)
    model = BearingModel()
    for i in range(3000):
        n, b = int(rng.choice([3, 6, 12])), 4
        x = rng.standard_normal((b, n)) * 10.0 ** rng.integers(-2, 7)
        sensors = rng.standard_normal((b, 1, 3)) * 10.0 ** rng.integers(-2, 7)
        if i % 10 == 0:
            sensors[:, 0, :2] = x[:, :2]  # straight above (or on) the sensor
            sensors[:, 0, 2] = x[:, 2] * (i % 20 == 0)
        if i % 37 == 0:
            x[:, int(rng.integers(3))] = np.nan
        row = int(rng.integers(b))
        with np.errstate(all="ignore"):
            z_all, jac_all = model.linearize(x, sensors, 12)
            z_one, jac_one = model.linearize(x[row:row + 1], sensors[row:row + 1], 12)
        assert z_one.shape == (1, 2) and jac_one.shape == (1, 2, 12)
        assert np.array_equal(z_one, z_all[row:row + 1], equal_nan=True)
        assert np.array_equal(jac_one, jac_all[row:row + 1], equal_nan=True)
