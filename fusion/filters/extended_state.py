"""Extended-state Kalman filters: TESKF (paper 0 Algorithms 1-2) and the one-lumped-state ESKF.

The kinematic state ``x`` (n) is augmented with the lumped uncertainty ``F`` (l) and, for the twice-extended
filter, its temporal difference ``dF`` (paper 0 eq. 12)::

    order 2 (TESKF): xi = [x; F; dF],  Acal = [[A, B, 0], [0, I, I], [0, 0, I]],  Bcal = [0; 0; I]
    order 1 (ESKF):  xi = [x; F],      Acal = [[A, B], [0, I]],                  Bcal = [0; I]

``Bcal`` injects the bounded ``order``-th difference of F; ``Dcal = [I; 0; ...]`` carries the process noise.
The covariance recursion is the upper bound of Theorem 1 (eq. 28) for both orders.
"""
from __future__ import annotations

import math

import numpy as np

from ..defaults import DEFAULT_QBAR
from ..linalg import GaussianState, joseph_update, symmetrize
from ..measurement import MeasurementModel
from ..motion import MotionModel
from ..registry import Param
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, nominal_plant_transition

Array = np.ndarray


def saturate(z: Array, bound: Array) -> Array:
    """sat(z, b) = sign(z) min(|z|, b) element-wise (paper 0 eq. 20)."""
    return np.sign(z) * np.minimum(np.abs(z), bound)


def trace_balance_theta(injection_cov: Array, p0: Array) -> float:
    """theta0 = sqrt(tr(Bcal Q2 Bcal^T) / tr(P0)) (paper 0 Remark 2, eq. 39)."""
    return math.sqrt(float(np.trace(injection_cov)) / float(np.trace(p0)))


class ExtendedStateKalmanFilter(LocalFilter):
    """TESKF (``order=2``) or ESKF (``order=1``) with saturated injection and (1+theta) inflation.

    ``qbar`` bounds E|d^order F_r|^2 per lumped component (Assumption 2); ``theta`` > 0 is the Young split
    parameter; ``None`` picks it by the trace balance of eq. 39 against ``p0_trace_ref`` (tr P0 of the
    augmented prior), which the caller passes when it knows P0.
    """

    def __init__(
        self,
        motion: MotionModel,
        measurement: MeasurementModel,
        order: int = 2,
        qbar: float | Array = DEFAULT_QBAR,
        theta: float | None = None,
        p0: Array | None = None,
    ) -> None:
        if order not in (1, 2):
            raise ValueError(f"order must be 1 (ESKF) or 2 (TESKF), got {order}")
        self.motion = motion
        self.measurement = measurement
        self.order = order
        self.name = "teskf" if order == 2 else "eskf"
        n, l = motion.dim, motion.lumped_dim  # noqa: E741 (l: the paper's lumped dimension)
        self.kinematic_dim = n
        self.lumped_dim = l
        self.state_dim = nx = n + order * l
        self.qbar = np.broadcast_to(np.asarray(qbar, dtype=float), (l,)).copy()
        if np.any(self.qbar <= 0):
            raise ValueError("qbar must be positive")
        # Augmented transition (eq. 12)
        a_cal = np.zeros((nx, nx))
        a_cal[:n, :n] = motion.A
        a_cal[:n, n : n + l] = motion.B
        for j in range(order):
            blk = slice(n + j * l, n + (j + 1) * l)
            a_cal[blk, blk] = np.eye(l)
            if j + 1 < order:
                a_cal[blk, n + (j + 1) * l : n + (j + 2) * l] = np.eye(l)
        self.a_cal = a_cal
        b_cal = np.zeros((nx, l))
        b_cal[n + (order - 1) * l :, :] = np.eye(l)
        self.b_cal = b_cal
        # Q1 = Dcal Q Dcal^T (eq. 16), Q2 = 4 diag(qbar) (eq. 26)
        q1 = np.zeros((nx, nx))
        q1[:n, :n] = motion.Q
        injection_cov = b_cal @ (4.0 * np.diag(self.qbar)) @ b_cal.T
        if theta is None:
            if p0 is None:
                raise ValueError("theta=None needs p0 for the trace-balance heuristic")
            theta = trace_balance_theta(injection_cov, p0)
        if not theta > 0:
            raise ValueError(f"theta must be positive, got {theta}")
        self.theta = float(theta)
        self._r_scale = 1.0 / (1.0 + self.theta)  # Rbar = R / (1 + theta) (eq. 22)
        self._a_cal_t = np.ascontiguousarray(a_cal.T)
        # Qtilde = Q1 + (1 + 1/theta) Bcal Q2 Bcal^T (eq. 27)
        self.q_tilde = q1 + (1.0 + 1.0 / self.theta) * injection_cov

    def initial_state(self, mean: Array, cov: Array, lumped_var: float = 1.0) -> GaussianState:
        """xi0 = [x0; 0; 0] (Assumption 1) and P0 = blkdiag(cov, lumped_var I)."""
        base = super().initial_state(mean, cov, lumped_var)
        b, n = base.mean.shape
        xi = np.zeros((b, self.state_dim))
        xi[:, :n] = base.mean
        p = np.zeros((b, self.state_dim, self.state_dim))
        p[:, :n, :n] = base.cov
        idx = np.arange(n, self.state_dim)
        p[:, idx, idx] = lumped_var
        return GaussianState(xi, p)

    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> GaussianState:
        """Algorithm 2 lines 5-7: Rbar = R/(1+theta), wrapped innovation, Joseph update with C = [H 0 0]."""
        z_pred, c = self.measurement.linearize(state.mean[:, : self.kinematic_dim], sensors, self.state_dim)
        innovation = self.measurement.residual(z, z_pred)
        return joseph_update(state, c, innovation, noise_cov * self._r_scale)

    def nominal_transition(self) -> Array | None:
        """The plant's linear part ``A`` (the kinematic block of ``Acal``, eq. 12)."""
        return nominal_plant_transition(self.motion)

    def injection(self, state: GaussianState) -> Array | None:
        """Saturated nominal ``order``-th difference of F (eq. 20), or None when there is no nominal F.

        The nominal difference is taken along the nominal trajectory from the posterior kinematic estimate:
        F_j = F_nom(x_j), x_{j+1} = A x_j + B F_j.
        """
        x = state.mean[:, : self.kinematic_dim]
        f0 = self.motion.lumped_nominal(x)
        if f0 is None:
            return None
        values = [f0]
        for _ in range(self.order):
            x = x @ self.motion.A.T + values[-1] @ self.motion.B.T
            nominal = self.motion.lumped_nominal(x)
            assert nominal is not None  # a plant with a nominal lumped term has it at every state
            values.append(nominal)
        diff = values[2] - 2.0 * values[1] + values[0] if self.order == 2 else values[1] - values[0]
        return saturate(diff, self.qbar)

    def predict(self, state: GaussianState) -> GaussianState:
        """Algorithm 2 line 8: psi = Acal xi+ + Bcal d, Pbar = (1+theta) Acal P+ Acal^T + Qtilde."""
        mean = state.mean @ self._a_cal_t
        d = self.injection(state)
        if d is not None:
            mean = mean + d @ self.b_cal.T
        cov = (1.0 + self.theta) * (self.a_cal @ state.cov @ self._a_cal_t) + self.q_tilde
        return GaussianState(mean, symmetrize(cov))


