"""A chi-square gate between two estimates of one state whose cross-correlation is unknown.

A tracker checks each neighbour's prior against its own prediction before fusing it: under CI diffusion the
two are correlated by an unknown amount, so the covariance of their difference ``d = x_a - x_b`` is not
``P_a + P_b``. What holds for *any* correlation, when both estimates are consistent (error covariance at most
``P_a``, ``P_b``), is the covariance-intersection bound: for every ``omega`` in (0, 1)

    Cov(d) <= B(omega) = P_a / omega + P_b / (1 - omega),

because ``0 <= (c e_a + e_b / c)(c e_a + e_b / c)^T`` with ``c^2 = (1 - omega) / omega`` gives
``-(e_a e_b^T + e_b e_a^T) <= e_a e_a^T (1 - omega) / omega + e_b e_b^T omega / (1 - omega)``.
For Gaussian errors ``q = d^T B(omega)^-1 d`` is then stochastically below a chi-square with ``n`` degrees of
freedom, so rejecting when ``q > chi2_n(1 - alpha)`` wrongly rejects an honest neighbour with probability at
most ``alpha``, whatever the correlation, as long as ``omega`` does not depend on ``d``. The gate takes the
``omega`` of the smallest-volume bound (minimum ``det B``), which depends on the covariances alone.

The minimisation runs in the basis that diagonalises both covariances: with ``P_a = L L^T`` and
``L^-1 P_b L^-T = V diag(lam) V^T``, ``B(omega) = L V diag(1/omega + lam/(1 - omega)) V^T L^T`` and
``q = sum_i z_i^2 / (1/omega + lam_i/(1 - omega))`` with ``z = V^T L^-1 d``.

A clutter filter's validation gate ``{nu: nu^T S^-1 nu <= gamma}`` has the volume :func:`gate_volume`;
:func:`expected_gate_clutter` is the clutter expected in it.
"""
from __future__ import annotations

import math

import numpy as np

from .linalg import (
    GaussianState,
    cholesky_one,
    congruence,
    small_inverse,
    spd_mean_cov_one,
    spd_quadratic_form_one,
    symmetrize,
)
from .measurement import MeasurementModel
from .scan import Scan

Array = np.ndarray

#: the omegas searched for the smallest-volume bound (the determinant is smooth and unimodal in omega)
_OMEGAS = np.linspace(0.02, 0.98, 49)


def gate_threshold(dim: int, false_rejection: float) -> float:
    """The chi-square quantile ``chi2_dim(1 - false_rejection)``: the gate's bound on an honest ``q``."""
    if not 0.0 < false_rejection < 1.0:
        raise ValueError(f"gate false-rejection probability must lie in (0, 1), got {false_rejection}")
    from scipy.special import chdtri  # the inverse survival function; lighter to import than scipy.stats

    return float(chdtri(dim, false_rejection))


def ci_gate_statistic(x_a: Array, cov_a: Array, x_b: Array, cov_b: Array) -> float:
    """``q = d^T B(omega*)^-1 d`` for ``d = x_a - x_b`` with the CI bound of the module docstring at the
    smallest-volume ``omega*``; ``inf`` if either covariance is not positive definite or a value is not finite.
    One pair, the tracker's gate on a neighbour's message: :func:`ci_gate_statistics` computes the same for many
    pairs at once, which costs several times more for one (a flood of forged messages is gated one by one)."""
    d = np.asarray(x_a, dtype=float) - np.asarray(x_b, dtype=float)
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(cov_a)) and np.all(np.isfinite(cov_b))):
        return float("inf")
    try:
        low = np.linalg.cholesky(0.5 * (cov_a + cov_a.T))
    except np.linalg.LinAlgError:
        return float("inf")
    low_inv = np.linalg.inv(low)
    lam, vecs = np.linalg.eigh(low_inv @ (0.5 * (cov_b + cov_b.T)) @ low_inv.T)
    if lam[0] <= 0.0:
        return float("inf")
    z2 = (vecs.T @ (low_inv @ d)) ** 2
    w = _OMEGAS[:, None]
    scale = 1.0 / w + lam[None, :] / (1.0 - w)  # B's eigenvalues in the joint basis, one row per omega
    best = int(np.argmin(np.sum(np.log(scale), axis=1)))  # log det B up to the constant log det P_a
    return float(np.sum(z2 / scale[best]))


