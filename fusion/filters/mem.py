"""MEM-EKF* and the extended-object information filter of paper 4 (multiplicative error model, point returns).

An elliptical (or rectangular) object with centre ``m``, velocity, orientation ``alpha`` and semi-axes
``l1``, ``l2`` produces point returns (paper 4 eq. 3)::

    y = H x + S h + v,   S = R(alpha) diag(l1, l2),   H = [I2 0],   h ~ (0, C^h),   v ~ N(0, C^v).

The state is split into the kinematics ``x = [m1, m2, v1, v2]`` and the extent ``p = [alpha, l1, l2]``; the
filters here keep the 7-vector ``[x, p]`` with a block-diagonal covariance.  Everything is batched over a
leading axis B (nodes x runs); a loop over the J points of a scan is the only Python loop.

**Pseudo-linear models** (paper 4 Sec. 3; Yang & Baum 2019, MEM-EKF*).  Around the current estimate
(superscript ``[i-1]``), with ``S1``, ``S2`` the rows of ``S`` and ``J1``, ``J2`` their Jacobians in ``p``
(Prop. 1, notes "Pseudo-linear models")::

    J1 = [[-l1 sin a, cos a, 0], [-l2 cos a, 0, -sin a]],   J2 = [[l1 cos a, sin a, 0], [-l2 sin a, 0, cos a]]
    y ~ H x + v^x,      R^x = C^I + C^II + C^v,  C^I = S C^h S^T (7),  C^II_mn = tr(C^p J_n^T C^h J_m) (8)
    C^y = H C^x H^T + R^x                                                            (10)
    Y = F((y - H x)(x)(y - H x)) = [Y1^2, Y2^2, Y1 Y2]                               (11), F (12)
    Y ~ M p + v^p,      E v^p = F vect(C^y) - M p,   R^p = C_Y - M C^p M^T            (13)
    C_Y = F (C^y (x) C^y)(F + Ftilde)^T                                              (13), Ftilde (14)
    M = [2 S1 C^h J1; 2 S2 C^h J2; S1 C^h J2 + S2 C^h J1]                            (15)

The pseudo-measurement and ``C^y`` use the kinematic estimate *before* this point (``x^[i-1]``, ``C^x[i-1]``),
exactly as MEM-EKF* does: the kinematic and extent corrections of one point are both computed from the same
prior, and ``R^x`` uses the extent prior.

**MEM-EKF*** (:func:`mem_point_update`, notes "Single-sensor update equals MEM-EKF*")::

    x+ = x + C^x H^T (C^y)^-1 (y - H x),        C^x+ = C^x - C^x H^T (C^y)^-1 H C^x
    p+ = p + C^p M^T C_Y^-1 (Y - F vect(C^y)),  C^p+ = C^p - C^p M^T C_Y^-1 M C^p

written in Joseph form (``(I - K H) C (I - K H)^T + K R K^T``, the same numbers for the optimal gain but
symmetric PSD in floating point).

**R^p guard.**  ``R^p = C_Y - M C^p M^T`` is a difference of two moment approximations; nothing in the paper
guarantees it is positive definite, and where it is not, the MEM-EKF* extent covariance above loses positive
definiteness too (``C^p+ >= 0`` iff ``R^p >= 0``).  Measured: over 8e5 random priors (scales over eight decades,
extreme aspect ratios) and an adversarial search, the smallest eigenvalue of the whitened
``C_Y^-1/2 R^p C_Y^-1/2`` never went below -1e-9 (rounding at degenerate inputs), and in runs of the paper's
S2 (lambda = 5, 10) it stayed above 0.16.  :func:`rp_matrix` symmetrises ``R^p`` and raises the whitened eigenvalues to
``rp_floor`` (default 1e-9), i.e. ``R^p_g >= rp_floor C_Y``.  Both filters use the *guarded* model
``Y = M p + v^p, Cov v^p = R^p_g`` (innovation covariance ``C_Yg = M C^p M^T + R^p_g``), so the covariance
form and the information form stay equal; where the guard is inactive ``R^p_g = R^p``, ``C_Yg = C_Y`` bit for
bit and the update is exactly MEM-EKF*.

**Information form** (paper 4 Sec. 4, eqs. 18-19; CI eqs. 22-23; CM eq. 25), with ``V^x = (R^x)^-1``,
``V^p = (R^p_g)^-1`` and ``Ytilde = Y - F vect(C^y) + M p^[i-1]``::

    q^x += H^T V^x y,       Omega^x += H^T V^x H
    q^p += M^T V^p Ytilde,  Omega^p += M^T V^p M

For one point this is the Kalman update of the linear models (6) and (13): the kinematic block equals the
MEM-EKF* kinematic update exactly, the extent block equals the (guarded) MEM-EKF* extent update exactly
(matrix inversion lemma: ``C^p M^T (M C^p M^T + R^p)^-1 = (Omega^p + M^T V^p M)^-1 M^T V^p``).

**Sequential, not summed at the prior.**  The paper processes the points of a node *sequentially*
(Sec. 3: "The measurements ... at each sensor node are processed in a sequential way"; Algorithms 1-3,
"for i = 1, ..., n_k // sequential"): point ``i`` is linearised at the estimate after points ``1..i-1``
(``S``, ``J``, ``M``, ``R^x``, ``R^p``, ``C^y`` and the pseudo-measurement all carry the superscript
``[i-1]``).  Only the *i-th points of different sensors* are summed at the same linearisation point (eqs. 18-19,
25).  :func:`mem_information_increment` therefore runs the node's own sequential information filter over its
scan, starting from the given prior, and returns the accumulated increments ``(sum_i dOmega_i, sum_i dq_i)``;
prior information plus that increment is the paper's local posterior after its ``n_k`` points, and it equals
``n_k`` sequential MEM-EKF* updates.  ``sequential=False`` linearises every point at the prior instead
(summed at the prior: order-independent, but not the paper's filter).  The paper interleaves consensus
rounds *between* points (Algorithms 2-3, lines 5-18, assuming every sensor has the same ``n_k``); a rule that
exchanges one increment per scan (consensus on measurements on whole scans) cannot reproduce that
interleaving, the increments here are what a node contributes for its whole scan.

**Prediction in information form** (eqs. 20-21, notes "Information filters")::

    Omega+ = (F Omega^-1 F^T + C_w)^-1,   q+ = Omega+ F Omega^-1 q

(eq. 20b is the same matrix by the matrix inversion lemma; eq. 20a as printed has ``Omega`` where eq. 21a has
``Omega^-1``: the inverse is the correct one).  It equals the covariance prediction ``(F x, F C F^T + C_w)``.

**Orientation.**  ``alpha`` is never differenced inside the update: it enters through ``sin``/``cos`` in
``S`` and ``J``, and linearly through ``M p^[i-1]`` in ``Ytilde``, where the branch cancels
(``p+ = p^[i-1] + K (Y - F vect(C^y))``).  The state's ``alpha`` is continuous and never wrapped; an error
``alpha_hat - alpha`` is an angle difference (wrap it), and an ellipse is also unchanged by ``alpha + pi``.
Note that ``q^p = Omega^p p`` carries ``alpha`` absolutely, so information vectors of different nodes only
combine meaningfully when their orientation estimates are on the same branch.

Filters (:data:`~zentrack.fusion.filters.base.FILTER_REGISTRY`): ``"mem-ekf"`` (single-sensor MEM-EKF*,
sequential, covariance form) and ``"mem-if"`` (the information filter, with
:meth:`MemInformationFilter.information_increment` for consensus on measurements).  Their factory needs a
:class:`~zentrack.fusion.motion_eot.ExtendedObjectMotion` (or any 7-state motion with ``A``, ``Q``) and an
:class:`ExtentPointModel` (``spread`` = ``C^h``, ``noise_cov`` = default ``C^v``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..linalg import (
    GaussianState,
    InformationPair,
    congruence,
    mat_vec,
    small_inverse,
    spd_inverse,
    symmetrize,
    to_information,
)
from ..registry import Param
from .base import FILTER_REGISTRY, FilterContext, LocalFilter
from .pda_common import as_scan_batch

Array = np.ndarray

#: F of eq. (12): ``F vect(e e^T) = [e1^2, e2^2, e1 e2]``
F_SELECT = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0]])
#: Ftilde of eq. (14)
F_TILDE = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 0.0]])
#: floor of the guarded ``R^p`` relative to ``C_Y``: ``R^p_g >= RP_REL_FLOOR C_Y`` (see :func:`rp_matrix`)
RP_REL_FLOOR = 1e-9
KIN, EXT = 4, 3  # kinematic and extent dimensions


# ------------------------------------------------------------------------------------------ model pieces
def shape_matrix(p: Array) -> Array:
    """``S = R(alpha) diag(l1, l2)`` (eq. 3) for extents ``p`` ``(B, 3)`` -> ``(B, 2, 2)``."""
    a, l1, l2 = p[..., 0], p[..., 1], p[..., 2]
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([l1 * c, -l2 * s], -1), np.stack([l1 * s, l2 * c], -1)], -2)


def shape_jacobians(p: Array) -> Array:
    """``J`` ``(B, 2, 2, 3)``: ``J[:, n]`` is the Jacobian of row ``S_n`` of ``S`` in ``p`` (Prop. 1, notes)."""
    a, l1, l2 = p[..., 0], p[..., 1], p[..., 2]
    c, s, z = np.cos(a), np.sin(a), np.zeros_like(a)
    j1 = np.stack([np.stack([-l1 * s, c, z], -1), np.stack([-l2 * c, z, -s], -1)], -2)
    j2 = np.stack([np.stack([l1 * c, s, z], -1), np.stack([-l2 * s, z, c], -1)], -2)
    return np.stack([j1, j2], -3)


def kron_cov(cy: Array) -> Array:
    """``C_Y = F (C^y (x) C^y)(F + Ftilde)^T`` (Prop. 2 / eq. 13) for ``cy`` ``(B, 2, 2)`` -> ``(B, 3, 3)``."""
    kron = (cy[:, :, None, :, None] * cy[:, None, :, None, :]).reshape(cy.shape[0], 4, 4)  # np.kron per row
    return symmetrize(F_SELECT @ kron @ (F_SELECT + F_TILDE).T)


class MemLinearisation(NamedTuple):
    """The pseudo-linear models of one point at one estimate (stacks over B)."""

    rx: Array  #: ``R^x`` (B, 2, 2), eqs. (6)-(8)
    cy: Array  #: ``C^y`` (B, 2, 2), eq. (10)
    m: Array  #: ``M`` (B, 3, 3), eq. (15)
    y_mean: Array  #: ``F vect(C^y)`` (B, 3), the mean of the pseudo-measurement
    c_yy: Array  #: ``C_Y`` (B, 3, 3), its covariance


def _batch_cov(c: Array, b: int) -> Array:
    c = np.asarray(c, dtype=float)
    return np.broadcast_to(c, (b, 2, 2))


def mem_linearisation(cx: Array, p: Array, cp: Array, cv: Array, ch: Array) -> MemLinearisation:
    """The models (6) and (13) at kinematic covariance ``cx`` ``(B, 4, 4)`` and extent ``p`` ``(B, 3)``,
    ``cp`` ``(B, 3, 3)``; ``cv`` ``(B, 2, 2)`` or ``(2, 2)``, ``ch`` ``(2, 2)``."""
    b = p.shape[0]
    ch = np.asarray(ch, dtype=float)
    s = shape_matrix(p)
    jac = shape_jacobians(p)
    c_i = congruence(s, ch)  # eq. (7)
    c_ii = np.einsum("bij,bnkj,kl,bmli->bmn", cp, jac, ch, jac)  # eq. (8): tr(C^p J_n^T C^h J_m)
    rx = symmetrize(c_i + c_ii + _batch_cov(cv, b))
    cy = symmetrize(cx[:, :2, :2] + rx)  # eq. (10)
    g = np.einsum("bmk,kl,bnlj->bmnj", s, ch, jac)  # g[:, m, n] = S_m C^h J_n
    m = np.stack([2.0 * g[:, 0, 0], 2.0 * g[:, 1, 1], g[:, 0, 1] + g[:, 1, 0]], axis=1)  # eq. (15)
    y_mean = np.stack([cy[:, 0, 0], cy[:, 1, 1], cy[:, 0, 1]], axis=-1)  # F vect(C^y)
    return MemLinearisation(rx, cy, m, y_mean, kron_cov(cy))


def pseudo_measurement(y: Array, x: Array) -> Array:
    """``Y = F((y - H x) (x) (y - H x)) = [e1^2, e2^2, e1 e2]`` (eq. 11), ``y`` ``(B, 2)``, ``x`` ``(B, 4)``."""
    e = y - x[:, :2]
    return np.stack([e[:, 0] ** 2, e[:, 1] ** 2, e[:, 0] * e[:, 1]], axis=-1)


def _sym_sqrt(c: Array) -> tuple[Array, Array]:
    """``C^(1/2)`` and ``C^(-1/2)`` of symmetric positive definite stacks (eigenvalues floored at 1e-300)."""
    w, u = np.linalg.eigh(c)
    w = np.maximum(w, 1e-300)
    ut = np.swapaxes(u, -1, -2)
    return (u * np.sqrt(w)[:, None, :]) @ ut, (u / np.sqrt(w)[:, None, :]) @ ut


def rp_matrix(c_yy: Array, m: Array, cp: Array, rel_floor: float = RP_REL_FLOOR) -> tuple[Array, Array]:
    """The guarded ``R^p = C_Y - M C^p M^T`` (Prop. 2) ``(B, 3, 3)`` and where the guard acted ``(B,)``.

    ``R^p`` is symmetrised.  Its scale is ``C_Y`` (``0 <= R^p <= C_Y`` whenever the model is consistent), so the
    floor is relative to it in every direction: where the whitened matrix ``W = C_Y^-1/2 R^p C_Y^-1/2`` has an
    eigenvalue below ``rel_floor``, those eigenvalues are raised to ``rel_floor`` and ``R^p_g = C_Y^1/2 W_g
    C_Y^1/2``, i.e. ``R^p_g >= rel_floor C_Y``.  Rows already above the floor are returned unchanged (bit for bit).
    """
    rp = symmetrize(c_yy - congruence(m, cp))
    root, inv_root = _sym_sqrt(symmetrize(c_yy))
    w, v = np.linalg.eigh(symmetrize(inv_root @ rp @ inv_root))
    clipped = ~(w[:, 0] >= rel_floor)  # NaN counts as clipped
    if clipped.any():
        vr = root @ v
        fixed = (vr * np.maximum(w, rel_floor)[:, None, :]) @ np.swapaxes(vr, -1, -2)
        rp = np.where(clipped[:, None, None], symmetrize(fixed), rp)
    return rp, clipped


def _guarded(lin: MemLinearisation, cp: Array, rel_floor: float) -> tuple[Array, Array]:
    """``(R^p_g, C_Yg)``: the guarded noise and innovation covariances (``C_Y`` where unguarded)."""
    rp, clipped = rp_matrix(lin.c_yy, lin.m, cp, rel_floor)
    if not clipped.any():
        return rp, lin.c_yy
    c_yg = np.where(clipped[:, None, None], symmetrize(congruence(lin.m, cp) + rp), lin.c_yy)
    return rp, c_yg


# ------------------------------------------------------------------------------------------ MEM-EKF*
class MemPosterior(NamedTuple):
    """Kinematic and extent estimates (stacks over B)."""

    x: Array  #: (B, 4)
    cx: Array  #: (B, 4, 4)
    p: Array  #: (B, 3)
    cp: Array  #: (B, 3, 3)


def mem_point_update(
    x: Array, cx: Array, p: Array, cp: Array, y: Array, cv: Array, ch: Array, rel_floor: float = RP_REL_FLOOR,
) -> MemPosterior:
    """One MEM-EKF* measurement update for a batch (module docstring): ``x`` ``(B, 4)``, ``cx`` ``(B, 4, 4)``,
    ``p`` ``(B, 3)`` = ``[alpha, l1, l2]``, ``cp`` ``(B, 3, 3)``, point ``y`` ``(B, 2)``, ``cv`` ``(B, 2, 2)``
    or ``(2, 2)``, ``ch`` ``(2, 2)``.  Both corrections use the prior (x, cx, p, cp)."""
    x, cx, p, cp, y = (np.asarray(a, dtype=float) for a in (x, cx, p, cp, y))
    lin = mem_linearisation(cx, p, cp, cv, ch)
    # kinematics (notes: x += C^x H^T (C^y)^-1 (y - H x)); Joseph form with R^x
    gain_x = cx[:, :, :2] @ small_inverse(lin.cy)  # (B, 4, 2)
    x_post = x + mat_vec(gain_x, y - x[:, :2])
    i_kh = np.eye(KIN) - np.concatenate([gain_x, np.zeros((x.shape[0], KIN, 2))], axis=-1)
    cx_post = symmetrize(congruence(i_kh, cx) + congruence(gain_x, lin.rx))
    # extent (notes: p += C^p M^T C_Y^-1 (Y - F vect(C^y))), with the kinematic prior in Y and C^y
    rp, c_yg = _guarded(lin, cp, rel_floor)
    gain_p = np.swapaxes(np.linalg.solve(c_yg, lin.m @ cp), -1, -2)  # C^p M^T C_Y^-1 (C_Y, C^p symmetric)
    p_post = p + mat_vec(gain_p, pseudo_measurement(y, x) - lin.y_mean)
    cp_post = symmetrize(congruence(np.eye(EXT) - gain_p @ lin.m, cp) + congruence(gain_p, rp))
    return MemPosterior(x_post, cx_post, p_post, cp_post)


# ------------------------------------------------------------------------------------------ information form
def mem_point_information(
    x: Array, cx: Array, p: Array, cp: Array, y: Array, cv: Array, ch: Array, rel_floor: float = RP_REL_FLOOR,
) -> tuple[InformationPair, InformationPair]:
    """One point's information contributions at the estimate ``(x, cx, p, cp)`` (eqs. 18-19 for one sensor):
    ``(H^T V^x H, H^T V^x y)`` ``(B, 4, 4), (B, 4)`` and ``(M^T V^p M, M^T V^p Ytilde)`` ``(B, 3, 3), (B, 3)``."""
    b = x.shape[0]
    lin = mem_linearisation(cx, p, cp, cv, ch)
    vx = small_inverse(lin.rx)  # V^x
    omega_x = np.zeros((b, KIN, KIN))
    omega_x[:, :2, :2] = symmetrize(vx)
    q_x = np.zeros((b, KIN))
    q_x[:, :2] = mat_vec(vx, y)
    rp, _ = _guarded(lin, cp, rel_floor)
    vp = spd_inverse(rp)  # V^p
    y_tilde = pseudo_measurement(y, x) - lin.y_mean + mat_vec(lin.m, p)  # eq. (17)
    mt = np.swapaxes(lin.m, -1, -2)
    omega_p = symmetrize(mt @ vp @ lin.m)
    q_p = mat_vec(mt @ vp, y_tilde)
    return InformationPair(omega_x, q_x), InformationPair(omega_p, q_p)


def _masked(mask: Array, a: Array) -> Array:
    return np.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, 0.0)


def mem_information_increment(
    x: Array, cx: Array, p: Array, cp: Array, points: Array, valid: Array, cv: Array, ch: Array,
    sequential: bool = True, rel_floor: float = RP_REL_FLOOR,
) -> tuple[InformationPair, InformationPair]:
    """The information one sensor's scan adds to the prior ``(x, cx, p, cp)`` (module docstring).

    ``points`` ``(B, J, 2)``, ``valid`` ``(B, J)`` (False: padding, contributes exactly zero and its value is
    never used); ``cv`` ``(B, 2, 2)`` or ``(2, 2)``, ``ch`` ``(2, 2)``.  Returns the kinematic increment
    ``(sum H^T V^x H, sum H^T V^x y)`` ``(B, 4, 4), (B, 4)`` and the extent increment
    ``(sum M^T V^p M, sum M^T V^p Ytilde)`` ``(B, 3, 3), (B, 3)``.

    ``sequential=True`` (the paper): point ``i`` is linearised at the node's own information-filter estimate
    after its valid points ``1..i-1`` (``x = Omega^-1 q`` of the running sums, eqs. 18-19 with one sensor);
    ``sequential=False``: every point at the prior.
    """
    x, cx, p, cp, points = (np.asarray(a, dtype=float) for a in (x, cx, p, cp, points))
    valid = np.asarray(valid, dtype=bool)
    b, n_pts = valid.shape
    d_ox, d_qx = np.zeros((b, KIN, KIN)), np.zeros((b, KIN))
    d_op, d_qp = np.zeros((b, EXT, EXT)), np.zeros((b, EXT))
    if sequential:
        ox0, op0 = spd_inverse(cx), spd_inverse(cp)
        qx0, qp0 = mat_vec(ox0, x), mat_vec(op0, p)
    xr, cxr, pr, cpr = x, cx, p, cp  # the running estimate the next point is linearised at
    for j in range(n_pts):
        ok = valid[:, j]
        if not ok.any():
            continue
        y = np.where(ok[:, None], points[:, j], xr[:, :2])  # padding never enters the arithmetic
        kin, ext = mem_point_information(xr, cxr, pr, cpr, y, cv, ch, rel_floor)
        d_ox += _masked(ok, kin.matrix)
        d_qx += _masked(ok, kin.vector)
        d_op += _masked(ok, ext.matrix)
        d_qp += _masked(ok, ext.vector)
        if sequential:  # the running information filter's estimate after this point
            cx_new, cp_new = spd_inverse(ox0 + d_ox), spd_inverse(op0 + d_op)
            rows = ok[:, None, None]
            cxr, cpr = np.where(rows, cx_new, cxr), np.where(rows, cp_new, cpr)
            xr = np.where(ok[:, None], mat_vec(cx_new, qx0 + d_qx), xr)
            pr = np.where(ok[:, None], mat_vec(cp_new, qp0 + d_qp), pr)
    return InformationPair(d_ox, d_qx), InformationPair(d_op, d_qp)


def information_predict(pair: InformationPair, f: Array, q: Array) -> InformationPair:
    """Prediction in information form (eqs. 20-21, notes): ``Omega+ = (F Omega^-1 F^T + C_w)^-1``,
    ``q+ = Omega+ F Omega^-1 q`` for stacks ``(B, n, n), (B, n)`` and ``f``, ``q`` ``(n, n)``."""
    cov = spd_inverse(pair.matrix)  # Omega^-1
    pred_cov = symmetrize(congruence(f, cov) + q)
    omega = spd_inverse(pred_cov)
    return InformationPair(omega, mat_vec(omega, mat_vec(f, mat_vec(cov, pair.vector))))


# ------------------------------------------------------------------------------------------ filters
class ExtentPointModel:
    """Point returns of an extended object (eq. 3): ``spread`` is ``C^h``, ``noise_cov`` the default ``C^v``.

    ``h`` is the centre ``H x`` (for plotting and for code that expects a measurement model); the filters of
    this module use the MEM likelihood instead.
    """

    name = "extent-point"
    dim = 2

    def __init__(self, spread: Array, noise_cov: Array) -> None:
        self.spread = np.asarray(spread, dtype=float)
        self.noise_cov = np.asarray(noise_cov, dtype=float)
        for label, c in (("spread", self.spread), ("noise_cov", self.noise_cov)):
            if c.shape != (2, 2) or not np.all(np.isfinite(c)) or not np.allclose(c, c.T) \
                    or np.linalg.eigvalsh(c)[0] < 0:
                raise ValueError(f"{label} must be a symmetric positive semidefinite 2x2 matrix, got {c.tolist()}")

    def h(self, x: Array, sensors: Array) -> Array:
        return np.tile(x[:, :2], (1, sensors.shape[1]))

    def jacobian(self, x: Array, sensors: Array, n_state: int | None = None) -> Array:
        b, s = x.shape[0], sensors.shape[1]
        jac = np.zeros((b, s, 2, n_state or x.shape[1]))
        jac[:, :, [0, 1], [0, 1]] = 1.0
        return jac.reshape(b, 2 * s, -1)

    def linearize(self, x: Array, sensors: Array, n_state: int | None = None) -> tuple[Array, Array]:
        return self.h(x, sensors), self.jacobian(x, sensors, n_state)

    def residual(self, z: Array, z_pred: Array) -> Array:
        return z - z_pred


def split_state(state: GaussianState) -> MemPosterior:
    """The kinematic and extent blocks of a 7-state (the marginal blocks: cross-covariances are dropped)."""
    return MemPosterior(state.mean[:, :KIN], state.cov[:, :KIN, :KIN], state.mean[:, KIN:], state.cov[:, KIN:, KIN:])


def join_state(x: Array, cx: Array, p: Array, cp: Array) -> GaussianState:
    """A 7-state with block-diagonal covariance ``diag(cx, cp)``."""
    b = x.shape[0]
    cov = np.zeros((b, KIN + EXT, KIN + EXT))
    cov[:, :KIN, :KIN] = cx
    cov[:, KIN:, KIN:] = cp
    return GaussianState(np.concatenate([x, p], axis=-1), cov)


@dataclass
class IncrementState(GaussianState):
    """A posterior of :class:`MemInformationFilter` with the information its scan added (``increment``,
    ``(B, 7, 7)`` / ``(B, 7)``; zero for rows without points): what consensus on measurements exchanges."""

    increment: InformationPair | None = None

    def copy(self) -> IncrementState:
        inc = self.increment
        return IncrementState(self.mean.copy(), self.cov.copy(),
                              None if inc is None else InformationPair(inc.matrix.copy(), inc.vector.copy()))


class _MemFilter(LocalFilter):
    """What the two MEM filters share: the 7-state, its blocks, the scan input.

    The whole 7-state is scored against the truth (``kinematic_dim = 7``: an extended object's truth has its
    extent), and a tracker or the batched simulator gives ``update`` every point of a scan (``takes_scans``);
    rows without points come back as their prior (``scanless_rows_unchanged``).
    """

    state_dim = KIN + EXT
    kinematic_dim = KIN + EXT
    takes_scans = True
    scanless_rows_unchanged = True

    def __init__(self, motion: Any, measurement: ExtentPointModel, rel_floor: float = RP_REL_FLOOR) -> None:
        if getattr(motion, "dim", None) != KIN + EXT or np.shape(getattr(motion, "A", np.empty(0))) != (7, 7):
            raise ValueError(f"{self.name}: needs a 7-state extended-object motion (motion_eot.ExtendedObjectMotion), "
                             f"got {getattr(motion, 'name', motion)!r}")
        if not hasattr(measurement, "spread"):
            raise ValueError(f"{self.name}: needs an ExtentPointModel (spread C^h, noise_cov C^v), "
                             f"got {getattr(measurement, 'name', measurement)!r}")
        self.motion = motion
        self.measurement = measurement
        self.spread = np.asarray(measurement.spread, dtype=float)
        self.rel_floor = rel_floor

    def initial_state(self, mean: Array, cov: Array, lumped_var: float = 1.0) -> GaussianState:
        """Prior from the full 7-dim ``mean`` ``(B, 7)`` and ``cov`` ``(7, 7)`` or ``(B, 7, 7)`` (used as given:
        a kinematic-only prior has no extent to start from)."""
        mean = np.atleast_2d(np.asarray(mean, dtype=float))
        if mean.shape[1] != self.state_dim:
            raise ValueError(f"{self.name}: the prior needs the kinematics and the extent [m1, m2, v1, v2, alpha, l1, "
                             f"l2] (7 components), got {mean.shape[1]}")
        return super().initial_state(mean, cov, lumped_var)

    def _scan(self, z: Array, noise_cov: Array | None, counts: Array | None) -> tuple[Array, Array, Array]:
        z = np.asarray(z, dtype=float)
        if z.shape[-1] != 2:
            raise ValueError(f"{self.name}: expects 2-D points, z of shape (B, 2) or (B, J, 2); got {z.shape}")
        points, valid = as_scan_batch(z, counts)
        cv = self.measurement.noise_cov if noise_cov is None else np.asarray(noise_cov, dtype=float)
        return points, valid, cv

    def predict_covariance(self, state: GaussianState) -> GaussianState:
        """The covariance-form prediction ``(A x, A C A^T + Q)``."""
        return GaussianState(self.motion.f(state.mean), symmetrize(congruence(self.motion.A, state.cov) + self.motion.Q))


class MemEkfFilter(_MemFilter):
    """Single-sensor MEM-EKF* (Yang & Baum 2019; paper 4's local model): points processed sequentially."""

    name = "mem-ekf"

    def predict(self, state: GaussianState) -> GaussianState:
        return self.predict_covariance(state)

    def update(
        self, state: GaussianState, z: Array, sensors: Array | None = None, noise_cov: Array | None = None,
        counts: Array | None = None,
    ) -> GaussianState:
        """``z`` ``(B, J, 2)`` (padded; ``counts`` ``(B,)`` real points, None = all) or ``(B, 2)``; ``sensors``
        ignored (points in the global frame); ``noise_cov`` ``C^v`` ``(B, 2, 2)`` or ``(2, 2)`` (None: the
        measurement model's)."""
        points, valid, cv = self._scan(z, noise_cov, counts)
        est = split_state(state)
        if not valid.any():
            return state
        for j in range(points.shape[1]):
            ok = valid[:, j]
            if not ok.any():
                continue
            y = np.where(ok[:, None], points[:, j], est.x[:, :2])
            post = mem_point_update(*est, y, cv, self.spread, self.rel_floor)
            est = MemPosterior(*(np.where(ok.reshape((-1,) + (1,) * (a.ndim - 1)), a, e) for a, e in zip(post, est)))
        out = join_state(*est)
        none: Array = ~np.any(valid, axis=1)
        return GaussianState(np.where(none[:, None], state.mean, out.mean), np.where(none[:, None, None], state.cov,
                                                                                     out.cov))


class MemInformationFilter(_MemFilter):
    """Paper 4's extended-object information filter (CEOT, eqs. 18-21) for one node's scans.

    ``update`` is the prior information plus :meth:`information_increment`; ``predict`` is eqs. 20-21.
    """

    name = "mem-if"

    def __init__(self, motion: Any, measurement: ExtentPointModel, sequential: bool = True,
                 rel_floor: float = RP_REL_FLOOR) -> None:
        super().__init__(motion, measurement, rel_floor)
        self.sequential = sequential

    def information_increment(
        self, state: GaussianState, z: Array, sensors: Array | None = None, noise_cov: Array | None = None,
        counts: Array | None = None,
    ) -> InformationPair:
        """The scan's information ``(B, 7, 7), (B, 7)``, block-diagonal (kinematic block first), linearised at
        ``state`` (see :func:`mem_information_increment`).  A relay (no points, ``counts`` 0) gets zeros."""
        points, valid, cv = self._scan(z, noise_cov, counts)
        kin, ext = mem_information_increment(*split_state(state), points, valid, cv, self.spread,
                                             self.sequential, self.rel_floor)
        b = state.mean.shape[0]
        matrix = np.zeros((b, KIN + EXT, KIN + EXT))
        matrix[:, :KIN, :KIN] = kin.matrix
        matrix[:, KIN:, KIN:] = ext.matrix
        return InformationPair(matrix, np.concatenate([kin.vector, ext.vector], axis=-1))

    def update(
        self, state: GaussianState, z: Array, sensors: Array | None = None, noise_cov: Array | None = None,
        counts: Array | None = None,
    ) -> GaussianState:
        """Prior information (of the marginal blocks) plus :meth:`information_increment`; rows without points
        keep their prior exactly."""
        inc = self.information_increment(state, z, sensors, noise_cov, counts)
        est = split_state(state)
        blocks = []
        for sl, c, m in ((slice(0, KIN), est.cx, est.x), (slice(KIN, KIN + EXT), est.cp, est.p)):
            omega = spd_inverse(c)
            post_cov = spd_inverse(omega + inc.matrix[:, sl, sl])
            blocks.append((mat_vec(post_cov, mat_vec(omega, m) + inc.vector[:, sl]), post_cov))
        out = join_state(blocks[0][0], blocks[0][1], blocks[1][0], blocks[1][1])
        none = ~np.any(inc.matrix != 0.0, axis=(1, 2))
        return IncrementState(np.where(none[:, None], state.mean, out.mean),
                              np.where(none[:, None, None], state.cov, out.cov), inc)

    def information_blocks(self, state: GaussianState) -> dict[str, InformationPair]:
        """What a node shares: ``state`` in information form and its scan's ``increment`` (zero after a
        prediction or a fusion), for consensus on measurements (``eot-cm``)."""
        inc = state.increment if isinstance(state, IncrementState) else None
        if inc is None:
            b, n = state.mean.shape
            inc = InformationPair(np.zeros((b, n, n)), np.zeros((b, n)))
        return {"state": to_information(state), "increment": inc}

    def predict(self, state: GaussianState) -> GaussianState:
        """Eqs. 20-21 on each block's information pair, returned as a Gaussian (equals :meth:`predict_covariance`
        for a block-diagonal state)."""
        est = split_state(state)
        a, q = self.motion.A, self.motion.Q
        out = []
        for sl, c, m in ((slice(0, KIN), est.cx, est.x), (slice(KIN, KIN + EXT), est.cp, est.p)):
            omega = spd_inverse(c)
            pred = information_predict(InformationPair(omega, mat_vec(omega, m)), a[sl, sl], q[sl, sl])
            cov = spd_inverse(pred.matrix)
            out.append((mat_vec(cov, pred.vector), cov))
        return join_state(out[0][0], out[0][1], out[1][0], out[1][1])


def _mem_ekf(context: FilterContext, rp_floor: float = RP_REL_FLOOR) -> MemEkfFilter:
    return MemEkfFilter(context.motion, context.measurement, rp_floor)  # type: ignore[arg-type]


def _mem_if(context: FilterContext, sequential: bool = True, rp_floor: float = RP_REL_FLOOR) -> MemInformationFilter:
    return MemInformationFilter(context.motion, context.measurement, sequential, rp_floor)  # type: ignore[arg-type]


_RP_FLOOR = Param("rp_floor", float, RP_REL_FLOOR, lo=0.0, hi=1.0, lo_open=True,
                  help="floor of the pseudo-measurement noise R^p relative to C_Y (R^p >= rp_floor C_Y)")

FILTER_REGISTRY.register(
    "mem-ekf", _mem_ekf, (_RP_FLOOR,),
    "MEM-EKF* (paper 4 / Yang & Baum 2019): extended object (ellipse/rectangle) from point returns, sequential",
    tags=("scans", "extent"),
)
FILTER_REGISTRY.register(
    "mem-if", _mem_if,
    (
        Param("sequential", bool, True,
              help="linearise each point at the estimate after the previous ones (the paper); False: all at the prior"),
        _RP_FLOOR,
    ),
    "extended-object information filter (paper 4 CEOT eqs. 18-21) with per-scan information increments",
    tags=("scans", "extent"),
)
