"""Extended-object geometry and metrics (paper 4); the truth path, point sampling and network placement that
simulate its scenarios are :mod:`zentrack.truth.simulation.eot_scenario`.

Paper 4 (distributed extended object tracking information filters, MEM point measurements) tracks one
object whose extent is ``p = [alpha, l1, l2]``: orientation ``alpha`` in radians from the x axis and the
semi-axes ``l1``, ``l2``. Centres ``m`` are ``(..., 2)``. Every function here is pure numpy and batched
over leading axes (extents and centres broadcast against each other).

What the paper itself gives, and what comes from elsewhere:

* Extent model (paper eq. 3): ``y = H x + S h + v`` with ``S = R(alpha) diag(l1, l2)``; ``h`` has
  covariance ``C^h = I/4`` (ellipse, uniform on the unit disc) or ``I/3`` (rectangle, uniform on the
  square). :func:`~zentrack.truth.simulation.eot_scenario.sample_extent_points` draws such scans, Poisson(lambda) points per scan.
* Metrics (paper Sec. 7, first paragraph): the Gaussian Wasserstein distance (GWD) for ellipses and OSPA
  on the four rectangle vertices, both "[22, 23]" (Yang & Baum) with no formula and no OSPA parameters in
  the paper (OSPA itself is :func:`zentrack.fusion.multitarget.metrics.ospa`; its parameters for paper 4 are
  here); the ACEE is defined in the paper (Sec. 7.1, an unnumbered display just after Fig. 7).
* The S2/S3 path (paper Fig. 8) and the network (paper Fig. 4) are figures only; see
  :func:`~zentrack.truth.simulation.eot_scenario.s2_trajectory` and
  :func:`~zentrack.truth.simulation.eot_scenario.place_network` for what is taken from where and what is our choice.
"""
from __future__ import annotations

import numpy as np

Array = np.ndarray

#: OSPA order p. The paper gives no OSPA parameters (Sec. 7 cites [22, 23]); p = 2 is our choice.
OSPA_ORDER = 2.0
#: Suggested OSPA cut-off c (m) for S3 (10 m x 5 m semi-axes, C^v = I, prior position variance 50 m^2).
#: Our choice, not the paper's: large enough that a tracking filter's corner errors are not saturated.
OSPA_CUTOFF_S3 = 50.0

# --------------------------------------------------------------------------------------------------------
# geometry


def rotation(alpha: Array) -> Array:
    """R(alpha) = [[cos, -sin], [sin, cos]], ``(..., 2, 2)``."""
    a = np.asarray(alpha, dtype=float)
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def shape_factor(p: Array) -> Array:
    """S = R(alpha) diag(l1, l2) (paper eq. 3), ``(..., 2, 2)``."""
    p = np.asarray(p, dtype=float)
    return rotation(p[..., 0]) * p[..., None, 1:3]  # scales the columns: R diag(l1, l2)


def shape_matrix(p: Array) -> Array:
    """X = S S^T = R(alpha) diag(l1^2, l2^2) R(alpha)^T, ``(..., 2, 2)``."""
    s = shape_factor(p)
    return s @ np.swapaxes(s, -1, -2)


def sqrtm_2x2(a: Array) -> Array:
    """Principal square root of symmetric positive semi-definite 2x2 matrices, ``(..., 2, 2)``.

    Closed form: sqrt(A) = (A + sqrt(det A) I) / sqrt(tr A + 2 sqrt(det A)); the zero matrix maps to zero.
    """
    a = np.asarray(a, dtype=float)
    s = np.sqrt(np.clip(np.linalg.det(a), 0.0, None))
    t = np.sqrt(np.clip(np.trace(a, axis1=-2, axis2=-1) + 2.0 * s, 0.0, None))
    num = a + s[..., None, None] * np.eye(2)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / t[..., None, None]
    return np.where((t > 0)[..., None, None], out, 0.0)


