"""Batched linear-algebra building blocks shared by every filter and fusion rule.

All functions take stacks of vectors ``(..., n)`` and matrices ``(..., n, n)`` so the same code runs one node
(a batch of one), all nodes of a network, or all nodes of many Monte Carlo runs at once; the ``*_one`` functions
are the tracker's cases on one matrix, computed with the same kernels so the results are the same bits.

LAPACK is reached through numpy's own gufuncs (``numpy.linalg._umath_linalg``: ``inv``, ``cholesky_lo``,
``solve1``), the very functions ``numpy.linalg.inv``/``cholesky``/``solve`` call after their Python-level
argument handling (``_makearray``, ``_commonType``, ``astype``), which costs more than the LAPACK call itself on a
12x12 matrix. The gufuncs take float64 arrays and report a failed factorisation as an "invalid" floating-point
flag with NaN output: :func:`inverse` turns the flag into ``LinAlgError`` exactly as ``numpy.linalg.inv`` does,
the ``*_one`` functions into ``None``. The module has been numpy's private home of these gufuncs since numpy 1.8
(names and signatures unchanged through numpy 2.x); if it is missing, the public functions are used.
"""
from __future__ import annotations

import importlib.machinery
import importlib.util
import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

Array = np.ndarray


def _raise_singular(err: str, flag: int) -> None:
    raise np.linalg.LinAlgError("Singular matrix")


try:  # numpy's LAPACK gufuncs (see the module docstring)
    from numpy.linalg import _umath_linalg as _gufuncs

    _inv_gufunc: Any = _gufuncs.inv
    _cholesky_gufunc: Any = _gufuncs.cholesky_lo
    _solve1_gufunc: Any = _gufuncs.solve1
except (ImportError, AttributeError):  # pragma: no cover - a numpy without them: the public functions

    def _inv_gufunc(m: Array, signature: str = "d->d") -> Array:  # raises LinAlgError itself
        return np.linalg.inv(m)

    def _cholesky_gufunc(m: Array, signature: str = "d->d") -> Array:
        try:
            return np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            return np.full_like(m, np.nan)

    def _solve1_gufunc(a: Array, b: Array, signature: str = "dd->d") -> Array:
        try:
            return np.linalg.solve(a, b)
        except np.linalg.LinAlgError:
            return np.full_like(b, np.nan)


#: numpy.linalg's error state around its gufuncs: a failed factorisation raises LinAlgError
_raising = np.errstate(call=_raise_singular, invalid="call", over="ignore", divide="ignore", under="ignore")
#: the error state of the ``*_one`` functions, which report a failed factorisation as None
_quiet_linalg = np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore")


@_raising
def inverse(m: Array) -> Array:
    """``M^-1`` of a matrix or stack (LU, LAPACK ``gesv``): ``numpy.linalg.inv``'s own gufunc, so the same bits and
    the same ``LinAlgError`` on a singular matrix, without its Python wrapper (half its cost on one 12x12)."""
    return _inv_gufunc(m, signature="d->d")


class _Lapack:
    """SciPy's LAPACK wrappers (``scipy.linalg.lapack.dpotrf`` etc.), loaded on first use without importing the
    ``scipy.linalg`` package.

    ``from scipy.linalg import lapack`` runs ``scipy.linalg/__init__``, which imports all of ``scipy.linalg``
    and SciPy's array-API layer (with it ``numpy.f2py``): about 0.13 s and 20 MB of a tracker's start, for the
    three routines it calls (``potrf``, ``potrs``, ``trtrs`` on one small matrix). The routines live in the
    extension module ``scipy.linalg._flapack``, which needs only numpy: it is loaded from its file alone, and
    ``scipy.linalg.lapack`` re-exports those very functions, so the results are the same bits. If
    ``scipy.linalg`` is already imported, or SciPy's layout differs, the public module is used.

    Nothing in ``zentrack.fusion`` calls it any more (numpy's gufuncs do the tracker's factorisations, so a
    tracker need not map SciPy's OpenBLAS and libgfortran); it stays for callers outside the package."""

    def __init__(self) -> None:
        self._module: ModuleType | None = None

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        if self._module is None:
            self._module = _load_flapack()
        value = getattr(self._module, name)
        setattr(self, name, value)  # later lookups are plain attribute reads
        return value


