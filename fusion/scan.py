"""Scans: what one sensor reported at one step.

A :class:`Scan` holds every return of one look of one sensor: ``returns`` ``(J, m)`` (J = 0 is a look that
saw nothing, which differs from no scan at all: a missing scan is absent, ``None`` or simply not in the
list), the sensor ``pose`` ``(3,)`` (its position; the measurement models take it as the ``sensors`` row),
and the measurement noise covariance ``(m, m)`` of each return.  Point-target filters use J = 1 (paper 0);
clutter filters (paper 1) take every return; extended-object filters (paper 4) many returns of one target.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .linalg import is_spd

Array = np.ndarray


@dataclass(frozen=True)
class Scan:
    """One look of sensor ``sensor`` at step ``step``: ``returns`` ``(J, m)``, ``pose`` ``(3,)``, ``noise_cov`` ``(m, m)``."""

    step: int
    sensor: int
    returns: Array
    pose: Array
    noise_cov: Array

    def __post_init__(self) -> None:
        for key in ("returns", "pose", "noise_cov"):
            object.__setattr__(self, key, np.asarray(getattr(self, key), dtype=float))

    @classmethod
    def single(cls, step: int, sensor: int, z: Array, pose: Array, noise_cov: Array) -> Scan:
        """A scan with one return ``z`` ``(m,)`` (J = 1)."""
        return cls(step, sensor, np.asarray(z, dtype=float)[None, :], pose, noise_cov)

    @classmethod
    def empty(cls, step: int, sensor: int, pose: Array, noise_cov: Array) -> Scan:
        """A look without any return (J = 0); ``m`` is taken from ``noise_cov``."""
        m = np.shape(noise_cov)[-1]
        return cls(step, sensor, np.zeros((0, m)), pose, noise_cov)

    @property
    def count(self) -> int:
        """J, the number of returns."""
        return int(self.returns.shape[0])

    @property
    def dim(self) -> int:
        """m, the dimension of one return."""
        return int(self.returns.shape[1])

    def validate(self) -> Scan:
        """Check types, shapes, finiteness and an SPD noise; raise ValueError naming the field."""
        for key in ("step", "sensor"):
            value = getattr(self, key)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{key}: expected a non-negative integer, got {value!r}")
        if self.returns.ndim != 2 or self.returns.shape[1] < 1:
            raise ValueError(f"returns: expected shape (J, m) with m >= 1, got {self.returns.shape}")
        if not np.all(np.isfinite(self.returns)):
            raise ValueError("returns: contains NaN or Inf")
        if self.pose.shape != (3,):
            raise ValueError(f"pose: expected shape (3,), got {self.pose.shape}")
        if not np.all(np.isfinite(self.pose)):
            raise ValueError("pose: contains NaN or Inf")
        m = self.returns.shape[1]
        if self.noise_cov.shape != (m, m):
            raise ValueError(f"noise_cov: expected shape {(m, m)}, got {self.noise_cov.shape}")
        if not bool(is_spd(self.noise_cov)):
            raise ValueError("noise_cov: not finite, symmetric and positive definite")
        return self
