"""Inverse covariance intersection (ICI) as pure maths (paper 2 Sec. 2.3.2), in one place.

- Two-estimate ICI (B. Noack, J. Sijs, M. Reinhardt, U. D. Hanebeck, "Decentralized data fusion with inverse
  covariance intersection", Automatica 79, 2017): :func:`ici_fuse_two`.
- Multi-estimate ICI (J. Ajgl, O. Straka, "Inverse covariance intersection fusion of multiple estimates",
  FUSION 2020; paper 2 eqs. 44-50): :func:`ici_fuse`, and its distributed form at one node after consensus
  averages (paper 2 eqs. 62-63): :func:`ici_from_averages`, which the ``dce-ici`` / ``diff-ici`` rules call.

Covariance intersection itself (the combination and its weight rules, paper 2 Section 2.3.1) lives in
:mod:`zentrack.fusion.covariance_intersection`.

When is ICI consistent? ICI is derived for estimates that share unknown *common information*: the information
of estimate i is ``P_i^-1 = D_i + C`` with a private part ``D_i >= 0`` and a common part ``C = Gamma_c^-1``
whose errors are mutually independent, so ``Cov(e_i, e_j) = P_i C P_j`` for i != j (Noack et al. 2017). Under
that model, with ``Gamma = sum alpha_i P_i``, the fused error covariance is bounded by the ICI covariance iff
(our derivation: write ``P_i^-1 e_i = u_i + v`` with ``Cov(u_i) = D_i``, ``Cov(v) = C``, expand ``P - K J K^T``)
``f(Gamma) >= (N - 1) sum alpha_i^2 f(P_i)`` with ``f(X) = X - X C X`` (matrix concave, ``f(P_i) >= 0``). Hence:

- two estimates: consistent for every ``omega`` in [0, 1] (``alpha_i <= 1 = 1 / (N - 1)``);
- N estimates: consistent for every common information when ``alpha_i <= 1 / (N - 1)`` for all i (the "box"
  condition; it implies the paper's ``sum alpha^2 <= 1 / (N - 1)``, the "ball"). The ball alone suffices when
  all ``P_i`` are equal, but not in general: with independent estimates (``C = 0``) the condition reads
  ``sum alpha_i (1 - (N - 1) alpha_i) P_i >= 0``, which fails when an ``alpha_j > 1 / (N - 1)`` meets a large
  ``P_j`` (e.g. N = 3, alpha = (0.55, 0.30, 0.15), sum alpha^2 = 0.415 <= 0.5, P = (10, 1, 1): fused bound
  0.567 < true error variance 0.573). Uniform weights ``1 / N`` always satisfy the box.
- Neither form of ICI bounds arbitrary correlations (any joint covariance with the given diagonal blocks), nor a
  "common noise" model ``e_i = w + u_i``; CI does (see ``tests/test_ici.py``, which measures all of this).

The consensus distributed form ``Y_F = N Ybar - (N - 1) Pbar^-1`` equals centralised ICI with uniform weights
only when the averages are exact; after finitely many rounds node i's averages weight estimate j by
``alpha_ij`` and the form is ``sum_j N alpha_ij Y_j - (N - 1)(sum_j alpha_ij P_j)^-1``, which is not the ICI
of eq. 47 with weights alpha (it re-weights the information by ``N alpha_ij``). Under the common-information
model it is not consistent in general, even at the paper's round count (measured in
``tests/test_consensus_weights.py``).
Replacing N by the row's effective count ``m_i = 1 / max_j alpha_ij`` (:func:`effective_count`; equal to N for
exact averages) gave no violation in any trial we ran (12,000 random convex weight vectors for N = 2, 3, 5, 8
and 2,000 consensus rows for N = 8, all under random common information, and a Nelder-Mead search for the worst
scalar case, N = 2..8, which with the same search finds the N form's true error variance up to 12 times its
claimed one for arbitrary convex weights); an empirical observation, not a proof.

Arrays carry leading batch dimensions: means ``(..., N, n)``, covariances ``(..., N, n, n)``, weights ``(..., N)``.
"""
from __future__ import annotations

import math

import numpy as np

from .linalg import GaussianState, InformationPair, is_spd, mat_vec, spd_inverse, symmetrize

Array = np.ndarray

__all__ = [
    "ICI_CONDITIONS", "check_ici_weights", "effective_count", "ici_from_averages", "ici_fuse", "ici_fuse_two",
    "ici_gains", "ici_weights_valid",
]

