"""Secant Kalman filter (paper 3, SecKF) and the paper's "linearisation solution" baseline.

**Secant operator** (paper 3 eq. 18, "separate dependent variables, stepwise independent variables"):
``SecLine[h, a, b]`` is the ``q x p`` matrix whose column ``i`` is

    (h(theta_i) - h(theta_{i-1})) / (b_i - a_i),   theta_i = [b_1..b_i, a_{i+1}..a_p],  theta_0 = a,

so ``SecLine (b - a) = h(b) - h(a)`` exactly (telescoping).  :func:`secant_operator` evaluates it on stacks
``(B, p)``; a column whose step ``|b_i - a_i|`` is below ``min_step`` is NaN and the caller falls back to the
Jacobian element.  Angle-valued outputs take their differences through the measurement model's wrapped
``residual``.

**SecKF step** (paper 3 Sec. 3.4, Fig. 9, with eqs. 21-27 and Appendix B), as implemented here:

1. prediction ``x̄_j = f(x̂_{j-1})``; EKF prior ``P̄_h = F_h P_{j-1} F_hᵀ + Q`` with ``F_h`` the Jacobian at
   ``x̂_{j-1}``;
2. first (EKF) update at the prediction with ``P̄_h``: ``H_s = ∂h/∂x (x̄_j)``, estimate ``x̂_h,j`` (only its
   mean is formed: the paper's ``P̂_h,j`` is never used afterwards);
3. ``H_sg = SecLine[h, x̄_j, x̂_h,j]`` element-wise mixed with ``H_s`` by the selection rule;
4. state-equation secant ``F_sg = SecLine[f, x̄_{j-1}, x̂_{j-1}]`` -- the secant between the *previous*
   step's prediction and posterior, as Appendix B writes ``g_f,14 = (f_xv(.., v̂_{j-1}, ..) -
   f_xv(.., v̄_{j-1}, ..)) / (v̂_{j-1} - v̄_{j-1})`` -- mixed with ``F_h`` (Jacobian at ``x̂_{j-1}``, the paper's
   ``f15 = cos ψ̂_{j-1} [..v̂_{j-1}..]``) by the same rule; secant prior ``P̄_G = F_sg P_{j-1} F_sgᵀ + Q``
   (eq. 24);
5. second update from the prediction: ``K = P̄_G H_sgᵀ (H_sg P̄_G H_sgᵀ + R)⁻¹``,
   ``x̂_j = x̄_j + K W(z - h(x̄_j))``, ``P_j = (I - K H_sg) P̄_G (I - K H_sg)ᵀ + K R Kᵀ`` (Joseph form: the
   same as the paper's ``(I - K H_sg) P̄_G`` for the gain above, but symmetric and PSD in floating point).

The first step (no previous pair yet) and a prior that did not come out of this filter (a fused estimate, a
plain :class:`~zentrack.fusion.linalg.GaussianState`) use ``F_sg = F_h``.  The pair ``(x̄_{j-1}, x̂_{j-1})``
and the EKF prior covariance travel in a :class:`SecantState` (a GaussianState with extra fields, like
:class:`~zentrack.fusion.filters.pda_common.ParticleState`): ``update`` returns the posterior with its
``prior_mean``; ``predict`` returns ``cov = P̄_G`` (what the final update uses; what fusion sees) and
``ekf_cov = P̄_h`` (the first update's prior).  With ``selection="none"`` the filter is exactly the EKF.

**Element selection** (paper 3 Sec. 3.3): a secant element is kept where the function of that one
coordinate is convex over its interval (Judgement Metric 1, second derivative >= 0) or a contraction
holds (Judgement Metric 2, Lipschitz constant < 1), else the Jacobian element is used:

- ``"convexity"``: the general rule evaluated numerically: convexity by the second difference
  ``g(a_i) + g(b_i) - 2 g((a_i + b_i)/2) >= -tol`` along the stepwise segment of column ``i`` (wrapped for
  angles); contraction by ``max(|secant|, |Jacobian|) < 1`` (the element's slope bound over the interval --
  note that this metric, like the paper's, depends on the units of the state);
- ``"paper-scenario2"``: the mask stated for scenario 2 (Appendix B / step 6): in ``F`` the ``v`` column of
  the ``x``, ``y`` and ``v`` rows uses secants, everything else (``psi`` columns, linear elements) the
  Jacobian; every element of ``H`` uses secants.  Only for the 5-state ``[x, y, z, v, psi]`` model;
- ``"all"``: every element secant; ``"none"``: every element Jacobian (= EKF).

**Linearisation solution baseline** ("lin", paper 3 ref. [8]): the paper says it is the fastest method
(2.6e-6 s per step), "cannot calculate velocity and heading angle", and its position error "remains
almost unchanged" over the 20 observations.  That is a per-observation (snapshot) position fix, not a
filter; here it is the pseudo-linear line-of-sight solution: the angle equations rewritten as equations
linear in the target position,

    sin α (x - s_x) - cos α (y - s_y) = 0,
    sin β [cos α (x - s_x) + sin α (y - s_y)] - cos β (z - s_z) = 0,

one pair per sensor, closed by the sea-surface constraint ``z = z̄`` (the prior height), solved by weighted
least squares (rows weighted by ``1 / (r² σ²)``, ``r`` the prior range, ``σ²`` the angle variance; the height
row by ``1 / P̄_zz``).  For one satellite the 3x3 system is solved exactly.  The position covariance is the
first-order one, ``(Aᵀ W A)⁻¹``; velocity and heading keep their prior (they are not observed) and the
cross-covariances are dropped.  ``predict`` is the EKF prediction, so the filter runs wherever the others
do; its position output does not depend on the prior position except for the height.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..linalg import GaussianState, congruence, joseph_update, mat_vec, small_inverse, symmetrize
from ..measurement import MeasurementModel
from ..registry import Param
from .base import FILTER_REGISTRY, FilterContext, LocalFilter

Array = np.ndarray
Difference = Callable[[Array, Array], Array]

SELECTIONS = ("convexity", "paper-scenario2", "all", "none")


class _Motion(Protocol):
    dim: int
    Q: Array

    def f(self, x: Array) -> Array: ...

    def jacobian(self, x: Array) -> Array: ...


def _minus(u: Array, v: Array) -> Array:
    return u - v


# ------------------------------------------------------------------------------------------ secant operator
def secant_path(a: Array, b: Array) -> Array:
    """The stepwise path ``(p + 1, B, p)``: ``theta_0 = a``, ``theta_i = [b_1..b_i, a_{i+1}..a_p]``."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.atleast_2d(np.asarray(b, dtype=float))
    p = a.shape[-1]
    lower = np.tri(p + 1, p, -1, dtype=bool)  # row i: the first i components come from b
    return np.where(lower[:, None, :], b[None], a[None])


