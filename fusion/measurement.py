"""Measurement models: bearing (azimuth, elevation), Cartesian point, and linear.

Every model offers ``h``, ``jacobian`` and ``linearize`` (both at once, with zero columns padded for
augmented states) and ``residual``.  A model maps a stack of states ``x`` ``(B, n)`` seen by a stack of sensor groups ``sensors`` ``(B, S, 3)`` to
stacked measurements ``(B, S*m)``: one node is ``S = 1``; a centralized filter stacks every sensor
(``S = M``, paper 0 eq. 15).  The Jacobian is ``(B, S*m, n)``; only the position columns are non-zero.
``residual`` wraps angular components to (-pi, pi] (paper 0 eq. 6).
"""
from __future__ import annotations

import math

import numpy as np

Array = np.ndarray


def wrap_angle(a: Array) -> Array:
    """Wrap angles to (-pi, pi] element-wise (paper 0 notation W(.))."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def bearing(x: Array, sensors: Array) -> Array:
    """Azimuth and elevation of positions ``x[..., :3]`` from ``sensors`` (paper 0 eq. 5).

    ``x`` ``(B, n)``, ``sensors`` ``(B, S, 3)`` -> ``(B, S*2)`` ordered ``[az_1, el_1, az_2, el_2, ...]``.
    """
    d = x[:, None, :3] - sensors
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    az = np.arctan2(dy, dx)
    el = np.arctan2(dz, np.hypot(dx, dy))
    return np.stack((az, el), axis=-1).reshape(x.shape[0], -1)


def bearing_jacobian(x: Array, sensors: Array, n_state: int | None = None) -> Array:
    """Closed-form Jacobian of :func:`bearing` (paper 0 eq. 7), ``(B, 2S, n_state)``.

    ``n_state`` (default ``x.shape[1]``) pads zero columns for augmented states (paper 0 eq. 13: C = [H 0 0]).
    """
    return bearing_linearize(x, sensors, n_state)[1]


def bearing_linearize(x: Array, sensors: Array, n_state: int | None = None) -> tuple[Array, Array]:
    """Predicted bearings and their Jacobian from one pass over the geometry (see :func:`bearing_jacobian`)."""
    b = x.shape[0]
    s = sensors.shape[1]
    if b == 1 and s == 1:
        one = _bearing_linearize_one(x, sensors, n_state or x.shape[1])
        if one is not None:
            return one
    d = x[:, None, :3] - sensors
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    rho2 = dx * dx + dy * dy
    rho = np.sqrt(rho2)
    r2 = rho2 + dz * dz
    z = np.empty((b, s, 2))
    z[..., 0] = np.arctan2(dy, dx)
    z[..., 1] = np.arctan2(dz, rho)
    jac = np.zeros((b, s, 2, n_state or x.shape[1]))
    k = -dz / (r2 * rho)
    jac[..., 0, 0] = -dy / rho2
    jac[..., 0, 1] = dx / rho2
    jac[..., 1, 0] = k * dx
    jac[..., 1, 1] = k * dy
    jac[..., 1, 2] = rho / r2
    return z.reshape(b, 2 * s), jac.reshape(b, 2 * s, -1)


def _bearing_linearize_one(x: Array, sensors: Array, n_state: int) -> tuple[Array, Array] | None:
    """:func:`bearing_linearize` for one state and one sensor (a tracker's own scan): the same IEEE operations in
    the same order on Python floats (``math.sqrt`` is correctly rounded like ``np.sqrt``) and the angles from
    ``np.arctan2`` (whose bits differ from ``math.atan2``'s), so the same bits, at a third of the numpy calls.
    None where Python would raise for a division by zero (the target straight above or on the sensor, where
    numpy gives infinities): the stacked code handles it."""
    dx, dy, dz = (x[0, :3] - sensors[0, 0]).tolist()
    rho2 = dx * dx + dy * dy
    rho = math.sqrt(rho2)
    r2 = rho2 + dz * dz
    try:
        k = -dz / (r2 * rho)
        row_az = (-dy / rho2, dx / rho2, 0.0)
        row_el = (k * dx, k * dy, rho / r2)
    except ZeroDivisionError:
        return None
    jac = np.zeros((1, 2, n_state))
    jac[0, 0, :3] = row_az
    jac[0, 1, :3] = row_el
    return np.arctan2(np.array(((dy, dz),)), np.array(((dx, rho),))), jac


class BearingModel:
    """Photoelectric sensor: azimuth/elevation of the target from the sensor position (angles wrap)."""

    name = "bearing"
    dim = 2

    def h(self, x: Array, sensors: Array) -> Array:
        return bearing(x, sensors)

    def jacobian(self, x: Array, sensors: Array, n_state: int | None = None) -> Array:
        return bearing_jacobian(x, sensors, n_state)

    def linearize(self, x: Array, sensors: Array, n_state: int | None = None) -> tuple[Array, Array]:
        return bearing_linearize(x, sensors, n_state)

    def residual(self, z: Array, z_pred: Array) -> Array:
        return wrap_angle(z - z_pred)


class PointModel:
    """Cartesian position measurement ``z = p + v`` (sensor position does not enter)."""

    name = "point"
    dim = 3

    def h(self, x: Array, sensors: Array) -> Array:
        return np.tile(x[:, :3], (1, sensors.shape[1]))

    def jacobian(self, x: Array, sensors: Array, n_state: int | None = None) -> Array:
        b, s = x.shape[0], sensors.shape[1]
        jac = np.zeros((b, s, 3, n_state or x.shape[1]))
        jac[:, :, [0, 1, 2], [0, 1, 2]] = 1.0
        return jac.reshape(b, 3 * s, -1)

    def linearize(self, x: Array, sensors: Array, n_state: int | None = None) -> tuple[Array, Array]:
        return self.h(x, sensors), self.jacobian(x, sensors, n_state)

    def residual(self, z: Array, z_pred: Array) -> Array:
        return z - z_pred


class LinearModel:
    """Linear measurement ``z = H x + v`` with a fixed ``H`` per sensor (paper 0 Experiment 1: H = [1 0])."""

    name = "linear"

    def __init__(self, matrix: Array) -> None:
        self.matrix = np.atleast_2d(np.asarray(matrix, dtype=float))
        self.dim = self.matrix.shape[0]

    def h(self, x: Array, sensors: Array) -> Array:
        n = self.matrix.shape[1]
        return np.tile(x[:, :n] @ self.matrix.T, (1, sensors.shape[1]))

    def jacobian(self, x: Array, sensors: Array, n_state: int | None = None) -> Array:
        b, s = x.shape[0], sensors.shape[1]
        jac = np.zeros((b, s * self.dim, n_state or x.shape[1]))
        jac[:, :, : self.matrix.shape[1]] = np.tile(self.matrix, (s, 1))
        return jac

    def linearize(self, x: Array, sensors: Array, n_state: int | None = None) -> tuple[Array, Array]:
        return self.h(x, sensors), self.jacobian(x, sensors, n_state)

    def residual(self, z: Array, z_pred: Array) -> Array:
        return z - z_pred


MeasurementModel = BearingModel | PointModel | LinearModel