#: ``"ball"``: the paper's sum alpha = 1, alpha >= 0, sum alpha^2 <= 1/(N-1); ``"box"``: also alpha_i <= 1/(N-1)
ICI_CONDITIONS = ("ball", "box")


# ------------------------------------------------------------------------------------------------- checking


def _finite(name: str, x: Array | float) -> Array:
    a = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise ValueError(f"{name} has non-finite values (first at index {tuple(int(i) for i in bad)})")
    return a


def _spd(name: str, m: Array) -> Array:
    """``m`` symmetrised, after checking that every matrix of the stack is symmetric positive definite."""
    m = _finite(name, m)
    if m.ndim < 2 or m.shape[-1] != m.shape[-2]:
        raise ValueError(f"{name} must be a stack of square matrices, got shape {m.shape}")
    ok = is_spd(m)
    if not np.all(ok):
        bad = np.argwhere(~np.asarray(ok))
        where = f" (first at batch index {tuple(int(i) for i in bad[0])})" if bad.size else ""
        raise ValueError(f"{name} is not symmetric positive definite{where}")
    return symmetrize(m)


def _condition(condition: str) -> str:
    if condition not in ICI_CONDITIONS:
        raise ValueError(f"condition must be one of {ICI_CONDITIONS}, got {condition!r}")
    return condition


def ici_weights_valid(alpha: Array, condition: str = "ball", tol: float = 1e-9) -> Array:
    """Boolean per weight vector ``(..., N) -> (...)``: does it satisfy the ICI weight conditions?

    ``"ball"`` (paper 2 eq. 45, Remark 2): ``sum alpha = 1``, ``alpha >= 0``, ``sum alpha^2 <= 1 / (N - 1)``;
    ``"box"``: additionally ``alpha_i <= 1 / (N - 1)`` (sufficient for consistency under every common
    information, see the module docstring). Each inequality holds up to ``tol``; N = 1 needs alpha = (1,).
    """
    _condition(condition)
    a = np.asarray(alpha, dtype=float)
    if a.ndim < 1 or a.shape[-1] < 1:
        raise ValueError(f"ICI weights must have a last axis of at least one estimate, got shape {a.shape}")
    n = a.shape[-1]
    cap = 1.0 / (n - 1) if n > 1 else math.inf
    ok = np.all(np.isfinite(a), axis=-1)
    ok &= np.all(a >= -tol, axis=-1)
    ok &= np.abs(a.sum(axis=-1) - 1.0) <= tol
    ok &= (a**2).sum(axis=-1) <= cap + tol
    if condition == "box":
        ok &= a.max(axis=-1) <= cap + tol
    return ok


def check_ici_weights(alpha: Array, tol: float = 1e-9, condition: str = "ball") -> None:
    """Raise ValueError (naming the condition, the weight vector and the offending value) unless every weight
    vector ``alpha (..., N)`` satisfies the conditions of :func:`ici_weights_valid`."""
    _condition(condition)
    a = np.asarray(alpha, dtype=float)
    if a.ndim < 1 or a.shape[-1] < 1:
        raise ValueError(f"ICI weights must have a last axis of at least one estimate, got shape {a.shape}")
    n = a.shape[-1]
    flat = a.reshape(-1, n)
    cap = 1.0 / (n - 1) if n > 1 else math.inf

    def where(row: int) -> str:
        idx = np.unravel_index(row, a.shape[:-1]) if a.ndim > 1 else ()
        return f"weights {tuple(int(i) for i in idx)} = {np.array2string(flat[row], precision=6)}" if idx \
            else f"weights {np.array2string(flat[row], precision=6)}"

    finite = np.all(np.isfinite(flat), axis=1)
    if not finite.all():
        raise ValueError(f"ICI weights must be finite: {where(int(np.argmin(finite)))}")
    low = flat.min(axis=1)
    if np.any(low < -tol):
        r = int(np.argmin(low))
        raise ValueError(f"ICI weights must be non-negative: {where(r)} has {low[r]:.6g} < 0")
    total = flat.sum(axis=1)
    if np.any(np.abs(total - 1.0) > tol):
        r = int(np.argmax(np.abs(total - 1.0)))
        raise ValueError(f"ICI weights must sum to 1: {where(r)} sums to {total[r]:.12g}")
    sq = (flat**2).sum(axis=1)
    if np.any(sq > cap + tol):
        r = int(np.argmax(sq))
        raise ValueError(f"ICI weights must satisfy sum alpha^2 <= 1/(N-1) = {cap:.6g} (N = {n}): "
                         f"{where(r)} has sum alpha^2 = {sq[r]:.6g}")
    if condition == "box":
        top = flat.max(axis=1)
        if np.any(top > cap + tol):
            r = int(np.argmax(top))
            raise ValueError(f"ICI weights must satisfy alpha_i <= 1/(N-1) = {cap:.6g} (N = {n}, 'box' "
                             f"condition): {where(r)} has max alpha = {top[r]:.6g}")