def gaussian_wasserstein(m_a: Array, p_a: Array, m_b: Array, p_b: Array, squared: bool = False) -> Array:
    """Gaussian Wasserstein distance (GWD) between ellipses ``(m_a, p_a)`` and ``(m_b, p_b)``, ``(...)``.

    d^2 = |m_a - m_b|^2 + tr(X_a + X_b - 2 (X_a^{1/2} X_b X_a^{1/2})^{1/2}), X = shape_matrix(p).

    Distance or square: paper 4 names the "GWD distance" (Sec. 7, Figs. 9-10) without a formula and cites
    Yang & Baum [22, 23], whose metric (Yang, Baum, Granstrom, MFI 2016) is the 2-Wasserstein distance
    between N(m_a, X_a) and N(m_b, X_b), i.e. the square root of the expression above, in metres; their
    published evaluation code also returns the root. So this returns the distance d (metres);
    ``squared=True`` returns d^2.

    The trace of the inner root uses the closed form of the 2x2 square root (see :func:`sqrtm_2x2`):
    tr sqrt(B) = sqrt(tr B + 2 sqrt(det B)), with tr B = tr(X_a X_b) and sqrt(det B) = l1a l2a l1b l2b,
    which needs no matrix root at all and is exact for singular (degenerate) shapes too.
    """
    m_a, m_b = np.asarray(m_a, dtype=float), np.asarray(m_b, dtype=float)
    p_a, p_b = np.asarray(p_a, dtype=float), np.asarray(p_b, dtype=float)
    xa, xb = shape_matrix(p_a), shape_matrix(p_b)
    tr_b = np.einsum("...ij,...ji->...", xa, xb)  # tr(X_a X_b) = tr(X_a^{1/2} X_b X_a^{1/2})
    sqrt_det_b = np.abs(p_a[..., 1] * p_a[..., 2] * p_b[..., 1] * p_b[..., 2])
    tr_root = np.sqrt(np.clip(tr_b + 2.0 * sqrt_det_b, 0.0, None))
    shape_term = np.trace(xa, axis1=-2, axis2=-1) + np.trace(xb, axis1=-2, axis2=-1) - 2.0 * tr_root
    d2 = np.sum((m_a - m_b) ** 2, axis=-1) + shape_term
    d2 = np.clip(d2, 0.0, None)  # rounding can leave a tiny negative for equal ellipses
    return d2 if squared else np.sqrt(d2)


def rectangle_corners(m: Array, p: Array) -> Array:
    """The four vertices of the rectangle (centre ``m``, extent ``p``), ``(..., 4, 2)``, counter-clockwise
    from the body-frame corner (+l1, +l2). These are the four points OSPA compares (paper Sec. 7.1)."""
    unit = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    s = shape_factor(p)
    return np.asarray(m, dtype=float)[..., None, :] + np.einsum("...ij,kj->...ki", s, unit)


def rectangle_outline(m: Array, p: Array) -> Array:
    """Closed rectangle polygon for a viewer: the four corners plus the first again, ``(..., 5, 2)``."""
    c = rectangle_corners(m, p)
    return np.concatenate([c, c[..., :1, :]], axis=-2)


def ellipse_outline(m: Array, p: Array, points: int = 64) -> Array:
    """Closed ellipse outline m + S [cos t, sin t], t in [0, 2 pi], ``(..., points, 2)`` (first == last)."""
    t = np.linspace(0.0, 2.0 * np.pi, points)
    unit = np.stack([np.cos(t), np.sin(t)], axis=-1)  # (points, 2)
    s = shape_factor(p)
    return np.asarray(m, dtype=float)[..., None, :] + np.einsum("...ij,kj->...ki", s, unit)


# --------------------------------------------------------------------------------------------------------
# metrics


def acee(estimates: Array, node_axis: int = -2) -> Array:
    """Averaged consensus estimate error (paper Sec. 7.1, the unnumbered display after Fig. 7).

    ACEE_k = 1 / (|G| (|G| - 1)) sum_{s in G} sum_{j in G} || x_hat_{k,s} - x_hat_{k,j} ||

    i.e. the mean Euclidean distance between the estimates of two distinct nodes (the s = j terms are 0).
    ``estimates`` is ``(..., M, n)`` with the nodes on ``node_axis`` and the state (or a slice of it:
    kinematics or extent, which the paper plots separately) last, e.g. ``(R, K, M, n)`` -> ``(R, K)``;
    average over runs afterwards. Needs at least two nodes.
    """
    est = np.moveaxis(np.asarray(estimates, dtype=float), node_axis, -2)
    m = est.shape[-2]
    if m < 2:
        raise ValueError("ACEE needs at least two nodes")
    diff = np.linalg.norm(est[..., :, None, :] - est[..., None, :, :], axis=-1)  # (..., M, M)
    return diff.sum(axis=(-2, -1)) / (m * (m - 1))
