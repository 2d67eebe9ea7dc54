"""Covariance intersection (CI) on information pairs, in one place: the combination, its fast path for one
receiver, the weight rules, and naive independent fusion for comparison. The registered fusion rules that use
them (``ci``, ``ci-fast``, ``dce-fci``, ...) are the modules of :mod:`zentrack.fusion.rules`.

CI (Julier & Uhlmann 1997; paper 0 eqs. 49-50 and Algorithm 2 line 10; paper 2 Section 2.3.1) fuses
estimates with unknown cross-correlation by a convex combination of their information pairs,
``Y = sum_j omega_j Y_j``, ``y = sum_j omega_j y_j``, then ``P = Y^-1``, ``x = P y``; the result is consistent
for any convex weights (paper 0 Lemma 1, Theorem 3).  Every rule, the batched simulator, the trackers and the
viewer combine through :func:`mix_information` (:func:`ci_fuse`, :func:`ci_combine`; :func:`ci_fuse_one` is the
tracker's bit-identical fast path for one receiver).  The weights are the graph's diffusion weights or one of
the weight rules, each named for what it computes:

- :func:`information_trace_weights`: ``omega_j ~ tr Y_j`` (paper 2 eq. 41, its "fast CI": "the weights are
  computed by the trace of the information matrix"; ``diff-fci``, ``dce-fci``);
- :func:`inverse_covariance_trace_weights`: ``omega_j ~ 1 / tr P_j`` (fast CI of Niehsen, FUSION 2002;
  ``ci-fast``);
- :func:`min_trace_weights`: the ``omega`` that (nearly) minimises ``tr P`` of the fused covariance (the
  classical CI criterion; ``ci-trace``).

Arrays carry a leading batch of independent networks: information matrices ``(R, M, n, n)`` and vectors
``(R, M, n)`` for M senders in each of R runs (R may be 1).  ``weights`` is ``(M, M)``: row i holds the
weights node i gives to each sender (or ``(R, M, M)`` per run).  ``present`` ``(R, M, M)`` or ``(M, M)``
marks which pairs actually reached each receiver; the row is renormalised over them, which keeps CI
consistent (paper 0 Theorem 3 holds for any convex weights).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .linalg import GaussianState, InformationPair, from_information, inverse, is_spd, spd_inverse

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


def mix_matrices(weights: Array, matrices: Array) -> Array:
    """``Y_i = sum_j w_ij Y_j``: the matrix half of :func:`mix_information` (``(R, S, n, n)`` -> ``(R, M, n, n)``)."""
    if np.ndim(weights) == 3:  # weights per run: the ordered sum over the senders (see mix_information)
        return np.einsum("rms,rsab->rmab", weights, matrices)
    r, s, n = matrices.shape[:3]
    return (weights @ matrices.reshape(r, s, n * n)).reshape(r, -1, n, n)


def mix_information(weights: Array, pair: InformationPair) -> InformationPair:
    """``Y_i = sum_j w_ij Y_j``, ``y_i = sum_j w_ij y_j`` (paper 0 eqs. 49-50 in information form): the CI
    combination of every rule, and the weighted average of the consensus rounds.

    ``weights`` is ``(M, S)`` shared by all runs or ``(R, M, S)`` per run, over the S senders of ``pair``
    (``(R, S, n, n)``, ``(R, S, n)``). Shared weights go through one matrix product (the BLAS kernel that
    :func:`ci_fuse_one` reproduces bit for bit on a tracker); weights per run (those a weight rule chooses per
    receiver, or rows renormalised over per-run ``present``) through einsum's ordered sum over the senders.
    The two orders agree to rounding; each is kept where results were pinned with it (a 1e-16 difference grows
    to the third digit of bench accuracy's sigma-point rows on exp2).
    """
    if np.ndim(weights) == 3:
        return InformationPair(mix_matrices(weights, pair.matrix), np.einsum("rms,rsa->rma", weights, pair.vector))
    return InformationPair(mix_matrices(weights, pair.matrix), weights @ pair.vector)


def ci_fuse(weights: Array, pair: InformationPair, present: Array | None = None) -> GaussianState:
    """CI diffusion (paper 0 Algorithm 2 line 10) with rows renormalised over the pairs present.

    Returns the fused state per receiver, ``(R, M, n)`` means and ``(R, M, n, n)`` covariances.
    """
    w = renormalise_rows(weights, present) if present is not None else np.asarray(weights, dtype=float)
    return from_information(mix_information(w, pair))


def ci_fuse_one(weights: Array, matrices: Sequence[Array], vectors: Sequence[Array]) -> GaussianState:
    """:func:`ci_fuse` for one receiver, the tracker's case: ``weights`` ``(S,)`` over the S pairs it holds
    (``(n, n)`` and ``(n,)`` each); returns ``(1, n)`` / ``(1, n, n)``.

    The same operations on 2-D arrays instead of ``(1, 1, ...)`` stacks (the same matmul and LAPACK kernels),
    so the result is bit for bit that of :func:`ci_fuse` with ``present`` all true, at about half the numpy
    call overhead (``np.array`` of the list, not ``np.stack``'s Python-level loop)."""
    w = np.asarray(weights, dtype=float)[None, :]
    total = w.sum(axis=-1, keepdims=True)
    if total[0, 0] <= 0:
        raise ValueError("a receiver has no positive-weight pair to fuse (its own pair must be present)")
    w = w / total
    stacked = np.array(matrices, dtype=float)
    if stacked.ndim != 3 or stacked.shape[1] != stacked.shape[2]:
        raise ValueError(f"ci_fuse_one: expected S square matrices, got an array of shape {stacked.shape}")
    n = stacked.shape[-1]
    matrix = (w @ stacked.reshape(len(matrices), n * n)).reshape(n, n)  # eqs. 49-50 in information form
    vector = w @ np.array(vectors, dtype=float)
    inv = inverse(matrix)  # spd_inverse on a stack smaller than CHOLESKY_INVERSE_MIN_BATCH
    cov = 0.5 * (inv + inv.T)
    return GaussianState((cov @ vector[0][:, None])[None, :, 0], cov[None])


def ci_combine(infos: Array, info_vectors: Array, omega: Array) -> GaussianState:
    """CI of N estimates per batch element, checked: ``Y = sum_i omega_i Y_i``, ``y = sum_i omega_i y_i``
    (paper 2 Section 2.3.1), returned as ``(Y^-1 y, Y^-1)``; :func:`ci_fuse` with one receiver per batch element.

    ``infos`` ``(..., N, n, n)``, ``info_vectors`` ``(..., N, n)``, ``omega`` ``(..., N)`` convex (non-negative,
    summing to one). ValueError on non-finite input, non-SPD information matrices or invalid weights (the
    batched simulator and the trackers call :func:`ci_fuse` / :func:`ci_fuse_one`, which do not check).
    """
    y_mat = np.asarray(infos, dtype=float)
    y_vec = np.asarray(info_vectors, dtype=float)
    w = np.asarray(omega, dtype=float)
    if y_mat.ndim < 3 or y_vec.shape != y_mat.shape[:-1] or w.shape[-1:] != y_mat.shape[-3:-2]:
        raise ValueError(f"shapes do not match: infos {y_mat.shape}, info_vectors {y_vec.shape}, omega {w.shape}")
    for name, a in (("infos", y_mat), ("info_vectors", y_vec), ("omega", w)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} has non-finite values")
    if not np.all(is_spd(y_mat)):
        raise ValueError("infos is not symmetric positive definite")
    if np.any(w < 0) or np.any(np.abs(w.sum(axis=-1) - 1.0) > 1e-9):
        raise ValueError(f"CI weights must be non-negative and sum to 1, got {np.array2string(w, precision=6)}")
    batch, (count, n) = y_mat.shape[:-3], y_mat.shape[-3:-1]
    w = np.broadcast_to(w, batch + (count,)).reshape(-1, 1, count)
    fused = ci_fuse(w, InformationPair(y_mat.reshape(-1, count, n, n), y_vec.reshape(-1, count, n)))
    return GaussianState(fused.mean.reshape(batch + (n,)), fused.cov.reshape(batch + (n, n)))


# ------------------------------------------------------------------------------------------------ weight rules

#: fixed-point iterations of :func:`min_trace_weights`: measured over 200 random pairs of 3-D covariances, the
#: fused trace is within 0.5 % of the minimum after 20 (within 0.1 % after 40; the iteration is slow where an
#: optimal weight is 0)
TRACE_ITERATIONS = 20


def normalise_weights(score: Array, support: Array | None = None) -> Array:
    """Convex weights proportional to ``score`` ``(..., S)``: over the last axis, or with ``support``
    ``(..., M, S)`` per receiver over the senders it holds (``(..., M, S)``, zero outside the support)."""
    if support is None:
        return score / score.sum(axis=-1, keepdims=True)
    omega = np.where(support, score[..., None, :], 0.0)
    return omega / omega.sum(axis=-1, keepdims=True)


def information_trace(infos: Array) -> Array:
    """``tr Y_j`` per information matrix ``(..., n, n) -> (...)``: the unnormalised weight of
    :func:`information_trace_weights` (the consensus rules average it, paper 2 DCE-FCI)."""
    return np.trace(infos, axis1=-2, axis2=-1)


def information_trace_weights(infos: Array, support: Array | None = None) -> Array:
    """The information-trace rule, ``omega_j = tr Y_j / sum_k tr Y_k`` (paper 2 eq. 41: fast CI with "the
    weights computed by the trace of the information matrix"): the better-informed estimate weighs more.

    ``infos`` ``(..., S, n, n)`` -> ``(..., S)``; with ``support`` ``(..., M, S)`` per receiver (see
    :func:`normalise_weights`). No checks (a diverged run's NaN reaches the simulator's guard); the traces of
    positive definite matrices are positive."""
    return normalise_weights(information_trace(infos), support)


def inverse_covariance_trace_weights(infos: Array, support: Array | None = None) -> Array:
    """The inverse-covariance-trace rule of fast CI, ``omega_j = (1 / tr P_j) / sum_k (1 / tr P_k)`` with
    ``P_j = Y_j^-1`` (W. Niehsen, "Information fusion based on fast covariance intersection filtering", FUSION
    2002): the estimate with the smaller covariance weighs more.

    ``infos`` ``(..., S, n, n)`` -> ``(..., S)``; with ``support`` ``(..., M, S)`` per receiver (see
    :func:`normalise_weights`). No checks, as :func:`information_trace_weights`."""
    return normalise_weights(1.0 / np.trace(spd_inverse(infos), axis1=-2, axis2=-1), support)


def min_trace_weights(infos: Array, support: Array | None = None, iterations: int = TRACE_ITERATIONS) -> Array:
    """The minimum-trace rule: convex weights that (nearly: :data:`TRACE_ITERATIONS`) minimise ``tr P`` of the
    fused ``P^-1 = sum_j omega_j Y_j`` (the classical CI criterion, Julier & Uhlmann 1997), starting from equal
    weights over the support, by the multiplicative fixed-point iteration ``omega_j <- omega_j g_j / sum_k
    omega_k g_k`` with ``g_j = tr(P Y_j P)`` (minus the gradient of ``tr P``; a fixed point with every
    ``omega_j > 0`` has equal ``g_j``, the optimality condition on the simplex; ``tr P`` is convex in ``omega``).

    ``infos`` ``(R, S, n, n)`` -> ``(R, S)``; with ``support`` ``(R, M, S)`` per receiver -> ``(R, M, S)``."""
    one = support is None
    held = np.ones(infos.shape[:-3] + (1, infos.shape[-3]), dtype=bool) if support is None else support
    omega = held / held.sum(axis=-1, keepdims=True)
    for _ in range(iterations):
        fused_cov = spd_inverse(mix_matrices(omega, infos))
        grad = np.einsum("rmcb,rsbc->rms", fused_cov @ fused_cov, infos)  # tr(P Y_j P) = tr(Y_j P P) >= 0
        omega = omega * grad
        omega = omega / omega.sum(axis=-1, keepdims=True)
    return omega[..., 0, :] if one else omega


# ------------------------------------------------------------------------------------------------ comparison


def independent_fuse(adjacency: Array, pair: InformationPair, present: Array | None = None) -> GaussianState:
    """Naive information-sum fusion ``Y_i = sum_j Y_j`` over neighbours and self (assumes independent errors).

    Not consistent under correlated errors; kept for comparison with CI.
    """
    a = (np.asarray(adjacency) != 0) | np.eye(adjacency.shape[-1], dtype=bool)
    if present is not None:
        a = a & present
    return from_information(mix_information(a.astype(float), pair))