# ------------------------------------------------------------------------------------------ multi-estimate


def _uniform(shape: tuple[int, ...], n: int) -> Array:
    return np.full(shape + (n,), 1.0 / n)


def ici_gains(covs: Array, alpha: Array | None = None) -> tuple[Array, Array]:
    """Fused covariance and the linear gains of multi-estimate ICI: ``x = sum_i K_i x_i``.

    ``K_i = P (P_i^-1 - (N - 1) alpha_i Gamma^-1)`` with ``Gamma = sum alpha_i P_i`` and
    ``P^-1 = sum P_i^-1 - (N - 1) Gamma^-1`` (Ajgl & Straka 2020; paper 2 eqs. 47-50); ``sum_i K_i = I``.
    Returns ``(P (..., n, n), K (..., N, n, n))``. No weight check (see :func:`ici_fuse`).
    """
    p_i = _spd("covs", covs)
    if p_i.ndim < 3:
        raise ValueError(f"covs must be (..., N, n, n), got shape {p_i.shape}")
    n_est = p_i.shape[-3]
    a = _uniform(p_i.shape[:-3], n_est) if alpha is None else _finite("alpha", alpha)
    a = np.broadcast_to(a, p_i.shape[:-2])
    y_i = spd_inverse(p_i)
    gamma_inv = spd_inverse(np.einsum("...i,...ijk->...jk", a, p_i))
    fused_info = _spd("the fused ICI information matrix", y_i.sum(axis=-3) - (n_est - 1) * gamma_inv)
    cov = spd_inverse(fused_info)
    gains = cov[..., None, :, :] @ (y_i - (n_est - 1) * a[..., None, None] * gamma_inv[..., None, :, :])
    return cov, gains


def ici_fuse(means: Array, covs: Array, alpha: Array | None = None, check: bool = True,
             condition: str = "ball") -> GaussianState:
    """Multi-estimate ICI of N estimates ``(x_i, P_i)`` (Ajgl & Straka 2020; paper 2 eqs. 47-50):

    ``Gamma = sum alpha_i P_i``, ``P^-1 = sum P_i^-1 - (N - 1) Gamma^-1``,
    ``x = P [sum P_i^-1 x_i - (N - 1) Gamma^-1 sum alpha_i x_i]``.

    ``means`` ``(..., N, n)``, ``covs`` ``(..., N, n, n)``, ``alpha`` ``(..., N)`` (default uniform ``1/N``,
    the weights under which the rule is consistent for every common information). With ``check`` the weights
    must pass :func:`check_ici_weights` under ``condition``. ValueError on non-finite input, covariances that are
    not SPD, or a fused information matrix that is not positive definite. Returns ``(..., n)``, ``(..., n, n)``.
    """
    x_i = _finite("means", means)
    p_i = _spd("covs", covs)
    if p_i.ndim < 3 or x_i.shape != p_i.shape[:-1]:
        raise ValueError(f"means (..., N, n) and covs (..., N, n, n) do not match: {x_i.shape}, {p_i.shape}")
    n_est = p_i.shape[-3]
    a = _uniform(p_i.shape[:-3], n_est) if alpha is None else _finite("alpha", alpha)
    if a.shape[-1:] != (n_est,):
        raise ValueError(f"alpha must have N = {n_est} weights on its last axis, got shape {a.shape}")
    if check:
        check_ici_weights(a, condition=condition)
    a = np.broadcast_to(a, p_i.shape[:-2])
    y_i = spd_inverse(p_i)
    gamma_inv = spd_inverse(np.einsum("...i,...ijk->...jk", a, p_i))
    fused_info = _spd("the fused ICI information matrix",
                      symmetrize(y_i.sum(axis=-3) - (n_est - 1) * gamma_inv))
    info_vec = mat_vec(y_i, x_i).sum(axis=-2) - (n_est - 1) * mat_vec(gamma_inv, np.einsum("...i,...ij->...j", a, x_i))
    cov = spd_inverse(fused_info)
    return GaussianState(mat_vec(cov, info_vec), cov)


