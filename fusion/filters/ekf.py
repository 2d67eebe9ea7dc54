"""Extended Kalman filter (the DEKF / centralized EKF baseline of paper 0 Section 6)."""
from __future__ import annotations

import numpy as np

from ..linalg import GaussianState, congruence, joseph_update, symmetrize
from ..measurement import MeasurementModel
from ..motion import MotionModel
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, nominal_plant_transition

Array = np.ndarray


class ExtendedKalmanFilter(LocalFilter):
    """EKF with the model's nominal nonlinear dynamics and a Joseph-form update on wrapped innovations."""

    name = "ekf"

    def __init__(self, motion: MotionModel, measurement: MeasurementModel) -> None:
        self.motion = motion
        self.measurement = measurement
        self.state_dim = self.kinematic_dim = motion.dim

    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> GaussianState:
        z_pred, jac = self.measurement.linearize(state.mean, sensors)
        return joseph_update(state, jac, self.measurement.residual(z, z_pred), noise_cov)

    def nominal_transition(self) -> Array | None:
        """The plant's linear part ``A`` (its nonlinear terms left out)."""
        return nominal_plant_transition(self.motion)

    def predict(self, state: GaussianState) -> GaussianState:
        jac = self.motion.jacobian(state.mean)
        cov = symmetrize(congruence(jac, state.cov) + self.motion.Q)
        return GaussianState(self.motion.f(state.mean), cov)


def _ekf(context: FilterContext) -> ExtendedKalmanFilter:
    return ExtendedKalmanFilter(context.motion, context.measurement)  # type: ignore[arg-type]


FILTER_REGISTRY.register("ekf", _ekf, (), "extended Kalman filter with the nominal nonlinear dynamics")
