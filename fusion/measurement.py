"""Measurement models: bearing (azimuth, elevation), Cartesian point, and linear.

A model maps a stack of states ``x`` ``(B, n)`` seen by a stack of sensor groups ``sensors`` ``(B, S, 3)`` to
stacked measurements ``(B, S*m)``: one node is ``S = 1``; a centralized filter stacks every sensor
(``S = M``, seed 000 eq. 15).  The Jacobian is ``(B, S*m, n)``; only the position columns are non-zero.
``residual`` wraps angular components to (-pi, pi] (seed 000 eq. 6).
"""
from __future__ import annotations

import numpy as np

Array = np.ndarray


def wrap_angle(a: Array) -> Array:
    """Wrap angles to (-pi, pi] element-wise (seed 000 notation W(.))."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def bearing(x: Array, sensors: Array) -> Array:
    """Azimuth and elevation of positions ``x[..., :3]`` from ``sensors`` (seed 000 eq. 5).

    ``x`` ``(B, n)``, ``sensors`` ``(B, S, 3)`` -> ``(B, S*2)`` ordered ``[az_1, el_1, az_2, el_2, ...]``.
    """
    d = x[:, None, :3] - sensors
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    az = np.arctan2(dy, dx)
    el = np.arctan2(dz, np.hypot(dx, dy))
    return np.stack((az, el), axis=-1).reshape(x.shape[0], -1)


def bearing_jacobian(x: Array, sensors: Array) -> Array:
    """Closed-form Jacobian of :func:`bearing` with respect to ``x`` (seed 000 eq. 7), ``(B, 2S, n)``."""
    b, n = x.shape
    s = sensors.shape[1]
    d = x[:, None, :3] - sensors
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    rho2 = dx * dx + dy * dy
    rho = np.sqrt(rho2)
    r2 = rho2 + dz * dz
    k = -dz / (r2 * rho)
    zero = np.zeros_like(dx)
    rows = [-dy / rho2, dx / rho2, zero, k * dx, k * dy, rho / r2]  # eq. 7, position columns
    jac = np.zeros((b, s, 2, n))
    jac[..., :3] = np.stack(rows, axis=-1).reshape(b, s, 2, 3)
    return jac.reshape(b, 2 * s, n)


class BearingModel:
    """Photoelectric sensor: azimuth/elevation of the target from the sensor position (angles wrap)."""

    name = "bearing"
    dim = 2

    def h(self, x: Array, sensors: Array) -> Array:
        return bearing(x, sensors)

    def jacobian(self, x: Array, sensors: Array) -> Array:
        return bearing_jacobian(x, sensors)

    def residual(self, z: Array, z_pred: Array) -> Array:
        return wrap_angle(z - z_pred)


class PointModel:
    """Cartesian position measurement ``z = p + v`` (sensor position does not enter)."""

    name = "point"
    dim = 3

    def h(self, x: Array, sensors: Array) -> Array:
        return np.tile(x[:, :3], (1, sensors.shape[1]))

    def jacobian(self, x: Array, sensors: Array) -> Array:
        b, n = x.shape
        s = sensors.shape[1]
        jac = np.zeros((b, s, 3, n))
        jac[:, :, [0, 1, 2], [0, 1, 2]] = 1.0
        return jac.reshape(b, 3 * s, n)

    def residual(self, z: Array, z_pred: Array) -> Array:
        return z - z_pred


class LinearModel:
    """Linear measurement ``z = H x + v`` with a fixed ``H`` per sensor (seed 000 Experiment 1: H = [1 0])."""

    name = "linear"

    def __init__(self, matrix: Array) -> None:
        self.matrix = np.atleast_2d(np.asarray(matrix, dtype=float))
        self.dim = self.matrix.shape[0]

    def h(self, x: Array, sensors: Array) -> Array:
        n = self.matrix.shape[1]
        return np.tile(x[:, :n] @ self.matrix.T, (1, sensors.shape[1]))

    def jacobian(self, x: Array, sensors: Array) -> Array:
        b, n = x.shape
        s = sensors.shape[1]
        jac = np.zeros((b, s * self.dim, n))
        jac[:, :, : self.matrix.shape[1]] = np.tile(self.matrix, (s, 1))
        return jac

    def residual(self, z: Array, z_pred: Array) -> Array:
        return z - z_pred


MeasurementModel = BearingModel | PointModel | LinearModel
