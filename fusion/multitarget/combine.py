"""The per-track update of an association: the PDA combination, done by any local filter.

Given ``beta_tj`` and ``beta_t0`` (:class:`~zentrack.fusion.multitarget.base.Association`), track ``t``'s
posterior is the Gaussian closest (same first two moments) to the mixture of its prediction (weight
``beta_t0``) and of its update by each return (weight ``beta_tj``), Bar-Shalom & Fortmann 1988 Sec. 6.4, in
the mixture form of Bar-Shalom, Daum & Huang 2009 ("The probabilistic data association filter", IEEE Control
Systems 29(6)):

    m = sum_c w_c m_c,    P = sum_c w_c (P_c + (m_c - m)(m_c - m)^T).

For a Kalman update (``m_j = m + W nu_j``, every ``P_j = P_c``) this is the PDAF's
``m + W nu`` and ``beta_0 P + (1 - beta_0) P_c + W (sum beta_j nu_j nu_j^T - nu nu^T) W^T``
(:mod:`~zentrack.fusion.filters.pdaf_ekf`); done through the local filter's own ``update`` it holds for any
registered filter (EKF, UKF, CKF, extended states). A 0/1 association (GNN) is the filter's update by the
assigned return. Every pair of the scan is updated in one batched call of the filter.
"""
from __future__ import annotations

import numpy as np

from ..filters.base import LocalFilter
from ..linalg import GaussianState, symmetrize
from ..scan import Scan
from .base import Association

Array = np.ndarray


def mixture_moments(weights: Array, means: Array, covs: Array, owner: Array, count: int) -> GaussianState:
    """Moment-matched Gaussians of ``count`` mixtures whose components ``c`` (``weights`` ``(C,)`` summing to one
    per owner, ``means`` ``(C, n)``, ``covs`` ``(C, n, n)``) belong to mixture ``owner[c]`` (module docstring)."""
    n = means.shape[1]
    mean = np.zeros((count, n))
    np.add.at(mean, owner, weights[:, None] * means)
    dev = means - mean[owner]
    cov = np.zeros((count, n, n))
    np.add.at(cov, owner, weights[:, None, None] * (covs + dev[:, :, None] * dev[:, None, :]))
    return GaussianState(mean, symmetrize(cov))


def updated_by_returns(local_filter: LocalFilter, prior: GaussianState, scan: Scan, returns: Array) -> GaussianState:
    """Each estimate of ``prior`` ``(B, n)`` updated by the filter with its return ``returns[b]`` of ``scan``."""
    b, m = returns.size, scan.dim
    return local_filter.update(prior, scan.returns[returns], np.broadcast_to(scan.pose, (b, 1, 3)),
                               np.broadcast_to(scan.noise_cov, (b, m, m)))


def associated_update(local_filter: LocalFilter, prior: GaussianState, scan: Scan, assoc: Association) -> GaussianState:
    """The posterior of every track ``(T, n)`` after ``scan``, weighted by ``assoc`` (module docstring).

    Tracks without a return of positive ``beta`` keep their prediction; tracks with one return of ``beta = 1``
    get the filter's update by it as is."""
    tracks, rets = np.nonzero(assoc.beta > 0.0)
    if tracks.size == 0:
        return prior
    updated = updated_by_returns(local_filter, GaussianState(prior.mean[tracks], prior.cov[tracks]), scan, rets)
    mean, cov = prior.mean.copy(), prior.cov.copy()
    hard = (assoc.beta[tracks, rets] == 1.0) & (assoc.beta0[tracks] == 0.0)
    mean[tracks[hard]], cov[tracks[hard]] = updated.mean[hard], updated.cov[hard]
    soft = ~hard
    if soft.any():
        owners = np.unique(tracks[soft])
        index = np.searchsorted(owners, tracks[soft])
        k = owners.size
        weights = np.concatenate([assoc.beta0[owners], assoc.beta[tracks[soft], rets[soft]]])
        owner = np.concatenate([np.arange(k), index])
        means = np.concatenate([prior.mean[owners], updated.mean[soft]])
        covs = np.concatenate([prior.cov[owners], updated.cov[soft]])
        mixed = mixture_moments(weights, means, covs, owner, k)
        mean[owners], cov[owners] = mixed.mean, mixed.cov
    return GaussianState(mean, cov)