def _stacked(func: Callable[[Array], Array], points: Array) -> Array:
    """``func`` on ``(k, B, p)`` points in one call (rows are independent) -> ``(k, B, q)``."""
    k, bsz, p = points.shape
    out = np.asarray(func(points.reshape(k * bsz, p)))
    return out.reshape(k, bsz, -1)


def _secant_with_values(
    func: Callable[[Array], Array], a: Array, b: Array, min_step: float, difference: Difference | None,
) -> tuple[Array, Array]:
    diff = difference or _minus
    vals = _stacked(func, secant_path(a, b))  # (p+1, B, q)
    p, bsz = a.shape[-1], a.shape[0]
    num = diff(vals[1:].reshape(p * bsz, -1), vals[:-1].reshape(p * bsz, -1)).reshape(p, bsz, -1)
    step = b - a  # (B, p)
    small = np.abs(step) < min_step
    safe = np.where(small, 1.0, step)
    cols = np.moveaxis(num, 0, -1) / safe[:, None, :]  # (B, q, p)
    return np.where(small[:, None, :], np.nan, cols), vals


def secant_operator(
    func: Callable[[Array], Array], a: Array, b: Array, min_step: float = 1e-9,
    difference: Difference | None = None,
) -> Array:
    """``SecLine[func, a, b]`` ``(B, q, p)`` for stacks ``a``, ``b`` ``(B, p)`` (see the module docstring).

    ``func`` maps rows independently; it is called once on the ``(p + 1) B`` path points stacked
    point-major (``(p + 1) * B`` rows: all of ``theta_0``, then all of ``theta_1``, ...).  ``difference``
    (default ``u - v``) is used for ``func(theta_i) - func(theta_{i-1})``: pass the measurement model's
    ``residual`` for angles.  Columns with ``|b_i - a_i| < min_step`` are NaN.
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.atleast_2d(np.asarray(b, dtype=float))
    return _secant_with_values(func, a, b, min_step, difference)[0]


# ------------------------------------------------------------------------------------------ selection
def paper_scenario2_mask(role: str) -> Array:
    """The scenario-2 mask of paper 3 (Appendix B): ``role="state"`` ``(5, 5)``, ``"measurement"`` ``(2, 5)``."""
    if role == "state":
        mask = np.zeros((5, 5), dtype=bool)
        mask[[0, 1, 3], 3] = True  # x, y and v rows, v column; psi columns (and linear elements) Jacobian
        return mask
    if role == "measurement":
        return np.ones((2, 5), dtype=bool)
    raise ValueError(f"role must be 'state' or 'measurement', got {role!r}")


def convexity_mask(
    func: Callable[[Array], Array], a: Array, b: Array, secant: Array, jacobian: Array,
    difference: Difference | None = None, rtol: float = 1e-10, path_values: Array | None = None,
) -> Array:
    """The general rule ``(B, q, p)``: convex along column ``i``'s segment, or a contraction (module docstring).

    Convexity: the second difference ``g(theta_{i-1}) + g(theta_i) - 2 g(mid_i) >= -tol``, ``mid_i`` the
    midpoint of the segment from ``theta_{i-1}`` to ``theta_i``, ``tol = rtol (|g_0| + |g_1| + 2|g_mid|)``
    (rounding).  Contraction: ``max(|secant|, |jacobian|) < 1`` (NaN secants count as not contracting).
    ``path_values``: ``func`` on :func:`secant_path` ``(p + 1, B, q)`` if already computed.
    """
    diff = difference or _minus
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.atleast_2d(np.asarray(b, dtype=float))
    bsz, p = a.shape
    path = secant_path(a, b)
    mids = 0.5 * (path[1:] + path[:-1])  # (p, B, p)
    if path_values is None:
        vals = _stacked(func, np.concatenate([path, mids]))  # (2p+1, B, q)
        g0, g1, gm = vals[:p], vals[1 : p + 1], vals[p + 1 :]
    else:
        g0, g1, gm = path_values[:p], path_values[1:], _stacked(func, mids)
    flat = (p * bsz, -1)
    second = diff(g0.reshape(flat), gm.reshape(flat)) + diff(g1.reshape(flat), gm.reshape(flat))
    second = second.reshape(p, bsz, -1)
    tol = rtol * (np.abs(g0) + np.abs(g1) + 2.0 * np.abs(gm)) + 1e-300
    convex = np.moveaxis(second >= -tol, 0, -1)  # (B, q, p)
    with np.errstate(invalid="ignore"):
        contraction = np.maximum(np.abs(secant), np.abs(jacobian)) < 1.0
    return convex | contraction


def element_mask(
    selection: str, role: str, func: Callable[[Array], Array], a: Array, b: Array, secant: Array,
    jacobian: Array, difference: Difference | None = None, path_values: Array | None = None,
) -> Array:
    """Boolean mask (broadcastable to ``(B, q, p)``): True where the secant element is used."""
    q, p = secant.shape[-2:]
    if selection == "all":
        return np.ones((q, p), dtype=bool)
    if selection == "none":
        return np.zeros((q, p), dtype=bool)
    if selection == "paper-scenario2":
        mask = paper_scenario2_mask(role)
        if role == "measurement" and q != 2 and q % 2 == 0:
            mask = np.ones((q, p), dtype=bool)  # several bearing sensors: every H element is a secant
        if mask.shape != (q, p):
            raise ValueError(f"selection 'paper-scenario2' is for the 5-state ship model; got a {q}x{p} matrix")
        return mask
    if selection == "convexity":
        return convexity_mask(func, a, b, secant, jacobian, difference, path_values=path_values)
    raise ValueError(f"selection must be one of {SELECTIONS}, got {selection!r}")


def mix(secant: Array, jacobian: Array, mask: Array) -> Array:
    """Secant elements where ``mask`` (and finite), Jacobian elements elsewhere."""
    return np.where(mask & np.isfinite(secant), secant, jacobian)


# ------------------------------------------------------------------------------------------ SecKF
@dataclass
class SecantState(GaussianState):
    """A SecKF state: the Gaussian (``mean``, ``cov``) plus what the next step needs.

    After ``update``: ``prior_mean`` ``(B, n)`` is the prediction this posterior was updated from (the pair
    ``(prior_mean, mean)`` gives the next state-equation secant).  After ``predict``: ``cov`` is the
    secant-propagated prior ``P̄_G`` and ``ekf_cov`` the Jacobian-propagated ``P̄_h`` (first update).
    """

    prior_mean: Array | None = None
    ekf_cov: Array | None = None

    def copy(self) -> SecantState:
        return SecantState(
            self.mean.copy(), self.cov.copy(),
            None if self.prior_mean is None else self.prior_mean.copy(),
            None if self.ekf_cov is None else self.ekf_cov.copy(),
        )


class SecantKalmanFilter(LocalFilter):
    """Paper 3 SecKF (see the module docstring); ``selection`` picks the element rule."""

    name = "seckf"

    def __init__(
        self, motion: _Motion, measurement: MeasurementModel, selection: str = "convexity",
        min_step: float = 1e-9,
    ) -> None:
        if selection not in SELECTIONS:
            raise ValueError(f"selection must be one of {SELECTIONS}, got {selection!r}")
        self.motion = motion
        self.measurement = measurement
        self.selection = selection
        self.min_step = min_step
        self.state_dim = self.kinematic_dim = motion.dim
        #: when not None, ``{"state": [...], "measurement": [...]}``: per call, the largest relative change
        #: ``max |mixed - Jacobian| / max |Jacobian|`` over the batch (see :meth:`track_deviation`)
        self.deviation: dict[str, list[float]] | None = None

    def track_deviation(self) -> None:
        """Record how far the secant-corrected matrices move from the Jacobians (a diagnostic: where they do
        not move, SecKF is the EKF)."""
        self.deviation = {"state": [], "measurement": []}

    def _note(self, role: str, mixed: Array, jac: Array) -> Array:
        if self.deviation is not None:
            scale = np.max(np.abs(jac), axis=(-2, -1)) + 1e-300
            self.deviation[role].append(float(np.max(np.max(np.abs(mixed - jac), axis=(-2, -1)) / scale)))
        return mixed

    # -- matrices
    def state_matrix(self, prior_mean: Array | None, post_mean: Array, jac: Array) -> Array:
        """``F_sg``: SecLine[f, prior_mean, post_mean] mixed with ``jac`` (``jac`` if there is no pair)."""
        if prior_mean is None or self.selection == "none":
            return jac
        f = self.motion.f
        sec, vals = _secant_with_values(f, prior_mean, post_mean, self.min_step, None)
        mask = element_mask(self.selection, "state", f, prior_mean, post_mean, sec, jac, None, vals)
        return self._note("state", mix(sec, jac, mask), jac)

    def measurement_matrix(self, pred: Array, est: Array, sensors: Array, jac: Array) -> Array:
        """``H_sg``: SecLine[h, pred, est] mixed with ``jac`` (the Jacobian at ``pred``)."""
        if self.selection == "none":
            return jac
        meas = self.measurement
        bsz = pred.shape[0]

        def h(x: Array) -> Array:
            return meas.h(x, np.tile(sensors, (x.shape[0] // bsz, 1, 1)))

        sec, vals = _secant_with_values(h, pred, est, self.min_step, meas.residual)
        mask = element_mask(self.selection, "measurement", h, pred, est, sec, jac, meas.residual, vals)
        return self._note("measurement", mix(sec, jac, mask), jac)

    # -- LocalFilter
    def predict(self, state: GaussianState) -> SecantState:
        jac = self.motion.jacobian(state.mean)
        ekf_cov = symmetrize(congruence(jac, state.cov) + self.motion.Q)
        prior_mean = state.prior_mean if isinstance(state, SecantState) else None
        if prior_mean is None or self.selection == "none":
            cov = ekf_cov
        else:
            f_sg = self.state_matrix(prior_mean, state.mean, jac)
            cov = symmetrize(congruence(f_sg, state.cov) + self.motion.Q)
        return SecantState(self.motion.f(state.mean), cov, None, ekf_cov)

    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> SecantState:
        meas = self.measurement
        ekf_cov = state.ekf_cov if isinstance(state, SecantState) else None
        first_prior = GaussianState(state.mean, state.cov if ekf_cov is None else ekf_cov)
        z_pred, jac = meas.linearize(state.mean, sensors)
        innovation = meas.residual(z, z_pred)
        if self.selection == "none":
            first = joseph_update(first_prior, jac, innovation, noise_cov)
            return SecantState(first.mean, first.cov, state.mean)
        # steps (2)-(4): the EKF estimate (its covariance is never used, so only the mean is formed)
        pct = first_prior.cov @ np.swapaxes(jac, -1, -2)
        gain = pct @ small_inverse(jac @ pct + noise_cov)
        first_mean = state.mean + mat_vec(gain, innovation)
        h_sg = self.measurement_matrix(state.mean, first_mean, sensors, jac)
        second = joseph_update(GaussianState(state.mean, state.cov), h_sg, innovation, noise_cov)
        return SecantState(second.mean, second.cov, state.mean)


def _seckf(context: FilterContext, selection: str = "convexity", min_step: float = 1e-9) -> SecantKalmanFilter:
    return SecantKalmanFilter(context.motion, context.measurement, selection, min_step)  # type: ignore[arg-type]


FILTER_REGISTRY.register(
    "seckf", _seckf,
    (
        Param("selection", str, "convexity", choices=SELECTIONS,
              help="secant/Jacobian element rule: convexity or contraction (general), the paper's scenario-2 "
                   "mask, all secants, none (= EKF)"),
        Param("min_step", float, 1e-9, lo=0.0,
              help="below this |b_i - a_i| a secant column falls back to the Jacobian"),
    ),
    "secant Kalman filter (paper 3): EKF, then a second update with secant-corrected F and H",
)


# ------------------------------------------------------------------------------------------ linearisation
class LinearisationFilter(LocalFilter):
    """Paper 3's "linearisation solution method": a pseudo-linear snapshot LOS position fix per observation
    (see the module docstring); bearing measurements only."""

    name = "lin"

    def __init__(self, motion: _Motion, measurement: MeasurementModel) -> None:
        if getattr(measurement, "name", "") != "bearing":
            raise ValueError("the linearisation solution needs bearing (azimuth, elevation) measurements")
        self.motion = motion
        self.measurement = measurement
        self.state_dim = self.kinematic_dim = motion.dim

    def predict(self, state: GaussianState) -> GaussianState:
        jac = self.motion.jacobian(state.mean)
        cov = symmetrize(congruence(jac, state.cov) + self.motion.Q)
        return GaussianState(self.motion.f(state.mean), cov)

    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> GaussianState:
        bsz, n = state.mean.shape
        s = sensors.shape[1]
        ang = np.asarray(z, dtype=float).reshape(bsz, s, 2)
        az, el = ang[..., 0], ang[..., 1]
        ca, sa, cb, sb = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
        rows = np.zeros((bsz, 2 * s + 1, 3))
        rows[:, 0:-1:2, 0], rows[:, 0:-1:2, 1] = sa, -ca
        rows[:, 1:-1:2, 0], rows[:, 1:-1:2, 1], rows[:, 1:-1:2, 2] = sb * ca, sb * sa, -cb
        rows[:, -1, 2] = 1.0
        rhs = np.empty((bsz, 2 * s + 1))
        rhs[:, :-1] = np.einsum("bkj,bkj->bk", rows[:, :-1], np.repeat(sensors, 2, axis=1))
        rhs[:, -1] = state.mean[:, 2]
        # weights: angle error sigma times the prior range, per sensor; the height row by the prior variance
        noise = np.broadcast_to(np.asarray(noise_cov, dtype=float), (bsz, 2 * s, 2 * s))
        rng2 = np.sum((state.mean[:, None, :3] - sensors) ** 2, axis=-1)  # (B, S)
        w = np.empty((bsz, 2 * s + 1))
        w[:, :-1] = 1.0 / (np.repeat(rng2, 2, axis=1) * np.diagonal(noise, axis1=1, axis2=2))
        w[:, -1] = 1.0 / np.maximum(state.cov[:, 2, 2], 1e-12)
        normal = np.swapaxes(rows, 1, 2) @ (rows * w[..., None])
        pos_cov = np.linalg.inv(normal)
        pos = mat_vec(pos_cov, np.einsum("bkj,bk->bj", rows, w * rhs))
        mean = state.mean.copy()
        mean[:, :3] = pos
        cov = state.cov.copy()
        cov[:, :3, :] = 0.0
        cov[:, :, :3] = 0.0
        cov[:, :3, :3] = pos_cov
        return GaussianState(mean, symmetrize(cov))


def _lin(context: FilterContext, **_: Any) -> LinearisationFilter:
    return LinearisationFilter(context.motion, context.measurement)  # type: ignore[arg-type]


FILTER_REGISTRY.register(
    "lin", _lin, (),
    "linearisation solution (paper 3 ref. [8]): pseudo-linear LOS position fix per observation, z = prior height",
)