def ici_from_averages(y_bar: Array, yv_bar: Array, p_bar: Array, x_bar: Array, n_estimates: float | Array,
                      check: bool = True) -> InformationPair:
    """Distributed multi-estimate ICI at one node from its consensus averages (paper 2 eqs. 62-63):

    ``Y_F = N Ybar - (N - 1) Pbar^-1``, ``y_F = N ybar - (N - 1) Pbar^-1 xbar``,

    where ``Ybar, ybar, Pbar, xbar`` (``(..., n, n)``, ``(..., n)``, ``(..., n, n)``, ``(..., n)``) are the node's
    averages of the information pairs ``(Y_j, y_j)`` and the moments ``(P_j, x_j)``, and N (scalar or ``(...)``)
    the number of estimates. With exact averages this is :func:`ici_fuse` with uniform weights. With ``check``,
    ValueError on non-finite input, a ``Pbar`` that is not SPD (it is used symmetrised) or a fused information
    matrix that is not positive definite; without (the fusion rules in the simulator and the trackers: a
    diverged run's values reach the simulator's guard), the same formula on the arrays as given.
    """
    if check:
        y_mat, y_vec, p_mat = _finite("Ybar", y_bar), _finite("ybar", yv_bar), _spd("Pbar", p_bar)
        x_vec, n = _finite("xbar", x_bar), _finite("n_estimates", n_estimates)
        if np.any(n < 1):
            raise ValueError(f"n_estimates must be at least 1, got {n_estimates}")
    else:
        y_mat, y_vec, p_mat, x_vec, n = y_bar, yv_bar, p_bar, x_bar, np.asarray(n_estimates, dtype=float)
    p_inv = spd_inverse(p_mat)
    mat = symmetrize(n[..., None, None] * y_mat - (n[..., None, None] - 1.0) * p_inv)
    vec = n[..., None] * y_vec - (n[..., None] - 1.0) * mat_vec(p_inv, x_vec)
    return InformationPair(_spd("the fused ICI information matrix", mat) if check else mat, vec)


def effective_count(alpha: Array) -> Array:
    """``1 / max_j alpha_j`` per weight vector ``(..., N) -> (...)``: N for uniform weights, fewer as the weights
    concentrate. Passed as ``n_estimates`` to :func:`ici_from_averages` in place of N after finitely many consensus
    rounds (``alpha`` = the node's row of ``Pi^L``), it kept the distributed form consistent in every trial of
    ``tests/test_consensus_weights.py`` where N did not (empirical; see the module docstring)."""
    a = _finite("alpha", alpha)
    top = a.max(axis=-1)
    if np.any(top <= 0):
        raise ValueError("weights must have a positive entry")
    return 1.0 / top


# -------------------------------------------------------------------------------------------- two estimates

#: golden-section search: a grid of this many points over [0, 1] brackets the minimum, then this many steps
_OMEGA_GRID = 21
_GOLDEN_STEPS = 40
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


def _ici_two_info(a_inv: Array, b_inv: Array, a_cov: Array, b_cov: Array, omega: Array) -> tuple[Array, Array]:
    """``C^-1 = A^-1 + B^-1 - Gamma^-1`` and ``Gamma^-1`` for ``omega`` of shape ``(...)``.

    ``C^-1`` is positive definite for every omega in [0, 1]: the inverse is matrix-convex, so
    ``Gamma^-1 <= omega A^-1 + (1 - omega) B^-1`` and ``C^-1 >= (1 - omega) A^-1 + omega B^-1``.
    """
    w = omega[..., None, None]
    gamma_inv = symmetrize(np.linalg.inv(w * a_cov + (1.0 - w) * b_cov))
    return symmetrize(a_inv + b_inv - gamma_inv), gamma_inv


def _trace_cov(a_inv: Array, b_inv: Array, a_cov: Array, b_cov: Array, omega: Array) -> Array:
    """``tr C(omega)`` per batch element."""
    info, _ = _ici_two_info(a_inv, b_inv, a_cov, b_cov, omega)
    return np.trace(np.linalg.inv(info), axis1=-2, axis2=-1)