def ci_gate_statistics(d: Array, cov_a: Array, cov_b: Array) -> Array:
    """:func:`ci_gate_statistic` of many pairs at once: ``d`` ``(P, n)`` the differences, ``cov_a``, ``cov_b``
    ``(P, n, n)``; ``(P,)`` values, ``inf`` for a pair with a covariance not positive definite or a value not
    finite."""
    d, cov_a, cov_b = (np.asarray(a, dtype=float) for a in (d, cov_a, cov_b))
    out = np.full(d.shape[0], np.inf)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(cov_a).all(axis=(1, 2)) & np.isfinite(cov_b).all(axis=(1, 2))
    if not ok.any():
        return out
    sym_a = 0.5 * (cov_a[ok] + np.swapaxes(cov_a[ok], 1, 2))
    sym_b = 0.5 * (cov_b[ok] + np.swapaxes(cov_b[ok], 1, 2))
    try:  # the common case: every P_a positive definite, one Cholesky for the stack
        low, good = np.linalg.cholesky(sym_a), np.ones(sym_a.shape[0], dtype=bool)
    except np.linalg.LinAlgError:  # numpy's Cholesky refuses a whole stack for one bad matrix
        good = np.linalg.eigvalsh(sym_a)[:, 0] > 0.0
        safe = np.where(good[:, None, None], sym_a, np.eye(d.shape[1]))
        try:
            low = np.linalg.cholesky(safe)
        except np.linalg.LinAlgError:  # an eigenvalue above 0 by a rounding: row by row, the failures refused
            rows = [cholesky_one(m) for m in safe]
            good &= np.array([r is not None for r in rows])
            low = np.stack([r if r is not None else np.eye(d.shape[1]) for r in rows])
    with np.errstate(all="ignore"):
        low_inv = np.linalg.inv(low)
        whitened = low_inv @ sym_b @ np.swapaxes(low_inv, 1, 2)
    good &= np.isfinite(whitened).all(axis=(1, 2))  # an extreme covariance overflows: refused, not an error
    whitened = np.where(good[:, None, None], whitened, np.eye(d.shape[1]))
    try:
        lam, vecs = np.linalg.eigh(whitened)
    except np.linalg.LinAlgError:  # no convergence for some row: every row of this batch refused
        return out
    z2 = np.einsum("pji,pj->pi", vecs, np.einsum("pij,pj->pi", low_inv, d[ok])) ** 2
    w = _OMEGAS[None, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = 1.0 / w + lam[:, None, :] / (1.0 - w)  # B's eigenvalues in the joint basis, one row per omega
        best = np.argmin(np.sum(np.log(scale), axis=2), axis=1)  # log det B up to the constant log det P_a
        q = np.sum(z2 / scale[np.arange(scale.shape[0]), best], axis=1)
    out[ok] = np.where(good & (lam[:, 0] > 0.0), q, np.inf)
    return out


def ci_gate_passes(x_a: Array, cov_a: Array, x_b: Array, cov_b: Array, threshold: float) -> bool:
    """Whether ``d = x_a - x_b`` passes the gate: ``q <= threshold`` either for ``omega = 1/2``
    (``B = 2 (P_a + P_b)``, one Cholesky: the cheap common case) or for the smallest-volume ``omega*`` of
    :func:`ci_gate_statistic`. Both bounds are fixed by the covariances alone, and an honest pair is refused
    only when both tests refuse it, so the false-rejection probability stays at most that of either test.

    One tracker runs this for every neighbour's message of every round, so the common case is one Cholesky
    factor and one solve (:func:`~zentrack.fusion.linalg.spd_quadratic_form_one`) instead of ``numpy.linalg``."""
    d = np.asarray(x_a, dtype=float) - np.asarray(x_b, dtype=float)
    cov_sum = np.asarray(cov_a, dtype=float) + np.asarray(cov_b, dtype=float)
    # a sum is finite only if every term is (an overflow of finite values is told apart by the exact check)
    if not math.isfinite(float(cov_sum.sum()) + float(d.sum())) and not (
            np.isfinite(d).all() and np.isfinite(cov_a).all() and np.isfinite(cov_b).all()):
        return False
    q_sum = spd_quadratic_form_one(cov_sum, d)  # d^T (P_a + P_b)^-1 d
    if q_sum is not None and 0.5 * q_sum <= threshold:
        return True
    return ci_gate_statistic(x_a, cov_a, x_b, cov_b) <= threshold


def information_mean_cov(matrix: Array, vector: Array) -> tuple[Array, Array] | None:
    """``(x, P) = (Y^-1 y, Y^-1)`` of one information pair (``Y`` symmetrised), or None if ``Y`` is not positive
    definite (:func:`~zentrack.fusion.linalg.spd_mean_cov_one`: a Cholesky factor's verdict, LU's inverse)."""
    return spd_mean_cov_one(0.5 * (matrix + matrix.T), vector)


def gate_volume(innov_cov: Array, gamma: float) -> Array:
    """Volume of the validation gate ``{nu: nu^T S^-1 nu <= gamma}``: ``c_m gamma^(m/2) sqrt(det S)``.

    ``innov_cov`` ``(..., m, m)``; ``c_m = pi^(m/2) / Gamma(m/2 + 1)`` (c_2 = pi).
    """
    s = np.asarray(innov_cov, dtype=float)
    m = s.shape[-1]
    c_m = math.pi ** (m / 2) / math.gamma(m / 2 + 1)
    return c_m * gamma ** (m / 2) * np.sqrt(np.linalg.det(s))


def expected_gate_clutter(innov_cov: Array, gamma: float, density: float | Array) -> Array:
    """Expected number of clutter returns in the gate per scan, ``lambda V_gate`` (Bar-Shalom & Fortmann 1988,
    eq. 2.3.2-3)."""
    return np.asarray(density) * gate_volume(innov_cov, gamma)


def mahalanobis2(innov: Array, s_inv: Array) -> Array:
    """``nu^T S^-1 nu`` for innovations ``(B, J, m)`` and ``S^-1`` ``(B, m, m)`` -> ``(B, J)``."""
    return ((innov @ s_inv) * innov).sum(axis=-1)


def innovation_distances(measurement: MeasurementModel, state: GaussianState, scan: Scan) -> tuple[Array, Array, Array]:
    """Every estimate of ``state`` (``(T, n)``) against every return of ``scan``, the measurement model linearised
    at the mean (the local EKF's linearisation): ``zhat_t = h(m_t)``, ``H_t = dh/dx(m_t)``, ``S_t = H_t P_t H_t^T +
    R``, ``nu_tj = y_j - zhat_t`` (angles wrapped by the model's ``residual``). Returns the innovations ``(T, J, m)``,
    ``S`` ``(T, m, m)`` and the squared Mahalanobis distances ``nu^T S^-1 nu`` ``(T, J)``: a return is in the
    validation gate ``gamma`` when its distance is at most ``gamma`` (Bar-Shalom & Fortmann 1988 Sec. 2.3)."""
    t, n = state.mean.shape
    sensors = np.broadcast_to(scan.pose, (t, 1, 3))
    z_pred, jac = measurement.linearize(state.mean, sensors, n)
    if z_pred.shape[1] != scan.dim:
        raise ValueError(f"scan of sensor {scan.sensor}: returns have {scan.dim} components, the model {z_pred.shape[1]}")
    s = symmetrize(congruence(jac, state.cov) + scan.noise_cov)
    innov = measurement.residual(scan.returns[None, :, :], z_pred[:, None, :])  # (T, J, m)
    return innov, s, mahalanobis2(innov, small_inverse(s))