def augmented_p0(motion: MotionModel, p0: Array, lumped_var: float, order: int) -> Array:
    """P0 = blkdiag(p0, lumped_var I) of the augmented state (Assumption 1)."""
    n_aug = motion.dim + order * motion.lumped_dim
    p0_aug = np.eye(n_aug) * lumped_var
    p0_aug[: motion.dim, : motion.dim] = p0
    return p0_aug


def extended_state_filter(
    context: FilterContext, order: int, qbar: float = DEFAULT_QBAR, theta: float | None = None
) -> ExtendedStateKalmanFilter:
    """TESKF/ESKF from a context; with ``theta=None`` theta is the trace balance against the augmented P0."""
    p0_aug = augmented_p0(context.motion, context.p0, context.lumped_var, order)
    return ExtendedStateKalmanFilter(
        context.motion, context.measurement, order=order, qbar=qbar, theta=theta, p0=p0_aug  # type: ignore[arg-type]
    )


EXTENDED_STATE_PARAMS = (
    Param("qbar", float, DEFAULT_QBAR, lo=0.0, lo_open=True, help="bound on E|d^order F|^2 per lumped component (Assumption 2)"),
    Param("theta", float, None, lo=0.0, lo_open=True, help="Young split parameter; None: trace balance (eq. 39)"),
)


def _teskf(context: FilterContext, qbar: float, theta: float | None) -> ExtendedStateKalmanFilter:
    return extended_state_filter(context, 2, qbar, theta)


def _eskf(context: FilterContext, qbar: float, theta: float | None) -> ExtendedStateKalmanFilter:
    return extended_state_filter(context, 1, qbar, theta)


FILTER_REGISTRY.register(
    "teskf", _teskf, EXTENDED_STATE_PARAMS, "twice-extended-state Kalman filter (paper 0 Algorithms 1-2)"
)
FILTER_REGISTRY.register(
    "eskf", _eskf, EXTENDED_STATE_PARAMS, "extended-state Kalman filter with one lumped state (paper 0 Section 6 baseline)"
)
