"""Geometry for display: covariance ellipsoids and bearing rays (numpy only)."""
from __future__ import annotations

import numpy as np

#: ellipsoids are drawn at this many standard deviations
SIGMAS = 3.0


def rotation_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Rotation matrix (proper, det = +1) to a unit quaternion in Rerun's ``xyzw`` order."""
    m = r
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    quat = np.array(q)
    return quat / np.linalg.norm(quat)


def covariance_ellipsoid(cov: np.ndarray, sigmas: float = SIGMAS) -> tuple[np.ndarray, np.ndarray]:
    """Half-sizes ``sigmas * sqrt(eig)`` and the xyzw quaternion of the principal axes of a 3x3 covariance."""
    eig, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    if np.linalg.det(vec) < 0:
        vec[:, 0] = -vec[:, 0]
    return sigmas * np.sqrt(np.clip(eig, 0.0, None)), rotation_to_quaternion(vec)


def bearing_direction(az: float, el: float) -> np.ndarray:
    """Unit line-of-sight vector of azimuth ``az`` and elevation ``el`` (paper 0 eq. 5 inverted)."""
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
