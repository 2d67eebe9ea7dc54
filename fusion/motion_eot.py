"""Extended-object motion of paper 4 (MEM information filter): NCV kinematics plus a random-walk extent.

The state is 7-dimensional, ``[m1, m2, v1, v2, alpha, l1, l2]``: the centre ``m``, its velocity, the
orientation ``alpha`` (counter-clockwise from the x axis, rad; continuous, never wrapped) and the two
semi-axes ``l1``, ``l2``.  Paper 4 eqs. (4)-(5) with the nearly-constant-velocity example below them::

    x+ = F^x x + w^x,  F^x = [[1, 0, T, 0], [0, 1, 0, T], [0, 0, 1, 0], [0, 0, 0, 1]],  w^x ~ N(0, C^x_w)
    p+ = F^p p + w^p,  F^p = I3,                                                       w^p ~ N(0, C^p_w)

so ``A = blockdiag(F^x, I3)`` and ``Q = blockdiag(C^x_w, C^p_w)``.  The two blocks are independent: the
filters of :mod:`zentrack.fusion.filters.mem` keep a block-diagonal covariance.

The model exposes the :data:`~zentrack.fusion.motion.MotionModel` attributes (``name``, ``dim``, ``ts``, ``A``,
``B``, ``Q``, ``noise_factor``, ``f``, ``jacobian``, ``lumped_nominal``, ``true_lumped``) with no lumped term
(``lumped_dim = 0``, like :class:`~zentrack.fusion.motion_ca.ConstantAcceleration3D`), so scenario code can
propagate a truth with ``A x + w`` like any other linear plant.

The module constants are the paper's tracker settings for its scenarios S2 (ellipse, Table 2, Sec. 7.2.1)
and S3 (rectangle, Table 3, Sec. 7.2.2), checked against the text of ``seeds/004_b87fee654ab67f10.txt``.
"""
from __future__ import annotations

import numpy as np

Array = np.ndarray

# ---------------------------------------------------------------------------------------------- paper S2
# Paper 4 Sec. 7.2.1 and Table 2 ("Tracker Parameter Setting in S2"): an ellipse with semi-axes 170 m and
# 40 m moving at 50 km/h, scan time T = 10 s, Poisson(lambda) points per sensor and scan, lambda in {5, 10}.
S2_TS = 10.0  #: T (s)
S2_SPEED = 50.0 / 3.6  #: 50 km/h in m/s
S2_SEMI_AXES = (170.0, 40.0)  #: true l1, l2 (m)
S2_MEAS_NOISE = np.diag([200.0, 8.0])  #: C^v_s (m^2)
S2_SPREAD = np.eye(2) / 4.0  #: C^h: h uniform on the unit disc (an elliptical object)
S2_Q_KINEMATIC = np.diag([100.0, 100.0, 1.0, 1.0])  #: C^x_w
S2_Q_EXTENT = np.diag([0.05, 1.0, 1.0])  #: C^p_w
S2_PRIOR_KINEMATIC = np.diag([100.0, 100.0, 10.0, 10.0])  #: C^x_{1,s}[0]
S2_PRIOR_EXTENT = np.diag([0.36, 70.0, 40.0])  #: C^p_{1,s}[0]

# ---------------------------------------------------------------------------------------------- paper S3
# Paper 4 Sec. 7.2.2 and Table 3 ("Tracker Parameter Settings in S3"): a rectangle with semi-axes 10 m and
# 5 m on the same path and speed, T = 10 s.
S3_TS = 10.0
S3_SPEED = 50.0 / 3.6
S3_SEMI_AXES = (10.0, 5.0)
S3_MEAS_NOISE = np.eye(2)  #: C^v_s = diag(1, 1)
S3_SPREAD = np.eye(2) / 3.0  #: C^h: h uniform on [-1, 1]^2 (a rectangular object)
S3_Q_KINEMATIC = np.diag([50.0, 50.0, 1.0, 1.0])
S3_Q_EXTENT = np.diag([0.05, 0.01, 0.001])
S3_PRIOR_KINEMATIC = np.diag([50.0, 50.0, 1.0, 1.0])
S3_PRIOR_EXTENT = np.diag([0.36, 5.0, 5.0])

