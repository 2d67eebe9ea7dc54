"""Square-root cubature information filter (SRCIF) of paper 2 Section 2.2 (Chandra, Gu & Postlethwaite 2013).

The local estimator of every UAV in DCE-ICI (paper 2): a cubature filter whose time update propagates a
square root of the covariance and whose measurement update is written in information form, so that the
scans of the node itself and of its neighbours (each with its own sensor pose and noise) enter as a *sum*
of information contributions computed from the same prior.  The paper's equations were lost in the text
dump; the algorithm below follows Chandra, Gu & Postlethwaite, "Square root cubature information filter",
IEEE Sensors Journal 13(2), 2013, and the reconstruction in ``papers/002-dce-ici.md``.

Notation: ``n`` state dimension, cubature points ``xi_l = +-sqrt(n) e_l`` with weights ``w = 1/(2n)``
(:func:`~zentrack.fusion.filters.sigma_point.cubature_points`), ``Tria(A)`` the lower-triangular ``S`` with
``S S^T = A A^T`` obtained from a QR decomposition of ``A^T`` (:func:`tria`).

Time update (paper 2 Sec. 2.2.2; Chandra 2013 eqs. 20-24)::

    X_l = x + S xi_l,  X*_l = f(X_l),  x- = sum_l w X*_l
    Xcal* = [X*_1 - x-, ..., X*_2n - x-] / sqrt(2n)
    S-    = Tria([Xcal*, S_Q])                      (Q = S_Q S_Q^T, S_Q may be rank deficient)

Measurement update of sensor ``s`` (paper 2 Sec. 2.2.3; Chandra 2013 eqs. 25-34)::

    Y- = (S- S-^T)^-1,  y- = Y- x-,  S_Y- = S-^-T
    X_l = x- + S- xi_l,  Z_l = h(X_l, p_s),  z^_s = sum_l w Z_l      (angles averaged around h(x-))
    P_xz = Xcal Zcal^T = sum_l w (X_l - x-)(Z_l - z^_s)^T
    I_s = Y- P_xz R_s^-1 P_xz^T Y-,   i_s = Y- P_xz R_s^-1 (nu_s + P_xz^T y-),   nu_s = W(z_s - z^_s)
    Y = Y- + sum_s I_s,  y = y- + sum_s i_s                          (paper 2: own + neighbours' scans)
    S_Y = Tria([S_Y-, Y- P_xz S_R,1^-T, ..., Y- P_xz S_R,S^-T])      (R_s = S_R,s S_R,s^T)

Equivalently ``H_s = P_xz^T Y-`` is the statistical linearisation of ``h`` and ``I_s = H_s^T R_s^-1 H_s``:
the update is the Kalman update of the linear model ``z_s ~ H_s x``.  Its implied innovation covariance
``H_s P- H_s^T + R_s`` leaves out the part of the sampled ``Pzz`` that ``H_s`` does not explain, so for a
nonlinear ``h`` the SRCIF is (slightly) more confident than the CKF; for linear ``h`` the two are equal.
Because every contribution uses the same prior, stacking sensors equals summing their contributions.

Numerics.  ``Y- P_xz`` is formed as ``S-^-T (sum_l w xi_l (Z_l - z^)^T)`` (``P_xz = S- sum_l w xi_l dZ_l^T``),
so no covariance is ever inverted, only triangular factors.  The posterior is returned in covariance form
from the information square root: ``P = S_Y^-T S_Y^-1`` and ``x = Y^-1 y`` evaluated as
``x- + P sum_s H_s^T R_s^-1 nu_s`` (identical, since ``i_s - I_s x- = H_s^T R_s^-1 nu_s``, but free of the
cancellation in ``Y^-1 y`` when positions are kilometres and ``Y`` is large).  A sensor padded with noise
``1e16 I`` contributes ``~1e-16 H^T H`` and changes nothing.  The noise matrix is taken block diagonal
(one ``m x m`` block per sensor, the sensors' noises are independent); off-diagonal blocks are ignored.

The estimate crosses the :class:`~zentrack.fusion.filters.base.LocalFilter` interface as an ordinary
:class:`~zentrack.fusion.linalg.GaussianState`, so each step starts from a Cholesky factor of the exported
covariance (the square root is an internal detail, as the fusion rules act on covariances).  A covariance
that is not numerically positive definite (e.g. after fusion) is factored through its eigen-decomposition
with eigenvalues floored at a tiny positive value instead of failing.
"""
from __future__ import annotations

import numpy as np

from ..linalg import GaussianState, InformationPair, lower_triangular_inverse, mat_vec, symmetrize
from ..measurement import MeasurementModel
from ..motion import MotionModel
from .base import FILTER_REGISTRY, FilterContext, LocalFilter
from .sigma_point import cubature_points, weighted_cov

Array = np.ndarray

#: eigenvalues of a covariance that is not positive definite are floored at this fraction of the largest
EIG_FLOOR = 1e-12


