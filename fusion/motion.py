"""Motion models in the affine-in-uncertainty form of paper 0 eq. 2: ``x+ = A x + B F(x, k) + w``.

Each model exposes
- ``A`` ``(n, n)``, ``B`` ``(n, l)``, ``Q`` ``(n, n)``, ``ts``: the nominal linear part, the lumped-input map and
  the process noise;
- ``f(x)`` / ``jacobian(x)``: the nominal nonlinear dynamics used by EKF/UKF/CKF (paper 0 Section 6: those
  filters use the known nonlinearity in their prediction);
- ``lumped_nominal(x)``: the nominal lumped term F_nom used for the saturated injection of extended-state
  filters, or ``None`` when the paper gives none;
- ``true_lumped(x, k)``: the lumped term of the simulated plant (truth only; never given to filters).
All take stacks ``x`` ``(B, n)``.
"""
from __future__ import annotations

import numpy as np

from .motion_ca import ConstantAcceleration3D
from .motion_cd import ContinuousCV3D

Array = np.ndarray


class Exp1Plant:
    """Paper 0 Experiment 1 (eq. 63): ``x+ = [[1,Ts],[-Ts,1]] x + [0;Ts](sin(x1^2+x2^2) + d_k) + w``.

    ``d_k = 0.3 sin(0.1 k)`` is the unmodelled input: present in the truth, absent from every filter.
    """

    name = "exp1"
    dim = 2
    lumped_dim = 1

    def __init__(self, ts: float = 0.1, q: float = 0.1, d_amp: float = 0.3, d_freq: float = 0.1) -> None:
        self.ts = ts
        self.A = np.array([[1.0, ts], [-ts, 1.0]])
        self.B = np.array([[0.0], [ts]])
        self.Q = q * np.eye(2)
        self.d_amp = d_amp
        self.d_freq = d_freq

    def lumped_nominal(self, x: Array) -> Array:
        return np.sin(x[:, 0:1] ** 2 + x[:, 1:2] ** 2)

    def true_lumped(self, x: Array, k: int) -> Array:
        return self.lumped_nominal(x) + self.d_amp * np.sin(self.d_freq * k)

    def f(self, x: Array) -> Array:
        return x @ self.A.T + self.lumped_nominal(x) @ self.B.T

    def jacobian(self, x: Array) -> Array:
        c = 2.0 * np.cos(x[:, 0] ** 2 + x[:, 1] ** 2)
        jac = np.broadcast_to(self.A, (x.shape[0], 2, 2)).copy()
        jac[:, 1, 0] += self.ts * c * x[:, 0]
        jac[:, 1, 1] += self.ts * c * x[:, 1]
        return jac


class ManeuveringCV3D:
    """Paper 0 Experiment 2 (eq. 66): constant velocity with a velocity-dependent acceleration.

    ``p+ = p + Ts v + w_p``, ``v+ = v + Ts a_nl(v) + w_v``, ``a_nl(v) = alpha sin(beta v^2)`` element-wise.
    zentrack's ``turn_rate`` (rad/s, default 0: the paper's model) adds a horizontal coordinated turn,
    ``a_nl(v) += turn_rate [-v_y, v_x, 0]``: a target that circles at the speed it has.
    Extended-state filters see only the constant-velocity nominal (``lumped_nominal`` is ``None``) and
    estimate the acceleration as the lumped term; EKF/UKF/CKF predict with ``a_nl``.
    """

    name = "cv3d"
    dim = 6
    lumped_dim = 3

    def __init__(self, ts: float = 0.1, sigma_w: float = 1.0, alpha: float = 1.2, beta: float = 2.5,
                 turn_rate: float = 0.0) -> None:
        self.ts = ts
        self.turn = turn_rate * np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
        eye = np.eye(3)
        self.A = np.block([[eye, ts * eye], [np.zeros((3, 3)), eye]])
        self.B = np.vstack([np.zeros((3, 3)), ts * eye])
        self.Q = sigma_w**2 * np.eye(6)
        self.alpha = alpha
        self.beta = beta

    def a_nl(self, v: Array) -> Array:
        return self.alpha * np.sin(self.beta * v * v) + v @ self.turn.T

    def lumped_nominal(self, x: Array) -> None:
        return None

    def true_lumped(self, x: Array, k: int) -> Array:
        return self.a_nl(x[:, 3:6])

    def f(self, x: Array) -> Array:
        return x @ self.A.T + self.a_nl(x[:, 3:6]) @ self.B.T

    def jacobian(self, x: Array) -> Array:
        v = x[:, 3:6]
        da = self.alpha * np.cos(self.beta * v * v) * 2.0 * self.beta * v
        jac = np.broadcast_to(self.A, (x.shape[0], 6, 6)).copy()
        idx = np.arange(3, 6)
        jac[:, idx, idx] += self.ts * da
        jac[:, 3:6, 3:6] += self.ts * self.turn
        return jac


MotionModel = Exp1Plant | ManeuveringCV3D | ContinuousCV3D | ConstantAcceleration3D