#: the paper's settings by scenario name: ts, C^x_w, C^p_w, prior C^x, prior C^p, C^v, C^h, semi-axes, speed
PAPER_SETTINGS: dict[str, dict[str, object]] = {
    "s2": {"ts": S2_TS, "q_kinematic": S2_Q_KINEMATIC, "q_extent": S2_Q_EXTENT, "prior_kinematic": S2_PRIOR_KINEMATIC,
           "prior_extent": S2_PRIOR_EXTENT, "noise_cov": S2_MEAS_NOISE, "spread": S2_SPREAD,
           "semi_axes": S2_SEMI_AXES, "speed": S2_SPEED},
    "s3": {"ts": S3_TS, "q_kinematic": S3_Q_KINEMATIC, "q_extent": S3_Q_EXTENT, "prior_kinematic": S3_PRIOR_KINEMATIC,
           "prior_extent": S3_PRIOR_EXTENT, "noise_cov": S3_MEAS_NOISE, "spread": S3_SPREAD,
           "semi_axes": S3_SEMI_AXES, "speed": S3_SPEED},
}


def ncv_transition(ts: float) -> Array:
    """``F^x`` of paper 4 (below eq. 5): 2-D nearly constant velocity, state ``[m1, m2, v1, v2]``."""
    f = np.eye(4)
    f[0, 2] = f[1, 3] = ts
    return f


def _psd_factor(q: Array) -> Array:
    """A square root ``G`` with ``G G^T = q`` (Cholesky when positive definite, else from the eigenvalues)."""
    try:
        return np.linalg.cholesky(q)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(q)
        return v * np.sqrt(np.clip(w, 0.0, None))


class ExtendedObjectMotion:
    """NCV centre plus random-walk extent (paper 4 eqs. 4-5): state ``[m1, m2, v1, v2, alpha, l1, l2]``.

    ``q_kinematic`` is ``C^x_w`` (4 x 4), ``q_extent`` ``C^p_w`` (3 x 3); both symmetric positive semidefinite.
    """

    name = "eot"
    dim = 7
    lumped_dim = 0
    kinematic_dim = 4
    extent_dim = 3

    def __init__(self, ts: float, q_kinematic: Array, q_extent: Array) -> None:
        q_kinematic = np.asarray(q_kinematic, dtype=float)
        q_extent = np.asarray(q_extent, dtype=float)
        if not ts > 0:
            raise ValueError(f"need ts > 0, got {ts}")
        if q_kinematic.shape != (4, 4) or q_extent.shape != (3, 3):
            raise ValueError(f"q_kinematic must be 4x4 and q_extent 3x3, got {q_kinematic.shape}, {q_extent.shape}")
        for name, q in (("q_kinematic", q_kinematic), ("q_extent", q_extent)):
            if not np.all(np.isfinite(q)) or not np.allclose(q, q.T) or np.linalg.eigvalsh(q)[0] < -1e-12 * max(
                    np.abs(q).max(), 1.0):
                raise ValueError(f"{name} must be finite, symmetric and positive semidefinite, got {q.tolist()}")
        self.ts = float(ts)
        self.q_kinematic = q_kinematic
        self.q_extent = q_extent
        self.F_kinematic = ncv_transition(self.ts)  # F^x
        self.F_extent = np.eye(3)  # F^p
        self.A = np.zeros((7, 7))
        self.A[:4, :4] = self.F_kinematic
        self.A[4:, 4:] = self.F_extent
        self.B = np.zeros((7, 0))
        self.Q = np.zeros((7, 7))
        self.Q[:4, :4] = q_kinematic
        self.Q[4:, 4:] = q_extent
        self.noise_factor = np.zeros((7, 7))
        self.noise_factor[:4, :4] = _psd_factor(q_kinematic)
        self.noise_factor[4:, 4:] = _psd_factor(q_extent)

    @classmethod
    def paper(cls, scenario: str = "s2", ts: float | None = None) -> ExtendedObjectMotion:
        """The motion of paper 4's scenario ``"s2"`` (ellipse) or ``"s3"`` (rectangle), Tables 2-3."""
        if scenario not in PAPER_SETTINGS:
            raise ValueError(f"scenario must be one of {tuple(PAPER_SETTINGS)}, got {scenario!r}")
        s = PAPER_SETTINGS[scenario]
        return cls(float(s["ts"]) if ts is None else ts, s["q_kinematic"], s["q_extent"])  # type: ignore[arg-type]

    def f(self, x: Array) -> Array:
        return x @ self.A.T

    def jacobian(self, x: Array) -> Array:
        return np.broadcast_to(self.A, (x.shape[0], 7, 7)).copy()

    def lumped_nominal(self, x: Array) -> None:
        return None

    def true_lumped(self, x: Array, k: int) -> Array:
        return np.zeros((x.shape[0], 0))
