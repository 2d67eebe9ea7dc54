"""Ship motion models of paper 3 (SecKF, video-satellite angles-only tracking), Section 4.1.1.

State ``[x, y, z, v, psi]`` in the local ENU frame at the ship's initial position (notes "Model"): ``x`` East,
``y`` North, ``z`` Up (metres), speed ``v`` (m/s) and heading ``psi`` (rad) measured from North toward East, so
the velocity is ``vE = v sin psi``, ``vN = v cos psi``.

* :class:`ShipTurnCA` — scenario 1 (seed eq. 34): constant acceleration ``a_m`` along the track and a constant
  turn rate ``w = k_psi`` (the seed's heading line is ``psi_j = psi_{j-1} + k_psi t_d``: the rate is constant,
  not ``k_psi v``; Table 5 prints its unit as rad/s^2 but eq. 34 uses it as a rate in rad/s).  The position
  step is the exact integral of ``(vE, vN) = (v(t) sin psi(t), v(t) cos psi(t))`` with ``v(t) = v + a t``,
  ``psi(t) = psi + w t`` (notes "Scenario 1"):

      Dx = [w(v cos psi - (v+aT) cos(psi+wT)) + a(sin(psi+wT) - sin psi)] / w^2
      Dy = [w((v+aT) sin(psi+wT) - v sin psi) + a(cos(psi+wT) - cos psi)] / w^2

  **Axes check**: integrating by parts, ``int_0^T (v+at) sin(psi+wt) dt`` is exactly the ``Dx`` line and
  ``int_0^T (v+at) cos(psi+wt) dt`` the ``Dy`` line, so the notes' formula assigns the axes correctly for the
  North-to-East heading convention (x East gets ``sin``, y North gets ``cos``); the seed's eq. 34 lost the
  lower-limit terms in the dump but its upper-limit terms agree.  ``tests/test_motion_ship.py`` confirms it
  against RK4 integration of the continuous dynamics.  The step is evaluated in the equivalent rotation form
  ``Dx = sin(psi) C + cos(psi) S``, ``Dy = cos(psi) C - sin(psi) S`` with ``C = int (v+at) cos(wt) dt`` and
  ``S = int (v+at) sin(wt) dt``, which avoids most of the literal formula's ``1/w^2`` cancellation (only the
  small ``a``-term of ``S``, ``~ a T^2 wT/3``, keeps some: ~1e-8 relative in that term at the switch, ~1e-13
  of the displacement), and by their Taylor series when ``|w T| < 1e-4`` (truncation ``O((wT)^6)``, below
  1e-16 relative; the paper's ``k_psi = 1e-5`` with ``T = 1`` uses the series).  ``w = 0`` is the straight
  line ``b = vT + aT^2/2`` along ``psi``.
* :class:`ShipConstantPower` — scenario 2 (seed eq. 35): ``b = v T + (P - eta v^3) T^2 / (2 m v)``,
  ``x += sin(psi) b``, ``y += cos(psi) b``, ``v += (P - eta v^3) T / (m v)``, ``psi`` constant.

Both follow the :data:`~zentrack.fusion.motion.MotionModel` interface (``f``, ``jacobian`` with analytic
Jacobians, ``Q``, ``ts``; no lumped term).  ``A`` is the Jacobian at the paper's initial truth
:data:`SHIP_X0` — a constant transition matrix for code that wants one; every filter should use ``f`` and
``jacobian``.  ``hessian_diag(x)`` gives the pure second derivatives ``d^2 f_i / d x_j^2`` that the SecKF
element selection (notes "SecKF" step 4, seed Appendix B) tests for convexity.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Array = np.ndarray

#: Truth at the first observation: position 0, v = 10 m/s, psi = pi/4 (seed Section 4.1.1).
SHIP_X0 = np.array([0.0, 0.0, 0.0, 10.0, np.pi / 4])
#: Initial estimate covariance P0 = diag(41, 41, 1, 1, 1e-4).
SHIP_P0 = np.diag([41.0, 41.0, 1.0, 1.0, 1e-4])
#: Imaging interval t_d (s).
SHIP_TS = 1.0
#: Number of observations per run.
SHIP_OBSERVATIONS = 20
#: Process noise diagonal Q = diag(1, 1, 1, 0.01, 1e-10).
SHIP_Q_DIAG = (1.0, 1.0, 1.0, 0.01, 1e-10)

_SERIES_SWITCH = 1e-4


def _check_q(q_diag: Sequence[float]) -> Array:
    q = np.asarray(q_diag, dtype=float)
    if q.shape != (5,) or np.any(q < 0):
        raise ValueError(f"q_diag must be 5 non-negative numbers, got {q_diag}")
    return q


def turn_coefficients(w: float, t: float) -> tuple[float, float, float, float]:
    """``(c1, c2, s1, s2)`` with ``C = v c1 + a c2 = int_0^T (v+at) cos(wt) dt``, ``S = v s1 + a s2 = int (v+at) sin(wt) dt``.

    Closed forms ``c1 = sin(u)/w``, ``c2 = (cos u - 1 + u sin u)/w^2``, ``s1 = (1 - cos u)/w``,
    ``s2 = (sin u - u cos u)/w^2`` (``u = wT``), written with ``1 - cos u = 2 sin^2(u/2)``; for ``|u| < 1e-4``
    the Taylor series in ``u`` (three terms each).
    """
    u = w * t
    if abs(u) < _SERIES_SWITCH:
        u2 = u * u
        c1 = t * (1.0 - u2 / 6.0 + u2 * u2 / 120.0)
        c2 = t * t * (0.5 - u2 / 8.0 + u2 * u2 / 144.0)
        s1 = t * u * (0.5 - u2 / 24.0 + u2 * u2 / 720.0)
        s2 = t * t * u * (1.0 / 3.0 - u2 / 30.0 + u2 * u2 / 840.0)
        return c1, c2, s1, s2
    su, cu = np.sin(u), np.cos(u)
    one_minus_cos = 2.0 * np.sin(0.5 * u) ** 2
    c1 = su / w
    c2 = (u * su - one_minus_cos) / (w * w)
    s1 = one_minus_cos / w
    s2 = (su - u * cu) / (w * w)
    return float(c1), float(c2), float(s1), float(s2)


def turn_displacement(v: Array, psi: Array, a: float, w: float, t: float) -> tuple[Array, Array]:
    """Exact East/North displacement ``(Dx, Dy)`` over ``t`` s of the notes' turn integral (see module docstring)."""
    c1, c2, s1, s2 = turn_coefficients(w, t)
    big_c = v * c1 + a * c2
    big_s = v * s1 + a * s2
    sp, cp = np.sin(psi), np.cos(psi)
    return sp * big_c + cp * big_s, cp * big_c - sp * big_s


