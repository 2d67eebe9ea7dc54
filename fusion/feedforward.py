"""The feed-forward fusion centre of paper 1 (Section 4.1, Algorithm 1): covariance-weighted fusion.

The local estimates ``(m_s, P_s)`` of S sensors are fused as if their errors were independent (MMSE-optimal
linear fusion under that assumption, eqs. 17-18)::

    P_f^-1 = sum_s (P_s + eps I)^-1,      m_f = P_f sum_s (P_s + eps I)^-1 m_s,

``eps`` the regularisation of Sec. 5.3 (0 by default).  The result is not fed back to the local filters.
The paper notes it double counts common information (the same as :mod:`~zentrack.fusion.rules.independent`
over a complete graph); covariance intersection is the consistent alternative.
"""
from __future__ import annotations

import numpy as np

from .linalg import GaussianState, InformationPair, from_information, mat_vec, spd_inverse

Array = np.ndarray


def covariance_weighted_fusion(
    means: Array, covs: Array, eps: float = 0.0, present: Array | None = None
) -> GaussianState:
    """Fuse the local estimates ``means`` ``(..., S, n)``, ``covs`` ``(..., S, n, n)`` over the sensor axis.

    ``present`` ``(..., S)`` (bool) leaves out missing estimates; every fused group needs at least one.
    Returns the fused ``GaussianState`` with mean ``(..., n)`` and covariance ``(..., n, n)``.
    """
    means = np.asarray(means, dtype=float)
    covs = np.asarray(covs, dtype=float)
    n = means.shape[-1]
    info = spd_inverse(covs + eps * np.eye(n))
    vec = mat_vec(info, means)
    if present is not None:
        mask = np.asarray(present, dtype=bool)
        if np.any(~mask.any(axis=-1)):
            raise ValueError("covariance_weighted_fusion: a group has no estimate present")
        info = np.where(mask[..., None, None], info, 0.0)
        vec = np.where(mask[..., None], vec, 0.0)
    lead = means.shape[:-2]
    pair = InformationPair(info.sum(axis=-3).reshape((-1, n, n)), vec.sum(axis=-2).reshape((-1, n)))
    fused = from_information(pair)
    return GaussianState(fused.mean.reshape(lead + (n,)), fused.cov.reshape(lead + (n, n)))