def _load_flapack() -> Any:
    import scipy

    loaded = vars(scipy).get("linalg")  # scipy.linalg, if someone imported it
    if loaded is None:
        try:
            spec = importlib.machinery.PathFinder.find_spec("scipy.linalg._flapack", [f"{scipy.__path__[0]}/linalg"])
            if spec is not None and spec.loader is not None:
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                return module
        except (ImportError, OSError, AttributeError, IndexError):
            pass
    from scipy.linalg import lapack

    return lapack


#: LAPACK's routines as ``scipy.linalg.lapack`` has them (``lapack.dpotrf(...)``), loaded on first use
lapack: Any = _Lapack()


@dataclass
class GaussianState:
    """A stack of Gaussian estimates: ``mean`` is ``(B, n)``, ``cov`` is ``(B, n, n)``."""

    mean: Array
    cov: Array

    def copy(self) -> GaussianState:
        return GaussianState(self.mean.copy(), self.cov.copy())


@dataclass
class InformationPair:
    """A stack of information pairs ``(Y, y) = (P^-1, P^-1 x)``: ``matrix`` ``(B, n, n)``, ``vector`` ``(B, n)``."""

    matrix: Array
    vector: Array


def symmetrize(m: Array) -> Array:
    """Return ``(M + M^T) / 2`` over the last two axes."""
    return 0.5 * (m + np.swapaxes(m, -1, -2))


def mat_vec(m: Array, v: Array) -> Array:
    """Batched matrix-vector product ``M v`` for ``(..., a, b)`` and ``(..., b)``."""
    return (m @ v[..., None])[..., 0]


def congruence(a: Array, p: Array) -> Array:
    """``A P A^T`` for stacks (``A`` may be a single matrix)."""
    return a @ p @ np.swapaxes(a, -1, -2)


#: stacks at least this large are inverted through Cholesky (faster than LU per matrix on large stacks)
CHOLESKY_INVERSE_MIN_BATCH = 64


def spd_inverse(m: Array, symmetric: bool = True) -> Array:
    """Inverse of a stack of symmetric positive definite matrices (symmetrised unless ``symmetric=False``).

    Small stacks use LAPACK's LU inverse; large ones (Monte Carlo batches) use a Cholesky factor and a
    blocked triangular inverse, which costs about half as much per matrix.
    """
    batch = math.prod(m.shape[:-2])
    if batch < CHOLESKY_INVERSE_MIN_BATCH or m.shape[-1] < 4:
        inv = inverse(m)
        return symmetrize(inv) if symmetric else inv
    l_inv = lower_triangular_inverse(np.linalg.cholesky(m))
    return np.swapaxes(l_inv, -1, -2) @ l_inv  # P^-1 = L^-T L^-1 (symmetric by construction)


def lower_triangular_inverse(low: Array) -> Array:
    """Inverse of a stack of lower-triangular matrices by 2x2 block recursion (3x3 and smaller in closed form)."""
    n = low.shape[-1]
    if n <= 3:
        return _small_lower_inverse(low)
    h = n // 2
    i11 = lower_triangular_inverse(low[..., :h, :h])
    i22 = lower_triangular_inverse(low[..., h:, h:])
    out = np.zeros_like(low)
    out[..., :h, :h] = i11
    out[..., h:, h:] = i22
    out[..., h:, :h] = -(i22 @ (low[..., h:, :h] @ i11))
    return out


def _small_lower_inverse(low: Array) -> Array:
    n = low.shape[-1]
    out = np.zeros_like(low)
    d = [1.0 / low[..., i, i] for i in range(n)]
    for i in range(n):
        out[..., i, i] = d[i]
    if n >= 2:
        out[..., 1, 0] = -low[..., 1, 0] * d[0] * d[1]
    if n == 3:
        out[..., 2, 1] = -low[..., 2, 1] * d[1] * d[2]
        out[..., 2, 0] = (low[..., 1, 0] * low[..., 2, 1] * d[1] - low[..., 2, 0]) * d[0] * d[2]
    return out


