"""Gaussian comparators for paper 1 on the same clutter scans: PDAF with an EKF (``"pdaf-ekf"``) and the
nearest-neighbour EKF (``"nn-ekf"``).

Both linearise the measurement at the predicted mean, ``zhat = h(m)``, ``H = dh/dx(m)``, ``S = H P H^T + R``,
gate the wrapped innovations ``nu_j = y_j - zhat`` by ``nu_j^T S^-1 nu_j <= gamma`` and predict like the EKF
(``m+ = f(m)``, ``P+ = F P F^T + Q``).

**PDAF** (Bar-Shalom & Tse 1975; Bar-Shalom & Fortmann 1988 Sec. 6.4), with beta_j, beta_0 from
``l_j = N(nu_j; 0, S)`` (formula in :mod:`~zentrack.fusion.filters.pda_common`)::

    W = P H^T S^-1,  nu = sum_j beta_j nu_j,  m+ = m + W nu,
    P+ = beta_0 P + (1 - beta_0) P_c + W (sum_j beta_j nu_j nu_j^T - nu nu^T) W^T,

``P_c`` the Joseph-form Kalman covariance ``(I - W H) P (I - W H)^T + W R W^T``.

**NN-EKF**: the gated return of smallest ``nu^T S^-1 nu`` is taken as the target's and used in a plain EKF
(Joseph) update; no gated return, no update.  Known to lose the track in dense clutter (it is the baseline).
"""
from __future__ import annotations

import numpy as np

from ..gate import mahalanobis2
from ..linalg import GaussianState, congruence, joseph_update, mat_vec, small_inverse, symmetrize
from .base import FILTER_REGISTRY, FilterContext
from .pda_common import CLUTTER_PARAMS, ClutterFilter, context_models, gate, gaussian_log_density

Array = np.ndarray


class _LinearisedClutterFilter(ClutterFilter):
    """EKF prediction and the linearised gate shared by the PDAF-EKF and the NN-EKF."""

    def predict(self, state: GaussianState) -> GaussianState:
        jac = self.motion.jacobian(state.mean)
        return GaussianState(self.motion.f(state.mean), symmetrize(congruence(jac, state.cov) + self.motion.Q))

    def linearised_gate(
        self, state: GaussianState, z: Array, valid: Array, sensors: Array, noise_cov: Array
    ) -> tuple[Array, Array, Array, Array, Array]:
        """``H`` ``(B, m, n)``, ``S``, ``S^-1`` ``(B, m, m)``, innovations ``(B, J, m)`` and the gate mask."""
        z_pred, jac = self.measurement.linearize(state.mean, sensors)
        s = symmetrize(congruence(jac, state.cov) + noise_cov)
        s_inv = small_inverse(s)
        innov = self.measurement.residual(z, z_pred[:, None, :])
        return jac, s, s_inv, innov, gate(innov, s_inv, valid, self.gamma)


class PdafExtendedKalmanFilter(_LinearisedClutterFilter):
    """Probabilistic data association filter on an EKF (module docstring)."""

    name = "pdaf-ekf"

    def update_batch(
        self, state: GaussianState, z: Array, valid: Array, sensors: Array, noise_cov: Array
    ) -> GaussianState:
        if z.shape[1] == 0 or not np.any(valid):
            self.last_association = None
            return state
        jac, s, s_inv, innov, gated = self.linearised_gate(state, z, valid, sensors, noise_cov)
        log_lik = gaussian_log_density(innov, s_inv, np.linalg.slogdet(s)[1])
        assoc = self.associate(log_lik, gated, s)
        beta = assoc.beta
        nu = np.einsum("bj,bjm->bm", beta, innov)
        spread = np.einsum("bj,bjm,bjk->bmk", beta, innov, innov) - nu[:, :, None] * nu[:, None, :]
        p = state.cov
        gain = p @ np.swapaxes(jac, -1, -2) @ s_inv
        p_c = joseph_update(GaussianState(state.mean, p), jac, np.zeros_like(nu), noise_cov).cov
        b0 = assoc.beta0[:, None, None]
        cov = b0 * p + (1.0 - b0) * p_c + congruence(gain, spread)
        return GaussianState(state.mean + mat_vec(gain, nu), symmetrize(cov))


class NearestNeighbourExtendedKalmanFilter(_LinearisedClutterFilter):
    """EKF on the gated return nearest (Mahalanobis) to the prediction (module docstring)."""

    name = "nn-ekf"

    def update_batch(
        self, state: GaussianState, z: Array, valid: Array, sensors: Array, noise_cov: Array
    ) -> GaussianState:
        if z.shape[1] == 0 or not np.any(valid):
            return state
        jac, _, s_inv, innov, gated = self.linearised_gate(state, z, valid, sensors, noise_cov)
        d2 = np.where(gated, mahalanobis2(innov, s_inv), np.inf)
        best = np.argmin(d2, axis=1)
        has = np.isfinite(d2[np.arange(d2.shape[0]), best])
        if not np.any(has):
            return state
        nu = innov[np.arange(innov.shape[0]), best]
        upd = joseph_update(GaussianState(state.mean[has], state.cov[has]), jac[has], nu[has], noise_cov[has])
        mean, cov = state.mean.copy(), state.cov.copy()
        mean[has], cov[has] = upd.mean, upd.cov
        return GaussianState(mean, cov)


def _pdaf_ekf(context: FilterContext, gate: float, detection_prob: float,
              clutter_density: float | None) -> PdafExtendedKalmanFilter:
    motion, measurement = context_models(context)
    return PdafExtendedKalmanFilter(motion, measurement, gate, detection_prob, clutter_density)


def _nn_ekf(context: FilterContext, gate: float, detection_prob: float,
            clutter_density: float | None) -> NearestNeighbourExtendedKalmanFilter:
    motion, measurement = context_models(context)
    return NearestNeighbourExtendedKalmanFilter(motion, measurement, gate, detection_prob, clutter_density)


FILTER_REGISTRY.register(
    "pdaf-ekf", _pdaf_ekf, CLUTTER_PARAMS, "probabilistic data association filter on an EKF (paper 1 comparator)",
    tags=("scans",),
)
FILTER_REGISTRY.register(
    "nn-ekf", _nn_ekf, CLUTTER_PARAMS,
    "nearest-neighbour EKF (gated return of smallest Mahalanobis distance; paper 1 comparator)",
    tags=("scans",),
)

