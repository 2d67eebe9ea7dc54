"""Local filters behind one interface (:class:`LocalFilter`) and a factory by name."""
from __future__ import annotations

import numpy as np

from ..measurement import MeasurementModel
from ..motion import MotionModel
from .base import LocalFilter
from .ekf import ExtendedKalmanFilter
from .extended_state import ExtendedStateKalmanFilter, saturate, trace_balance_theta
from .sigma_point import (
    PointSet,
    SigmaPointKalmanFilter,
    cubature_kalman_filter,
    cubature_points,
    unscented_kalman_filter,
    unscented_points,
)

LOCAL_FILTERS = ("teskf", "eskf", "ekf", "ukf", "ckf")


def make_local_filter(
    kind: str,
    motion: MotionModel,
    measurement: MeasurementModel,
    p0: np.ndarray,
    lumped_var: float = 1.0,
    qbar: float = 1e-6,
    theta: float | None = None,
) -> LocalFilter:
    """Build a local filter by name (one of :data:`LOCAL_FILTERS`).

    ``p0`` is the kinematic prior covariance; extended-state filters add ``lumped_var`` I for their
    augmented blocks and, with ``theta=None``, pick theta by the trace balance against that P0.
    """
    if kind in ("teskf", "eskf"):
        order = 2 if kind == "teskf" else 1
        n_aug = motion.dim + order * motion.lumped_dim
        p0_aug = np.eye(n_aug) * lumped_var
        p0_aug[: motion.dim, : motion.dim] = p0
        return ExtendedStateKalmanFilter(motion, measurement, order=order, qbar=qbar, theta=theta, p0=p0_aug)
    if kind == "ekf":
        return ExtendedKalmanFilter(motion, measurement)
    if kind == "ukf":
        return unscented_kalman_filter(motion, measurement)
    if kind == "ckf":
        return cubature_kalman_filter(motion, measurement)
    raise ValueError(f"unknown local filter {kind!r}; choose one of {', '.join(LOCAL_FILTERS)}")


__all__ = [
    "LOCAL_FILTERS",
    "ExtendedKalmanFilter",
    "ExtendedStateKalmanFilter",
    "LocalFilter",
    "PointSet",
    "SigmaPointKalmanFilter",
    "cubature_kalman_filter",
    "cubature_points",
    "make_local_filter",
    "saturate",
    "trace_balance_theta",
    "unscented_kalman_filter",
    "unscented_points",
]