class ShipTurnCA:
    """Scenario 1: constant along-track acceleration ``a_m`` and constant turn rate ``k_psi`` (seed eq. 34).

    ``x+ = x + Dx``, ``y+ = y + Dy``, ``z+ = z``, ``v+ = v + a_m T``, ``psi+ = psi + k_psi T`` plus ``N(0, Q)``.
    """

    name = "ship-turn"
    dim = 5
    lumped_dim = 0

    def __init__(
        self, ts: float = SHIP_TS, a_m: float = 0.5, k_psi: float = 1e-5, q_diag: Sequence[float] = SHIP_Q_DIAG
    ) -> None:
        if not ts > 0:
            raise ValueError(f"need ts > 0, got {ts}")
        self.ts = float(ts)
        self.a_m = float(a_m)
        self.k_psi = float(k_psi)
        q = _check_q(q_diag)
        self.Q = np.diag(q)
        self.noise_factor = np.diag(np.sqrt(q))
        self.B = np.zeros((5, 0))
        self._coef = turn_coefficients(self.k_psi, self.ts)
        self.A = self.jacobian(SHIP_X0[None, :])[0]

    def _cs(self, x: Array) -> tuple[Array, Array]:
        c1, c2, s1, s2 = self._coef
        v = x[:, 3]
        return v * c1 + self.a_m * c2, v * s1 + self.a_m * s2

    def f(self, x: Array) -> Array:
        big_c, big_s = self._cs(x)
        sp, cp = np.sin(x[:, 4]), np.cos(x[:, 4])
        out = np.array(x, dtype=float, copy=True)
        out[:, 0] += sp * big_c + cp * big_s
        out[:, 1] += cp * big_c - sp * big_s
        out[:, 3] += self.a_m * self.ts
        out[:, 4] += self.k_psi * self.ts
        return out

    def jacobian(self, x: Array) -> Array:
        c1, _, s1, _ = self._coef
        big_c, big_s = self._cs(x)
        sp, cp = np.sin(x[:, 4]), np.cos(x[:, 4])
        dx, dy = sp * big_c + cp * big_s, cp * big_c - sp * big_s
        jac = np.broadcast_to(np.eye(5), (x.shape[0], 5, 5)).copy()
        jac[:, 0, 3] = sp * c1 + cp * s1
        jac[:, 0, 4] = dy
        jac[:, 1, 3] = cp * c1 - sp * s1
        jac[:, 1, 4] = -dx
        return jac

    def hessian_diag(self, x: Array) -> Array:
        """``(B, 5, 5)``: element ``[i, j] = d^2 f_i / d x_j^2`` (linear in ``v``; ``-Dx``, ``-Dy`` in ``psi``)."""
        big_c, big_s = self._cs(x)
        sp, cp = np.sin(x[:, 4]), np.cos(x[:, 4])
        out = np.zeros((x.shape[0], 5, 5))
        out[:, 0, 4] = -(sp * big_c + cp * big_s)
        out[:, 1, 4] = -(cp * big_c - sp * big_s)
        return out

    def lumped_nominal(self, x: Array) -> None:
        return None

    def true_lumped(self, x: Array, k: int) -> Array:
        return np.zeros((x.shape[0], 0))


