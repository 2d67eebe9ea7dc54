"""Continuous-discrete constant-velocity target of paper 1 (DPDA-FPF, Section 5.1).

The target follows the stochastic differential equation ``dX = A X dt + B dW`` with ``X = [p; v]`` (6),
``A = [[0, I], [0, 0]]`` and ``B = [0; I] sqrt(q)`` (``q``: diffusion intensity, m^2/s^3); scans arrive every
``ts`` seconds.  As in the paper, the truth and the particles are propagated by Euler–Maruyama with
``em_steps`` steps of ``dt = ts / em_steps`` per scan.

For the Gaussian filters (EKF-based comparators) and the PCRLB the model offers the discrete form of the
paper 0 interface ``x+ = A x + w``: ``A = exp(A_c ts) = [[I, ts I], [0, I]]`` and ``Q`` the covariance of
the composite Euler–Maruyama map over one scan,

    Q = q dt sum_{j=0}^{em_steps-1} F_dt^j B0 B0^T F_dt^jT,   F_dt = [[I, dt I], [0, I]],  B0 = [0; I],

so a truth simulated by :meth:`ContinuousCV3D.euler_maruyama` is *exactly* the linear-Gaussian model
``(A, Q)``.  As ``em_steps`` grows, ``Q`` tends to the exact discretisation
``q [[ts^3/3 I, ts^2/2 I], [ts^2/2 I, ts I]]``.
"""
from __future__ import annotations

import numpy as np

Array = np.ndarray


class ContinuousCV3D:
    """3-D constant velocity driven by white acceleration noise of intensity ``q``, Euler–Maruyama in time.

    Exposes the attributes of :data:`~zentrack.fusion.motion.MotionModel` (``A``, ``B``, ``Q``, ``ts``,
    ``f``, ``jacobian``, ``lumped_nominal``, ``true_lumped``) so Kalman-type filters run on it unchanged.
    """

    name = "cv3d-cd"
    dim = 6
    lumped_dim = 3

    def __init__(self, ts: float = 1.0, q: float = 0.1, em_steps: int = 10) -> None:
        # (ts < 0 predicts back, with the noise of |ts|: models.plant_over)
        if not (np.isfinite(ts) and ts != 0) or not q >= 0 or em_steps < 1:
            raise ValueError(f"need ts finite and not 0, q >= 0 and em_steps >= 1, got {ts}, {q}, {em_steps}")
        self.ts = float(ts)
        self.q = float(q)
        self.em_steps = int(em_steps)
        self.dt = self.ts / self.em_steps
        eye, zero = np.eye(3), np.zeros((3, 3))
        self.A = np.block([[eye, self.ts * eye], [zero, eye]])
        self.B = np.vstack([zero, self.ts * eye])
        f_dt = np.block([[eye, self.dt * eye], [zero, eye]])
        b0 = np.vstack([zero, eye])
        q_em = np.zeros((6, 6))
        f_j = np.eye(6)
        for _ in range(self.em_steps):
            g = f_j @ b0
            q_em += g @ g.T
            f_j = f_dt @ f_j
        self.Q = self.q * self.dt * q_em

    def exact_q(self) -> Array:
        """The exact discretisation ``q [[T^3/3 I, T^2/2 I], [T^2/2 I, T I]]`` (the em_steps -> inf limit of Q)."""
        t = self.ts
        return self.q * np.kron(np.array([[t**3 / 3, t**2 / 2], [t**2 / 2, t]]), np.eye(3))

    def euler_maruyama(self, x: Array, rng: np.random.Generator) -> Array:
        """One scan period of Euler–Maruyama: ``em_steps`` times ``p += v dt``, ``v += sqrt(q dt) xi``.

        ``x`` ``(..., 6)``; returns a new array of the same shape.
        """
        x = np.array(x, dtype=float, copy=True)
        scale = np.sqrt(self.q * self.dt)
        for _ in range(self.em_steps):
            x[..., :3] += self.dt * x[..., 3:6]
            x[..., 3:6] += scale * rng.standard_normal(x.shape[:-1] + (3,))
        return x

    def simulate(self, x0: Array, runs: int, steps: int, rng: np.random.Generator) -> Array:
        """Truth ``(runs, steps, 6)`` from ``x0`` ``(6,)`` (sample 0 is ``x0``), Euler–Maruyama between scans."""
        truth = np.empty((runs, steps, self.dim))
        x = np.broadcast_to(np.asarray(x0, dtype=float), (runs, self.dim)).copy()
        for k in range(steps):
            truth[:, k] = x
            x = self.euler_maruyama(x, rng)
        return truth

    # -- the discrete MotionModel interface (paper 0 eq. 2 form with F = 0) --
    def f(self, x: Array) -> Array:
        return x @ self.A.T

    def jacobian(self, x: Array) -> Array:
        return np.broadcast_to(self.A, (x.shape[0], 6, 6)).copy()

    def lumped_nominal(self, x: Array) -> None:
        return None

    def true_lumped(self, x: Array, k: int) -> Array:
        return np.zeros((x.shape[0], self.lumped_dim))
