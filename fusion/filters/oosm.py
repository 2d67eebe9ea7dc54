"""An out-of-sequence measurement (OOSM): a detection measured before the time the estimate is valid at.

A tracker whose estimate is valid at ``t_c`` (it has predicted, updated and fused up to there) receives a detection
measured at ``tau < t_c``. Rather than roll back and re-process everything after ``tau``, the one-step solution
**Al1** updates the current estimate directly (Bar-Shalom, "Update with out-of-sequence measurements in tracking:
exact solution", IEEE Trans. Aerospace and Electronic Systems 38(3), 2002, algorithm A; Bar-Shalom, Chen & Mallick,
"One-step solution for the multistep out-of-sequence-measurement problem in tracking", IEEE TAES 40(1), 2004, for a
lag of several steps). With ``k`` the current time ``t_c`` and ``kappa`` the detection's ``tau``, the model between
them is ``x(k) = F(k,kappa) x(kappa) + v(k,kappa)``, ``v ~ N(0, Q(k,kappa))``, and the last update, at ``k``, had
matrix ``H(k)``, innovation ``nu(k)`` and covariance ``S(k)`` on the prediction ``P(k|k-1)``. Then (2002, Section
III, algorithm A)::

    retrodicted noise    v^(k,kappa|k) = Q(k,kappa) H(k)' S(k)^-1 nu(k)
    retrodicted state    x^(kappa|k)   = F(kappa,k) [x^(k|k) - v^(k,kappa|k)],        F(kappa,k) = F(k,kappa)^-1
    noise covariance     P_vv(k,kappa) = Q(k,kappa) - Q(k,kappa) H(k)' S(k)^-1 H(k) Q(k,kappa)
    state-noise          P_xv(k,kappa) = Q(k,kappa) - P(k|k-1) H(k)' S(k)^-1 H(k) Q(k,kappa)
    retrodicted cov.     P(kappa|k)    = F(kappa,k) [P(k|k) + P_vv - P_xv - P_xv'] F(kappa,k)'
    cross covariance     P_xz(k,kappa) = [P(k|k) - P_xv(k,kappa)] F(kappa,k)' H(kappa)'
    innovation cov.      S(kappa)      = H(kappa) P(kappa|k) H(kappa)' + R(kappa)
    update               x^(k|kappa)   = x^(k|k) + P_xz S(kappa)^-1 [z(kappa) - H(kappa) x^(kappa|k)]
                         P(k|kappa)    = P(k|k) - P_xz S(kappa)^-1 P_xz'

For a linear-Gaussian system whose only update after ``kappa`` was the one at ``k`` this is exact: the result equals
re-processing (``tests/test_bench_async.py`` checks it to rounding). (Algorithm B of the same paper, "Bl1" in the
2004 one, is its cheaper approximation without the retrodicted noise ``v^``.)

**Several updates after kappa** (2004, the *equivalent measurement*): keep the estimate at some ``t_s <= tau`` before
them; everything that moved the estimate from its prediction ``x^(k|s)``, ``P(k|s)`` (predicted from ``t_s`` to
``k`` in one interval) to ``x^(k|k)``, ``P(k|k)`` counts as one measurement of ``x(k)`` with ``H* = I``. Its terms
above need no ``R*``: from ``P(k|k)^-1 = P(k|s)^-1 + R*^-1`` and the update's information form,

    H*' S*^-1 H*  = P(k|s)^-1 - P(k|s)^-1 P(k|k) P(k|s)^-1
    H*' S*^-1 nu* = P(k|s)^-1 (x^(k|k) - x^(k|s)),          with P(k|k-1) -> P(k|s).

That also covers what is no Kalman update at all: a tracker's covariance-intersection fusion with its neighbours
between ``t_s`` and ``k`` is folded into the equivalent measurement (an approximation: CI is not a measurement).

**The measurement step** is the filter's own update: the retrodicted estimate ``(x^(kappa|k), P(kappa|k))`` is
updated with the detection by the tracker's filter (its linearisation at the retrodicted state, its noise, angle
wrapping and Joseph form), giving ``x+``, ``P+``; since that update is ``x+ = x + P H' S^-1 nu``,
``P+ = P - P H' S^-1 H P``, the two products the current estimate needs are read off it,
``H' S^-1 nu = P^-1 (x+ - x)`` and ``H' S^-1 H = P^-1 - P^-1 P+ P^-1``, and with ``C = [P(k|k) - P_xv] F(kappa,k)'``
the update above is ``x^(k|kappa) = x^(k|k) + C H' S^-1 nu``, ``P(k|kappa) = P(k|k) - C H' S^-1 H C'``. So a
filter with extra states (the TESKF's lumped term) or a scaled noise (its ``R / (1 + theta)``) is updated as its own
update would, and a bearing is linearised where the target was at ``tau``.

**F and Q** over ``k - kappa`` are read off the filter's own prediction over that interval
(:func:`linear_parts`): ``F`` from the predicted means of the unit vectors, ``Q`` from the prediction of a zero
covariance. For a Kalman filter these are its model's; the TESKF's prediction also inflates the covariance by
``(1 + theta)`` (paper 0 Theorem 1's bound), which the retrodiction leaves out (``P(k|s)``, predicted by the filter
itself, has it).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..estimates import Estimate, GaussianEstimate
from ..linalg import symmetrize
from ..scan import Scan
from .base import NodeFilter
from .interval import INTERVAL_TOLERANCE_S, IntervalPredictor

Array = np.ndarray
Correct = Callable[[Estimate, Sequence[Scan]], Estimate]


def linear_parts(filt: NodeFilter, dim: int, kinematic_dim: int) -> tuple[Array, Array]:
    """``(F, Q)`` of a filter whose prediction is ``x+ = F x``, ``P+ = F P F' + Q`` (module docstring): F from
    the predicted means of the ``dim`` unit vectors, Q from the prediction of a zero covariance."""
    zero = filt.predict(GaussianEstimate(np.zeros(dim), np.zeros((dim, dim)), kinematic_dim))
    assert isinstance(zero, GaussianEstimate)
    f = np.empty((dim, dim))
    for j in range(dim):
        unit = np.zeros(dim)
        unit[j] = 1.0
        moved = filt.predict(GaussianEstimate(unit, np.zeros((dim, dim)), kinematic_dim))
        assert isinstance(moved, GaussianEstimate)
        f[:, j] = moved.mean - zero.mean
    return f, symmetrize(zero.cov)


class OutOfSequence:
    """Al1 (module docstring) for one tracker's filter: :meth:`update` takes the current estimate (valid at
    ``t_c``), an estimate it stored at ``t_s <= tau`` and the detection measured at ``tau``."""

    #: the (F, Q) of this many intervals are kept (the least recently used goes first)
    KEPT = 64

    def __init__(self, predictor: IntervalPredictor, correct: Correct) -> None:
        self.predictor, self.correct = predictor, correct
        self._parts: dict[float, tuple[Array, Array]] = {}

    def parts(self, dt: float, dim: int, kinematic_dim: int) -> tuple[Array, Array]:
        """``(F, Q)`` of the filter's prediction over ``dt`` seconds (identity and zero for no time)."""
        if dt <= INTERVAL_TOLERANCE_S:
            return np.eye(dim), np.zeros((dim, dim))
        key = round(dt, 9)
        found = self._parts.pop(key, None)
        if found is None:
            found = linear_parts(self.predictor.filter_for(dt), dim, kinematic_dim)
        self._parts[key] = found  # (re)inserted last: the most recently used
        if len(self._parts) > self.KEPT:
            del self._parts[next(iter(self._parts))]
        return found

    def update(self, current: GaussianEstimate, t_c: float, stored: GaussianEstimate, t_s: float, tau: float,
               scan: Scan) -> GaussianEstimate:
        """``current`` (valid at ``t_c``) updated with ``scan`` measured at ``tau`` (``t_s <= tau <= t_c``), given
        the estimate ``stored`` the tracker held at ``t_s`` (the last one at or before ``tau``)."""
        n, kin = current.dim, current.kinematic_dim
        x_c, p_c = current.mean, current.cov
        # the equivalent measurement of everything between t_s and t_c (Bar-Shalom, Chen & Mallick 2004)
        predicted = self.predictor.predict(stored, t_c - t_s)
        assert isinstance(predicted, GaussianEstimate)
        u = np.linalg.inv(predicted.cov)  # P(k|s)^-1
        hsh = u - u @ p_c @ u  # H*' S*^-1 H*
        hsn = u @ (x_c - predicted.mean)  # H*' S*^-1 nu*
        # retrodiction to tau (Bar-Shalom 2002, algorithm A)
        f, q = self.parts(t_c - tau, n, kin)
        f_back = np.linalg.inv(f)  # F(kappa, k)
        v_hat = q @ hsn
        p_vv = q - q @ hsh @ q
        p_xv = q - predicted.cov @ hsh @ q
        x_tau = f_back @ (x_c - v_hat)
        p_tau = symmetrize(f_back @ (p_c + p_vv - p_xv - p_xv.T) @ f_back.T)
        # the filter's own update at tau, carried to t_c by the cross covariance
        retro = GaussianEstimate(x_tau, p_tau, kin)
        post = self.correct(retro, [scan])
        assert isinstance(post, GaussianEstimate)
        p_tau_inv = np.linalg.inv(p_tau)
        gain_nu = p_tau_inv @ (post.mean - x_tau)  # H' S^-1 nu
        gain_h = p_tau_inv - p_tau_inv @ post.cov @ p_tau_inv  # H' S^-1 H
        cross = (p_c - p_xv) @ f_back.T  # cov(x(k), x(kappa) | Z^k)
        return GaussianEstimate(x_c + cross @ gain_nu, symmetrize(p_c - cross @ gain_h @ cross.T), kin)