def tria(a: Array) -> Array:
    """``Tria(A)``: lower-triangular ``S`` ``(..., n, n)`` with ``S S^T = A A^T`` for ``A`` ``(..., n, k)``.

    From the QR decomposition ``A^T = Q R``: ``A A^T = R^T R``, so ``S = R^T`` with the signs of the columns
    chosen to make the diagonal non-negative (then ``S`` is the Cholesky factor of ``A A^T``).
    """
    n, k = a.shape[-2], a.shape[-1]
    if k < n:  # QR needs at least n rows in A^T: zero columns do not change A A^T
        a = np.concatenate([a, np.zeros(a.shape[:-1] + (n - k,))], axis=-1)
    r = np.linalg.qr(np.swapaxes(a, -1, -2), mode="r")
    sign = np.where(np.diagonal(r, axis1=-2, axis2=-1) < 0.0, -1.0, 1.0)
    return np.swapaxes(r, -1, -2) * sign[..., None, :]


def sqrt_factor(cov: Array) -> Array:
    """Lower-triangular square roots ``(..., n, n)`` of a stack of covariances.

    Cholesky when the whole stack is positive definite; otherwise an eigen-decomposition square root with
    eigenvalues floored at ``EIG_FLOOR`` times the largest (made triangular by :func:`tria`).  Members that
    are not finite get NaN factors, so a diverged member stays NaN (the simulator's divergence guard sees it)
    instead of stopping the whole stack.
    """
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        finite = np.all(np.isfinite(cov), axis=(-1, -2))[..., None, None]
        vals, vecs = np.linalg.eigh(np.where(finite, symmetrize(cov), np.eye(cov.shape[-1])))
        floor = EIG_FLOOR * np.maximum(vals[..., -1:], np.finfo(float).tiny)
        return np.where(finite, tria(vecs * np.sqrt(np.maximum(vals, floor))[..., None, :]), np.nan)


def noise_square_root(motion: MotionModel) -> Array:
    """``S_Q`` ``(n, q)`` with ``Q = S_Q S_Q^T``: the motion's ``noise_factor`` when it has one, else a Cholesky
    factor of ``Q``, else (``Q`` singular) ``V sqrt(max(Lambda, 0))`` from its eigen-decomposition."""
    n = motion.dim
    factor = getattr(motion, "noise_factor", None)
    if factor is not None:
        s_q = np.asarray(factor, dtype=float)
        s_q = s_q.reshape(n, -1) if s_q.ndim == 1 else s_q
        if s_q.ndim != 2 or s_q.shape[0] != n:
            raise ValueError(f"motion {motion.name!r}: noise_factor must be (n, q) with n = {n}, got {s_q.shape}")
        return s_q
    q = symmetrize(np.asarray(motion.Q, dtype=float))
    try:
        return np.linalg.cholesky(q)
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(q)
        return vecs * np.sqrt(np.maximum(vals, 0.0))