@_quiet_linalg
def cholesky_one(m: Array) -> Array | None:
    """The lower Cholesky factor of one symmetric matrix ``(n, n)`` (its lower triangle is read), or None if it is
    not positive definite.

    numpy's ``cholesky_lo`` gufunc (LAPACK ``potrf``) called directly: a third of the cost of
    ``numpy.linalg.cholesky`` on one small matrix. None when ``potrf`` fails (``info > 0``), which the gufunc
    reports by a NaN factor, and when ``m[0, 0]`` is NaN (the factor's first entry is its square root): the
    verdict of ``numpy.linalg.cholesky`` (and of SciPy's ``dpotrf``), stricter on a NaN first pivot. Like
    ``potrf``, it does not reliably refuse a NaN elsewhere: callers that may hold one check finiteness."""
    low = _cholesky_gufunc(m, signature="d->d")
    return None if low[0, 0] != low[0, 0] else low


@_quiet_linalg
def spd_mean_cov_one(matrix: Array, vector: Array) -> tuple[Array, Array] | None:
    """``(M^-1 v, M^-1)`` of one symmetric ``(n, n)`` matrix and ``(n,)`` vector, or None if ``M`` is not positive
    definite (the Cholesky factor's verdict of :func:`cholesky_one`; the inverse is LU's, :func:`inverse`)."""
    low = _cholesky_gufunc(matrix, signature="d->d")
    if low[0, 0] != low[0, 0]:
        return None
    inv = _inv_gufunc(matrix, signature="d->d")
    return inv @ vector, inv


@_quiet_linalg
def spd_quadratic_form_one(m: Array, v: Array) -> float | None:
    """``v^T M^-1 v`` for one symmetric ``(n, n)`` ``M`` and ``(n,)`` ``v`` as ``z^T z`` with ``z = L^-1 v``,
    ``M = L L^T``; None if ``M`` is not positive definite (:func:`cholesky_one`'s verdict)."""
    low = _cholesky_gufunc(m, signature="d->d")
    if low[0, 0] != low[0, 0]:
        return None
    z = _solve1_gufunc(low, v, signature="dd->d")
    return float(z @ z)


def to_information(state: GaussianState) -> InformationPair:
    """``(P, x) -> (P^-1, P^-1 x)`` (paper 0 Algorithm 2 line 9, the broadcast pair)."""
    y_mat = spd_inverse(state.cov, symmetric=False)
    return InformationPair(y_mat, mat_vec(y_mat, state.mean))


def from_information(pair: InformationPair) -> GaussianState:
    """``(Y, y) -> (Y^-1, Y^-1 y)`` (paper 0 Algorithm 2 line 10, after mixing)."""
    cov = spd_inverse(pair.matrix)
    return GaussianState(mat_vec(cov, pair.vector), cov)


_SIGN2 = np.array([[1.0, -1.0], [-1.0, 1.0]])


def small_inverse(s: Array) -> Array:
    """Inverse of a stack of small matrices: 1x1 and 2x2 in closed form (adjugate), larger ones via LAPACK.

    The innovation covariance of one bearing sensor (2x2) is inverted this way: on stacks of hundreds it is
    several times faster than a batched LAPACK call.
    """
    m = s.shape[-1]
    if m == 1:
        return 1.0 / s
    if m == 2:
        if s.ndim == 2:
            one = _inverse_2x2_one(s)
            if one is not None:
                return one
        det = s[..., 0, 0] * s[..., 1, 1] - s[..., 0, 1] * s[..., 1, 0]
        adj = np.swapaxes(s[..., ::-1, ::-1], -1, -2) * _SIGN2  # [[d, -b], [-c, a]]
        return adj / det[..., None, None]
    return inverse(s)


