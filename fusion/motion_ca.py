"""Constant-acceleration target of paper 2 (DCE-ICI, Section 2.1): 9 states, white acceleration increments.

Per axis ``[p, v, a]+ = F1 [p, v, a] + G1 w``, ``F1 = [[1, T, T^2/2], [0, 1, T], [0, 0, 1]]``,
``G1 = [T^2/2, T, 1]^T``, ``w ~ N(0, sigma_w^2)`` (the seed's model; the notes order the state per axis).
zentrack orders the state ``[x, y, z, vx, vy, vz, ax, ay, az]`` (positions first, as every measurement model
and metric of the package reads ``x[:3]`` as the position and ``x[3:6]`` as the velocity); the model is the
same up to that permutation.

``Q = sigma_w^2 G G^T`` has rank 3, so the model also offers ``noise_factor`` (``G sigma_w``, 9 x 3): the
truth draws its process noise through it and square-root filters use it as the square root of ``Q``.

A manoeuvre schedule (the seed's second scenario: piecewise-constant acceleration over 0-50, 50-100 and
100-200 s) is a property of the truth, not of the model: :func:`apply_acceleration_schedule` sets the
acceleration components at each step before the model propagates them.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Array = np.ndarray


class ConstantAcceleration3D:
    """3-D constant acceleration with white acceleration increments of standard deviation ``sigma_w``.

    Exposes the attributes of :data:`~zentrack.fusion.motion.MotionModel`; it has no lumped term
    (``lumped_dim = 0``), so extended-state filters do not apply to it.
    """

    name = "ca9"
    dim = 9
    lumped_dim = 0

    def __init__(self, ts: float = 0.5, sigma_w: float = 0.1) -> None:
        if not (np.isfinite(ts) and ts != 0) or not sigma_w >= 0:  # (ts < 0 predicts back: models.plant_over)
            raise ValueError(f"need ts finite and not 0, and sigma_w >= 0, got {ts}, {sigma_w}")
        self.ts = float(ts)
        self.sigma_w = float(sigma_w)
        eye = np.eye(3)
        t = self.ts
        self.A = np.block([[eye, t * eye, 0.5 * t * t * eye], [0 * eye, eye, t * eye], [0 * eye, 0 * eye, eye]])
        self.B = np.zeros((9, 0))
        self.G = np.vstack([0.5 * t * t * eye, t * eye, eye])  # (9, 3): one acceleration increment per axis
        self.noise_factor = self.sigma_w * self.G
        self.Q = self.noise_factor @ self.noise_factor.T

    def lumped_nominal(self, x: Array) -> None:
        return None

    def true_lumped(self, x: Array, k: int) -> Array:
        return np.zeros((x.shape[0], 0))

    def f(self, x: Array) -> Array:
        return x @ self.A.T

    def jacobian(self, x: Array) -> Array:
        return np.broadcast_to(self.A, (x.shape[0], 9, 9)).copy()


def acceleration_at(schedule: Sequence[tuple[float, Sequence[float]]], t: float) -> Array | None:
    """The scheduled acceleration at time ``t`` (the last segment started at or before ``t``), or None."""
    current = None
    for start, accel in schedule:
        if t + 1e-9 >= start:
            current = np.asarray(accel, dtype=float)
    return current


def apply_acceleration_schedule(x: Array, schedule: Sequence[tuple[float, Sequence[float]]], t: float) -> Array:
    """``x`` ``(B, 9)`` with its acceleration set to the schedule's value at ``t`` (a copy; unchanged if none)."""
    accel = acceleration_at(schedule, t)
    if accel is None:
        return x
    out = x.copy()
    out[:, 6:9] = accel
    return out
