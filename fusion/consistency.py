"""Consistency of estimates: NEES, its chi-square band and the covariance ratio eta (what a viewer or a
recorder shows live beside a run).

Errors are ``(R, K, M, n)`` (runs, steps, nodes, state) and covariances ``(R, K, M, n, n)``.
"""
from __future__ import annotations

import numpy as np

Array = np.ndarray


def nees(err: Array, cov: Array) -> Array:
    """Normalised estimation error squared e^T P^-1 e, ``(R, K, M)``."""
    sol = np.linalg.solve(cov, err[..., None])[..., 0]
    return np.sum(err * sol, axis=-1)


def anees_band(dof: int, samples: int, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` band of the average of ``samples`` independent chi-square(``dof``) NEES values."""
    from scipy.stats import chi2  # imported here: tracker processes never need scipy.stats

    lo, hi = chi2.ppf([(1 - prob) / 2, (1 + prob) / 2], dof * samples) / samples
    return float(lo), float(hi)


def consistency_ratio(err: Array, cov: Array) -> float:
    """eta = (1/T) sum_k tr(Sigma_hat_k) / tr(P_k) (paper 0 eq. 65), averaged over nodes.

    Sigma_hat_k is the Monte Carlo error covariance over runs; P_k the runs' mean reported covariance.
    eta > 1: the filter is optimistic.
    """
    emp = np.mean(np.sum(err**2, axis=-1), axis=0)  # (K, M): tr of the empirical covariance
    rep = np.mean(np.trace(cov, axis1=-2, axis2=-1), axis=0)  # (K, M)
    return float(np.mean(emp / rep))
