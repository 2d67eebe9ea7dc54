"""Sigma-point filters (UKF and CKF) built on one shared transform.

A point set is a function of the covariance square root that returns unit offsets ``(p, n)`` scaled per
column, plus mean and covariance weights.  The UKF uses the scaled unscented set (Wan & van der Merwe), the
CKF the third-degree spherical-radial cubature set ``+-sqrt(n) e_i`` with equal weights.  Angle-valued
measurement components are averaged around ``h(mean)`` with wrapped residuals, so means never jump at +-pi.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..linalg import GaussianState, covariance_update, symmetrize
from ..measurement import MeasurementModel
from ..motion import MotionModel
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, nominal_plant_transition

Array = np.ndarray


@dataclass(frozen=True)
class PointSet:
    """Unit sigma offsets ``(p, n)`` (applied to the Cholesky factor) and weights ``wm``, ``wc`` ``(p,)``."""

    offsets: Array
    wm: Array
    wc: Array


def unscented_points(n: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 1.0) -> PointSet:
    """Scaled unscented set with 2n+1 points; defaults keep every weight positive for any n."""
    lam = alpha**2 * (n + kappa) - n
    c = np.sqrt(n + lam)
    offsets = np.vstack([np.zeros(n), c * np.eye(n), -c * np.eye(n)])
    wm = np.full(2 * n + 1, 1.0 / (2.0 * (n + lam)))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + 1.0 - alpha**2 + beta
    return PointSet(offsets, wm, wc)


def cubature_points(n: int) -> PointSet:
    """Third-degree cubature set: 2n points ``+-sqrt(n) e_i``, weights 1/(2n)."""
    c = np.sqrt(n)
    offsets = np.vstack([c * np.eye(n), -c * np.eye(n)])
    w = np.full(2 * n, 1.0 / (2 * n))
    return PointSet(offsets, w, w)


def sigma_points(state: GaussianState, points: PointSet) -> Array:
    """``(B, p, n)`` points ``x + L u_j`` with ``P = L L^T``."""
    chol = np.linalg.cholesky(state.cov)
    return state.mean[:, None, :] + points.offsets @ np.swapaxes(chol, -1, -2)


def weighted_cov(wc: Array, da: Array, db: Array) -> Array:
    """sum_j wc_j da_j db_j^T for ``da`` ``(B, p, a)``, ``db`` ``(B, p, b)``."""
    return np.swapaxes(da * wc[:, None], -1, -2) @ db


class SigmaPointKalmanFilter(LocalFilter):
    """Additive-noise sigma-point Kalman filter; ``points`` selects UKF or CKF."""

    def __init__(self, motion: MotionModel, measurement: MeasurementModel, points: PointSet, name: str) -> None:
        self.motion = motion
        self.measurement = measurement
        self.points = points
        self.name = name
        self.state_dim = self.kinematic_dim = motion.dim

    def nominal_transition(self) -> Array | None:
        """The plant's linear part ``A`` (its nonlinear terms left out)."""
        return nominal_plant_transition(self.motion)

    def predict(self, state: GaussianState) -> GaussianState:
        pts = sigma_points(state, self.points)
        b, p, n = pts.shape
        prop = self.motion.f(pts.reshape(b * p, n)).reshape(b, p, n)
        mean = np.einsum("p,bpn->bn", self.points.wm, prop)
        d = prop - mean[:, None, :]
        cov = weighted_cov(self.points.wc, d, d) + self.motion.Q
        return GaussianState(mean, symmetrize(cov))

    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> GaussianState:
        meas = self.measurement
        pts = sigma_points(state, self.points)
        b, p, n = pts.shape
        zs = meas.h(pts.reshape(b * p, n), np.repeat(sensors, p, axis=0)).reshape(b, p, -1)
        ref = meas.h(state.mean, sensors)
        z_mean = ref + np.einsum("p,bpm->bm", self.points.wm, meas.residual(zs, ref[:, None, :]))
        dz = meas.residual(zs, z_mean[:, None, :])
        dx = pts - state.mean[:, None, :]
        innov_cov = weighted_cov(self.points.wc, dz, dz) + noise_cov
        cross = weighted_cov(self.points.wc, dx, dz)
        return covariance_update(state, cross, innov_cov, meas.residual(z, z_mean))


def unscented_kalman_filter(motion: MotionModel, measurement: MeasurementModel) -> SigmaPointKalmanFilter:
    return SigmaPointKalmanFilter(motion, measurement, unscented_points(motion.dim), "ukf")


def cubature_kalman_filter(motion: MotionModel, measurement: MeasurementModel) -> SigmaPointKalmanFilter:
    return SigmaPointKalmanFilter(motion, measurement, cubature_points(motion.dim), "ckf")


def _ukf(context: FilterContext) -> SigmaPointKalmanFilter:
    return unscented_kalman_filter(context.motion, context.measurement)  # type: ignore[arg-type]


def _ckf(context: FilterContext) -> SigmaPointKalmanFilter:
    return cubature_kalman_filter(context.motion, context.measurement)  # type: ignore[arg-type]


FILTER_REGISTRY.register("ukf", _ukf, (), "unscented Kalman filter (scaled set, alpha 1, beta 2, kappa 1)")
FILTER_REGISTRY.register("ckf", _ckf, (), "cubature Kalman filter (third-degree spherical-radial set)")
