"""Fusion rules on information pairs: covariance intersection (CI) diffusion and naive independent fusion.

Arrays carry a leading batch of independent networks: information matrices ``(R, M, n, n)`` and vectors
``(R, M, n)`` for M senders in each of R runs (R may be 1).  ``weights`` is ``(M, M)``: row i holds the
weights node i gives to each sender.  ``present`` ``(R, M, M)`` or ``(M, M)`` marks which pairs actually
reached each receiver; the row is renormalised over them, which keeps CI consistent (seed 000 Theorem 3
holds for any convex weights).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .linalg import GaussianState, InformationPair, from_information

Array = np.ndarray


def renormalise_rows(weights: Array, present: Array | None = None) -> Array:
    """Zero the weights of absent senders and rescale each row to sum to one.

    A row with no sender present (not even the node itself) is an error: the caller must keep its own pair.
    """
    w = np.asarray(weights, dtype=float)
    if present is not None:
        w = np.where(present, w, 0.0)
    total = w.sum(axis=-1, keepdims=True)
    if np.any(total <= 0):
        raise ValueError("a receiver has no positive-weight pair to fuse (its own pair must be present)")
    return w / total


def mix_information(weights: Array, pair: InformationPair) -> InformationPair:
    """``Y_i = sum_j w_ij Y_j``, ``y_i = sum_j w_ij y_j`` (seed 000 eqs. 49-50 in information form).

    ``weights`` is ``(M, M)`` shared by all runs or ``(R, M, M)`` per run.
    """
    y_mat, y_vec = pair.matrix, pair.vector
    r, m, n = y_vec.shape
    mixed_mat = (weights @ y_mat.reshape(r, m, n * n)).reshape(r, -1, n, n)
    return InformationPair(mixed_mat, weights @ y_vec)


def ci_fuse(weights: Array, pair: InformationPair, present: Array | None = None) -> GaussianState:
    """CI diffusion (seed 000 Algorithm 2 line 10) with rows renormalised over the pairs present.

    Returns the fused state per receiver, ``(R, M, n)`` means and ``(R, M, n, n)`` covariances.
    """
    w = renormalise_rows(weights, present) if present is not None else np.asarray(weights, dtype=float)
    return from_information(mix_information(w, pair))


def ci_fuse_one(weights: Array, matrices: Sequence[Array], vectors: Sequence[Array]) -> GaussianState:
    """:func:`ci_fuse` for one receiver, the tracker's case: ``weights`` ``(S,)`` over the S pairs it holds
    (``(n, n)`` and ``(n,)`` each); returns ``(1, n)`` / ``(1, n, n)``.

    The same operations on 2-D arrays instead of ``(1, 1, ...)`` stacks (the same matmul and LAPACK kernels),
    so the result is bit for bit that of :func:`ci_fuse` with ``present`` all true, at about half the numpy
    call overhead."""
    w = np.asarray(weights, dtype=float)[None, :]
    total = w.sum(axis=-1, keepdims=True)
    if total[0, 0] <= 0:
        raise ValueError("a receiver has no positive-weight pair to fuse (its own pair must be present)")
    w = w / total
    stacked = np.stack(matrices)
    n = stacked.shape[-1]
    matrix = (w @ stacked.reshape(len(matrices), n * n)).reshape(n, n)  # eqs. 49-50 in information form
    vector = w @ np.stack(vectors)
    inv = np.linalg.inv(matrix)  # spd_inverse on a stack smaller than CHOLESKY_INVERSE_MIN_BATCH
    cov = 0.5 * (inv + inv.T)
    return GaussianState((cov @ vector[0][:, None])[None, :, 0], cov[None])


def independent_fuse(adjacency: Array, pair: InformationPair, present: Array | None = None) -> GaussianState:
    """Naive information-sum fusion ``Y_i = sum_j Y_j`` over neighbours and self (assumes independent errors).

    Not consistent under correlated errors; kept for comparison with CI.
    """
    a = (np.asarray(adjacency) != 0) | np.eye(adjacency.shape[-1], dtype=bool)
    if present is not None:
        a = a & present
    return from_information(mix_information(a.astype(float), pair))
