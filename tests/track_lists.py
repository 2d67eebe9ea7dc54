"""Track lists for the track-to-track tests: constant-velocity covariances, three far-apart targets, random SPD
matrices and a one-line track."""
from __future__ import annotations

import numpy as np

from zentrack.fusion.track_to_track import TrackEstimate, TrackId

#: a constant-velocity state's covariance: positions (m^2), velocities (m^2/s^2)
P4 = np.diag([4.0, 4.0, 0.5, 0.5])
#: three targets, far apart (hundreds of standard deviations)
TARGETS = np.array([[0.0, 0.0, 1.0, 0.0], [400.0, 0.0, 0.0, 1.0], [0.0, 400.0, -1.0, 1.0]])


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T / n + 0.2 * np.eye(n))


def track(born: int, node: int, serial: int, mean, cov=P4, step: int = 10, status: str = "confirmed") -> TrackEstimate:
    return TrackEstimate(TrackId(born, node, serial), np.asarray(mean, dtype=float), cov, status, step)
