"""Track life cycle: M-of-N confirmation, and deletion after K consecutive misses or a covariance too large.

- :class:`MOfNConfirmer` (Blackman & Popoli 1999, sequential M-of-N track confirmation): a tentative track is
  confirmed once it has ``M`` hits among its first ``N`` steps (the birth step counts, being born of a return
  or a prior), and deleted as soon as it can no longer make it (fewer than ``M`` even if every step left in
  the window were a hit).
- :class:`MissesCovarianceDeleter`: any track is deleted after ``K`` consecutive misses, or when the trace of
  its position covariance exceeds a bound (a coasting track that no longer locates anything).
- :class:`RayConfirmationDeleter`: bearing sensors: a track that fewer than three cameras (and no point sensor)
  detected over its last ``K`` steps, and fewer than two with returns no other track could explain, is deleted: a
  triangulation **ghost**, where two cameras' rays of two targets meet, is detected by those two cameras only, and
  each of its rays is the track of the target it belongs to.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

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


class RayConfirmationDeleter(Deleter):
    """Bearing sensors: the deleter ``inner`` decides, and besides a track at least ``window`` steps old is deleted
    when over its last ``window`` steps (:attr:`Track.detected_by`, :attr:`Track.detected_alone_by`) it had returns,
    none of a sensor outside ``bearing_sensors``, of fewer than ``min_rays`` sensors, and of fewer than two sensors
    whose return no other track's gate held.

    Why: two rays always meet (within the noise), so a point two cameras see is not yet a target; the triangulation
    initiator starts a track only where a third ray confirms the point
    (:class:`~zentrack.fusion.multitarget.triangulation.TriangulationInitiator`), and this asks a held track to
    keep a third ray, or two rays that nothing else explains. A **ghost** (camera a's ray of one ship crossing
    camera b's ray of another) is detected by a and b at nearly every step while the ships move slowly, so K misses
    never delete it; a third camera's rays of those ships pass elsewhere, and each of its two rays lies in the gate
    of the track of the ship it belongs to. A target that only two cameras still see keeps its track while no other
    track could take those rays. A track with no return in the window is left to ``inner`` (K misses). ``window``
    is the tracker's K: a target seen by three cameras at P_D 0.9 passes unless one of them misses it K steps
    running.

    The centralized tracker's (:func:`~.central.make_central_tracker`), which has every camera's rays. Not a node's:
    a node has three cameras' scans, and a track it deleted so came back from its neighbours' lists the next step
    (on ``ais-nyharbor-cameras`` fragmentations went from 7 to 224 per node and GOSPA from 98.3 to 102.2 m)."""

    def __init__(self, inner: Deleter, bearing_sensors: Iterable[int], window: int, min_rays: int = 3) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1 step, got {window}")
        if min_rays < 1:
            raise ValueError(f"min_rays must be >= 1, got {min_rays}")
        self.inner = inner
        self.bearing_sensors = frozenset(int(s) for s in bearing_sensors)
        self.window, self.min_rays = int(window), int(min_rays)

    def unconfirmed(self, track: Track) -> bool:
        """Whether ``track`` (at least ``window`` steps old) lacks a third ray, and two rays of its own, over its last
        ``window`` steps (class docstring)."""
        if track.step - track.birth_step < self.window:
            return False
        recent = self._within_window(track.detected_by, track.step)
        if not recent or len(recent) >= self.min_rays or not self.bearing_sensors.issuperset(recent):
            return False  # (no return at all: the K misses decide)
        return len(self._within_window(track.detected_alone_by, track.step)) < 2

    def _within_window(self, last_step_of: dict[int, int], step: int) -> list[int]:
        """The sensors whose last step in ``last_step_of`` lies within the ``window`` steps up to ``step``."""
        return [s for s, k in last_step_of.items() if k > step - self.window]

    def should_delete(self, track: Track) -> bool:
        return self.inner.should_delete(track) or self.unconfirmed(track)
