"""Track life cycle: M-of-N confirmation, and deletion after K consecutive misses or a covariance too large.

- :class:`MOfNConfirmer` (Blackman & Popoli 1999, sequential M-of-N track confirmation): a tentative track is
  confirmed once it has ``M`` hits among its first ``N`` steps (the birth step counts, being born of a return
  or a prior), and deleted as soon as it can no longer make it (fewer than ``M`` even if every step left in
  the window were a hit).
- :class:`MissesCovarianceDeleter`: any track is deleted after ``K`` consecutive misses, or when the trace of
  its position covariance exceeds a bound (a coasting track that no longer locates anything).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .base import Confirmer, Deleter, Track, TrackStatus


class MOfNConfirmer(Confirmer):
    """Confirm at ``m`` hits within the first ``n`` steps of a track; give it up once that is out of reach."""

    def __init__(self, m: int = 2, n: int = 3) -> None:
        if not 1 <= m <= n:
            raise ValueError(f"M-of-N confirmation needs 1 <= M <= N, got M={m}, N={n}")
        self.m, self.n = int(m), int(n)

    def decide(self, track: Track) -> TrackStatus:
        if track.status is not TrackStatus.TENTATIVE:
            return track.status
        window = track.hits[: self.n]
        if sum(window) >= self.m:
            return TrackStatus.CONFIRMED
        if sum(window) + self.n - len(window) < self.m:  # even hits at every step left cannot make M
            return TrackStatus.DELETED
        return TrackStatus.TENTATIVE


class MissesCovarianceDeleter(Deleter):
    """Delete after ``max_misses`` consecutive misses, or when ``trace(P[pos, pos]) > max_position_trace``
    (``position_indices``: the position components of the filter state; inf: no covariance bound)."""

    def __init__(self, max_misses: int = 3, max_position_trace: float = math.inf,
                 position_indices: Sequence[int] = (0, 1, 2)) -> None:
        if max_misses < 1:
            raise ValueError(f"max_misses must be >= 1, got {max_misses}")
        if not max_position_trace > 0:
            raise ValueError(f"max_position_trace must be positive, got {max_position_trace}")
        if len(position_indices) == 0:
            raise ValueError("position_indices must name at least one state component")
        self.max_misses = int(max_misses)
        self.max_position_trace = float(max_position_trace)
        self.position_indices = np.asarray(position_indices, dtype=int)

    def position_trace(self, track: Track) -> float:
        """The trace of the track's position covariance."""
        idx = self.position_indices
        return float(track.cov[idx, idx].sum())  # the diagonal entries of the position block

    def should_delete(self, track: Track) -> bool:
        return track.misses >= self.max_misses or self.position_trace(track) > self.max_position_trace