def _optimal_omega(a_inv: Array, b_inv: Array, a_cov: Array, b_cov: Array) -> Array:
    """``argmin_{omega in [0, 1]} tr C(omega)`` per batch element.

    ``C^-1(omega)`` is matrix-concave in omega (``-Gamma^-1`` is, the inverse being matrix-convex) and ``tr X^-1``
    convex and decreasing, so ``tr C`` is convex in omega: a grid brackets the minimum, a golden-section search
    on the bracket refines it (to ~5e-10), and the endpoints 0 and 1 are compared last.
    """
    batch = a_cov.shape[:-2]
    grid = np.linspace(0.0, 1.0, _OMEGA_GRID)
    vals = np.stack([_trace_cov(a_inv, b_inv, a_cov, b_cov, np.full(batch, g)) for g in grid], axis=-1)
    k = np.argmin(vals, axis=-1)
    lo = grid[np.maximum(k - 1, 0)]
    hi = grid[np.minimum(k + 1, _OMEGA_GRID - 1)]
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1 = _trace_cov(a_inv, b_inv, a_cov, b_cov, x1)
    f2 = _trace_cov(a_inv, b_inv, a_cov, b_cov, x2)
    for _ in range(_GOLDEN_STEPS):
        left = f1 <= f2  # minimum in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        new_x = np.where(left, hi - _INV_PHI * (hi - lo), lo + _INV_PHI * (hi - lo))
        new_f = _trace_cov(a_inv, b_inv, a_cov, b_cov, new_x)
        x1, x2, f1, f2 = (np.where(left, new_x, x2), np.where(left, x1, new_x),
                          np.where(left, new_f, f2), np.where(left, f1, new_f))
    best = 0.5 * (lo + hi)
    f_best = _trace_cov(a_inv, b_inv, a_cov, b_cov, best)
    for edge in (0.0, 1.0):
        f_edge = _trace_cov(a_inv, b_inv, a_cov, b_cov, np.full(batch, edge))
        better = f_edge <= f_best
        best = np.where(better, edge, best)
        f_best = np.where(better, f_edge, f_best)
    return best


def ici_fuse_two(a: Array, a_cov: Array, b: Array, b_cov: Array, omega: float | Array | None = None
                 ) -> tuple[GaussianState, Array]:
    """Two-estimate ICI (Noack et al. 2017): ``Gamma = omega A + (1 - omega) B``,
    ``C^-1 = A^-1 + B^-1 - Gamma^-1``, ``C^-1 c = A^-1 a + B^-1 b - Gamma^-1 (omega a + (1 - omega) b)``.

    ``a, b`` ``(..., n)``, ``A, B`` ``(..., n, n)``; ``omega`` scalar or ``(...)`` in [0, 1], or None to minimise
    ``tr C`` over [0, 1] per batch element (convex in omega; golden-section search). Returns the fused state and
    omega ``(...)``. ValueError on non-finite input, non-SPD covariances or omega outside [0, 1].
    """
    xa, xb = _finite("a", a), _finite("b", b)
    pa, pb = _spd("A", a_cov), _spd("B", b_cov)
    batch = np.broadcast_shapes(pa.shape[:-2], pb.shape[:-2], xa.shape[:-1], xb.shape[:-1])
    n = pa.shape[-1]
    if pb.shape[-1] != n or xa.shape[-1] != n or xb.shape[-1] != n:
        raise ValueError(f"dimensions do not match: a {xa.shape}, A {pa.shape}, b {xb.shape}, B {pb.shape}")
    pa, pb = np.broadcast_to(pa, batch + (n, n)), np.broadcast_to(pb, batch + (n, n))
    xa, xb = np.broadcast_to(xa, batch + (n,)), np.broadcast_to(xb, batch + (n,))
    a_inv, b_inv = spd_inverse(pa), spd_inverse(pb)
    if omega is None:
        w = _optimal_omega(a_inv, b_inv, pa, pb)
    else:
        w = np.broadcast_to(_finite("omega", omega), batch).astype(float)
        if np.any((w < 0) | (w > 1)):
            raise ValueError(f"omega must lie in [0, 1], got {np.asarray(omega)}")
    info, gamma_inv = _ici_two_info(a_inv, b_inv, pa, pb, w)
    info = _spd("the fused ICI information matrix", info)
    vec = mat_vec(a_inv, xa) + mat_vec(b_inv, xb) - mat_vec(gamma_inv, w[..., None] * xa + (1.0 - w[..., None]) * xb)
    cov = spd_inverse(info)
    return GaussianState(mat_vec(cov, vec), cov), w