class ShipConstantPower:
    """Scenario 2: constant engine power ``P`` against drag ``eta v^2`` for a ship of mass ``m`` (seed eq. 35).

    ``g(v) = (P - eta v^3) / (m v)`` is the acceleration; ``b = v T + g T^2 / 2`` the distance run along the
    heading, ``x+ = x + sin(psi) b``, ``y+ = y + cos(psi) b``, ``v+ = v + g T``, ``psi+ = psi`` plus ``N(0, Q)``.
    Requires ``v != 0`` (the model divides by ``v``).
    """

    name = "ship-power"
    dim = 5
    lumped_dim = 0

    def __init__(
        self,
        ts: float = SHIP_TS,
        power: float = 2.4e5,
        eta: float = 10.0,
        mass: float = 1e4,
        q_diag: Sequence[float] = SHIP_Q_DIAG,
    ) -> None:
        if not ts > 0 or not mass > 0:
            raise ValueError(f"need ts > 0 and mass > 0, got {ts}, {mass}")
        self.ts = float(ts)
        self.power = float(power)
        self.eta = float(eta)
        self.mass = float(mass)
        q = _check_q(q_diag)
        self.Q = np.diag(q)
        self.noise_factor = np.diag(np.sqrt(q))
        self.B = np.zeros((5, 0))
        self.A = self.jacobian(SHIP_X0[None, :])[0]

    def accel(self, v: Array) -> Array:
        """``g(v) = (P - eta v^3) / (m v)`` (m/s^2)."""
        return (self.power - self.eta * v**3) / (self.mass * v)

    def accel_dv(self, v: Array) -> Array:
        """``g'(v) = -P / (m v^2) - 2 eta v / m``."""
        return -self.power / (self.mass * v * v) - 2.0 * self.eta * v / self.mass

    def f(self, x: Array) -> Array:
        t = self.ts
        v = x[:, 3]
        g = self.accel(v)
        b = v * t + 0.5 * g * t * t
        out = np.array(x, dtype=float, copy=True)
        out[:, 0] += np.sin(x[:, 4]) * b
        out[:, 1] += np.cos(x[:, 4]) * b
        out[:, 3] += g * t
        return out

    def jacobian(self, x: Array) -> Array:
        t = self.ts
        v = x[:, 3]
        g, dg = self.accel(v), self.accel_dv(v)
        b = v * t + 0.5 * g * t * t
        db = t + 0.5 * dg * t * t
        sp, cp = np.sin(x[:, 4]), np.cos(x[:, 4])
        jac = np.broadcast_to(np.eye(5), (x.shape[0], 5, 5)).copy()
        jac[:, 0, 3] = sp * db
        jac[:, 0, 4] = cp * b
        jac[:, 1, 3] = cp * db
        jac[:, 1, 4] = -sp * b
        jac[:, 3, 3] = 1.0 + dg * t
        return jac

    def hessian_diag(self, x: Array) -> Array:
        """``(B, 5, 5)``: ``[i, j] = d^2 f_i / d x_j^2`` (seed Appendix B: ``d^2 x / dv^2 = sin(psi)(P/(m v^3) - eta/m) T^2``)."""
        t = self.ts
        v = x[:, 3]
        g = self.accel(v)
        b = v * t + 0.5 * g * t * t
        d2g = 2.0 * self.power / (self.mass * v**3) - 2.0 * self.eta / self.mass
        sp, cp = np.sin(x[:, 4]), np.cos(x[:, 4])
        out = np.zeros((x.shape[0], 5, 5))
        out[:, 0, 3] = sp * 0.5 * d2g * t * t
        out[:, 0, 4] = -sp * b
        out[:, 1, 3] = cp * 0.5 * d2g * t * t
        out[:, 1, 4] = -cp * b
        out[:, 3, 3] = d2g * t
        return out

    def lumped_nominal(self, x: Array) -> None:
        return None

    def true_lumped(self, x: Array, k: int) -> Array:
        return np.zeros((x.shape[0], 0))