class SquareRootCubatureInformationFilter(LocalFilter):
    """SRCIF on stacks of estimates (paper 2 Sec. 2.2; see the module docstring for the equations).

    ``update`` takes the scans of ``S`` sensors stacked: ``z`` ``(B, S*m)``, ``sensors`` ``(B, S, 3)`` and
    a block-diagonal ``noise_cov`` ``(B, S*m, S*m)`` (or ``(S*m, S*m)`` shared by the batch).
    """

    def __init__(self, motion: MotionModel, measurement: MeasurementModel, name: str = "srcif") -> None:
        self.motion = motion
        self.measurement = measurement
        self.points = cubature_points(motion.dim)
        self.noise_sqrt = noise_square_root(motion)
        self.name = name
        self.state_dim = self.kinematic_dim = motion.dim

    def _points(self, mean: Array, sqrt: Array) -> Array:
        """Cubature points ``(B, 2n, n)``: ``x + S xi_l`` (as :func:`~.sigma_point.sigma_points`, given ``S``)."""
        return mean[:, None, :] + self.points.offsets @ np.swapaxes(sqrt, -1, -2)

    def predict(self, state: GaussianState) -> GaussianState:
        """Time update (paper 2 Sec. 2.2.2): propagated cubature points, ``S- = Tria([Xcal*, S_Q])``."""
        pts = self._points(state.mean, sqrt_factor(state.cov))
        b, p, n = pts.shape
        prop = self.motion.f(pts.reshape(b * p, n)).reshape(b, p, n)
        mean = np.einsum("p,bpn->bn", self.points.wm, prop)
        centred = (prop - mean[:, None, :]) * np.sqrt(self.points.wc)[:, None]  # rows of Xcal*^T: dX / sqrt(2n)
        s_q = np.broadcast_to(self.noise_sqrt, (b,) + self.noise_sqrt.shape)
        sqrt = tria(np.concatenate([np.swapaxes(centred, -1, -2), s_q], axis=-1))
        return GaussianState(mean, symmetrize(sqrt @ np.swapaxes(sqrt, -1, -2)))

    def _whitened(
        self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array
    ) -> tuple[Array, Array, Array]:
        """The prior information square root and the whitened contributions of every sensor.

        Returns ``S_Y-`` ``(B, n, n)`` (``= S-^-T``), ``W`` ``(B, S, n, m)`` with ``W_s = Y- P_xz,s S_R,s^-T``
        (so ``I_s = W_s W_s^T``) and ``a`` ``(B, S, m)`` with ``a_s = S_R,s^-1 nu_s`` (whitened innovation).
        """
        meas = self.measurement
        mean = state.mean
        sqrt = sqrt_factor(state.cov)
        sqrt_inv = lower_triangular_inverse(sqrt)
        pts = self._points(mean, sqrt)
        b, p, n = pts.shape
        n_sens = sensors.shape[1]
        zs = meas.h(pts.reshape(b * p, n), np.repeat(sensors, p, axis=0)).reshape(b, p, -1)
        ref = meas.h(mean, sensors)
        z_mean = ref + np.einsum("p,bpm->bm", self.points.wm, meas.residual(zs, ref[:, None, :]))
        dz = meas.residual(zs, z_mean[:, None, :])
        m = dz.shape[-1] // n_sens
        # S-^-1 P_xz = sum_l w xi_l dZ_l^T, then Y- P_xz = S-^-T (S-^-1 P_xz): no covariance is inverted
        unit_cross = weighted_cov(self.points.wc, np.broadcast_to(self.points.offsets, pts.shape), dz)
        ht = np.swapaxes(sqrt_inv, -1, -2) @ unit_cross  # (B, n, S*m): H^T = Y- P_xz
        ht = ht.reshape(b, n, n_sens, m).transpose(0, 2, 1, 3)  # (B, S, n, m)
        r = np.broadcast_to(noise_cov, (b, n_sens * m, n_sens * m)).reshape(b, n_sens, m, n_sens, m)
        idx = np.arange(n_sens)
        r_blocks = np.moveaxis(r[:, idx, :, idx, :], 0, 1)  # (B, S, m, m): the diagonal blocks R_s
        r_sqrt_inv = lower_triangular_inverse(np.linalg.cholesky(symmetrize(r_blocks)))  # S_R,s^-1
        w = ht @ np.swapaxes(r_sqrt_inv, -1, -2)  # Y- P_xz,s S_R,s^-T
        nu = meas.residual(z, z_mean).reshape(b, n_sens, m)
        a = mat_vec(r_sqrt_inv, nu)
        return np.swapaxes(sqrt_inv, -1, -2), w, a

    def contributions(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> InformationPair:
        """Per-sensor information contributions ``I_s`` ``(B, S, n, n)`` and ``i_s`` ``(B, S, n)`` of the scans
        (paper 2 Sec. 2.2.3) for the prior ``state``; the posterior is ``(Y- + sum I_s, y- + sum i_s)``."""
        b, n = state.mean.shape
        if sensors.shape[1] == 0:
            return InformationPair(np.zeros((b, 0, n, n)), np.zeros((b, 0, n)))
        _, w, a = self._whitened(state, z, sensors, noise_cov)
        mat = w @ np.swapaxes(w, -1, -2)
        # i_s = W_s S_R,s^-1 (nu_s + P_xz^T y-) = W_s (a_s + W_s^T x-)
        vec = mat_vec(w, a + np.einsum("bsnm,bn->bsm", w, state.mean))
        return InformationPair(mat, vec)

    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> GaussianState:
        """Information-form correction with ``S`` stacked scans (paper 2 Sec. 2.2.3), square root by QR."""
        if sensors.shape[1] == 0:  # no scan: the posterior is the prior
            return state.copy()
        s_y_prior, w, a = self._whitened(state, z, sensors, noise_cov)
        b, n_sens, n, m = w.shape
        w_all = w.transpose(0, 2, 1, 3).reshape(b, n, n_sens * m)
        s_y = tria(np.concatenate([s_y_prior, w_all], axis=-1))  # S_Y = Tria([S_Y-, W_1, ..., W_S])
        s_y_inv = lower_triangular_inverse(s_y)
        cov = symmetrize(np.swapaxes(s_y_inv, -1, -2) @ s_y_inv)  # P = Y^-1 = S_Y^-T S_Y^-1
        # x = Y^-1 y = x- + Y^-1 sum_s H_s^T R_s^-1 nu_s  (H_s^T R_s^-1 nu_s = W_s a_s)
        mean = state.mean + mat_vec(cov, mat_vec(w_all, a.reshape(b, n_sens * m)))
        return GaussianState(mean, cov)


def _srcif(context: FilterContext) -> SquareRootCubatureInformationFilter:
    if context.measurement is None:
        raise ValueError("local filter 'srcif' needs a measurement model")
    return SquareRootCubatureInformationFilter(context.motion, context.measurement)


FILTER_REGISTRY.register(
    "srcif",
    _srcif,
    (),
    "square-root cubature information filter (paper 2 section 2.2): own and neighbours' scans as summed "
    "information contributions",
)