def _inverse_2x2_one(s: Array) -> Array | None:
    """:func:`small_inverse`'s adjugate formula on one 2x2 float matrix in Python floats: the same IEEE operations
    in the same order (``det = a d - b c``, each entry of ``[[d, -b], [-c, a]]`` divided by ``det``), so the same
    bits, without a dozen numpy calls on four numbers. None for a zero determinant (Python raises where numpy
    gives infinities: the caller's numpy formula handles it) or a matrix that is not float64."""
    if s.dtype != np.float64:
        return None
    (a, b), (c, d) = s.tolist()
    det = a * d - b * c
    if det == 0.0:
        return None
    return np.array([[d / det, -b / det], [-c / det, a / det]])


_EYES: dict[int, Array] = {}


def _eye(n: int) -> Array:
    if n not in _EYES:
        _EYES[n] = np.eye(n)
    return _EYES[n]


def joseph_update(
    state: GaussianState, jac: Array, innovation: Array, noise_cov: Array
) -> GaussianState:
    """Kalman measurement update in Joseph form (paper 0 Algorithm 1 line 7).

    ``jac`` is ``(B, m, n)``, ``innovation`` ``(B, m)`` (already wrapped where angular), ``noise_cov``
    ``(B, m, m)`` or ``(m, m)``.  G = P C^T (C P C^T + R)^-1; x+ = x + G nu;
    P+ = (I - G C) P (I - G C)^T + G R G^T.
    """
    if state.cov.shape[0] == 1 and jac.shape[0] == 1:
        return _joseph_update_one(state, jac, innovation, noise_cov)
    p = state.cov
    pct = p @ np.swapaxes(jac, -1, -2)
    s = jac @ pct + noise_cov
    gain = pct @ small_inverse(s)
    mean = state.mean + mat_vec(gain, innovation)
    i_gc = _eye(p.shape[-1]) - gain @ jac
    cov = congruence(i_gc, p) + congruence(gain, np.broadcast_to(noise_cov, s.shape))
    return GaussianState(mean, symmetrize(cov))


def _joseph_update_one(state: GaussianState, jac: Array, innovation: Array, noise_cov: Array) -> GaussianState:
    """:func:`joseph_update` for a batch of one (a tracker): the same products on 2-D arrays (the same matmul
    kernels, so the same bits) without the stacked transposes and broadcasts, about 40 % less numpy overhead."""
    p, c, r = state.cov[0], jac[0], noise_cov[0] if noise_cov.ndim == 3 else noise_cov
    pct = p @ c.T
    s = c @ pct + r
    gain = pct @ small_inverse(s)
    mean = state.mean[0] + (gain @ innovation[0][:, None])[:, 0]
    i_gc = _eye(p.shape[-1]) - gain @ c
    cov = i_gc @ p @ i_gc.T + gain @ r @ gain.T
    return GaussianState(mean[None], (0.5 * (cov + cov.T))[None])


def covariance_update(
    state: GaussianState, cross_cov: Array, innov_cov: Array, innovation: Array
) -> GaussianState:
    """Kalman update from moments (sigma-point filters): K = Pxz S^-1, x+ = x + K nu, P+ = P - K S K^T."""
    gain = cross_cov @ small_inverse(innov_cov)
    mean = state.mean + mat_vec(gain, innovation)
    cov = state.cov - congruence(gain, innov_cov)
    return GaussianState(mean, symmetrize(cov))


def is_spd(m: Array) -> Array:
    """Boolean per matrix of the stack: symmetric (to 1e-9 relative) and positive definite."""
    m = np.asarray(m, dtype=float)
    scale = np.maximum(np.abs(m).max(axis=(-1, -2)), 1e-300)
    finite = np.all(np.isfinite(m), axis=(-1, -2))
    sym = np.abs(m - np.swapaxes(m, -1, -2)).max(axis=(-1, -2)) <= 1e-9 * scale
    safe = np.where(finite[..., None, None], symmetrize(m), np.eye(m.shape[-1]))
    eig_min = np.linalg.eigvalsh(safe)[..., 0]
    return finite & sym & (eig_min > 0)
