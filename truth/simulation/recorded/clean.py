"""Cleaning recorded position reports and interpolating them to scan times.

Per target, in the local east-north-up frame (metres, seconds), :func:`clean_track` keeps what a truth can stand
on:

1. reports with a finite time and position, sorted by time; of several at the same time, the first
   (**duplicates**: AIS stations and ADS-B receivers repeat reports);
2. no **outlier**: a report that would need more than ``max_speed`` from the last report kept is dropped (a
   jump of the GPS or a garbled message), the others are judged against the last one kept;
3. **segments** split where two reports are more than ``max_gap`` seconds apart: between them nobody knows where
   the target was, so the truth leaves it absent there rather than inventing a straight line; a segment of one
   report is dropped.

:func:`is_still` tells a target that never moves (a vessel **at anchor** or moored, an aircraft parked): one
whose positions all lie within ``min_extent`` metres of their median. :func:`interpolate_segment` gives position and
velocity at the scan times inside a segment by SciPy's shape-preserving piecewise cubic (PCHIP, Fritsch & Carlson
1980) on each coordinate: it passes through every report without the overshoot of a spline between sparse reports,
and its derivative is the velocity.

A recording whose positions are noisy at its own rate (ADS-B states every second scatter by tens of metres, and
barometric altitude comes in 25 ft steps) gives such an interpolation accelerations no aircraft flies. There
:func:`smooth_segment` fits SciPy's cubic smoothing spline (``make_smoothing_spline``: the ``f`` minimising
``sum (x_i - f(t_i))^2 + lam * integral f''(t)^2 dt``, Reinsch 1967) to each coordinate with the scenario's
``smoothing`` = ``lam`` (s^3); :func:`trajectory_at` picks one or the other. The truth of a real path is then itself
an estimate: the docs give its residuals beside every figure.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator, make_smoothing_spline

Array = np.ndarray


@dataclass(frozen=True)
class CleanTrack:
    """One target's cleaned reports: ``segments`` is a list of ``(t (n,), enu (n, 3))``, each with n >= 2 reports
    at strictly increasing times; the counts say what was dropped."""

    segments: list[tuple[Array, Array]]
    duplicates: int
    outliers: int
    lone_reports: int

    @property
    def reports(self) -> int:
        return sum(t.size for t, _ in self.segments)


def clean_track(t: Array, enu: Array, max_speed: float, max_gap: float) -> CleanTrack:
    """The cleaning of one target's reports (module docstring): ``t`` ``(n,)`` s, ``enu`` ``(n, 3)`` m."""
    t = np.asarray(t, dtype=float)
    enu = np.asarray(enu, dtype=float)
    finite = np.isfinite(t) & np.all(np.isfinite(enu), axis=1)
    order = np.argsort(t[finite], kind="stable")
    t, enu = t[finite][order], enu[finite][order]
    first = np.ones(t.size, dtype=bool)
    first[1:] = np.diff(t) > 0
    duplicates = int(t.size - first.sum())
    t, enu = t[first], enu[first]
    keep = np.zeros(t.size, dtype=bool)
    last = -1
    for i in range(t.size):  # each report against the last one kept
        if last < 0 or np.linalg.norm(enu[i] - enu[last]) <= max_speed * (t[i] - t[last]):
            keep[i] = True
            last = i
    outliers = int(t.size - keep.sum())
    t, enu = t[keep], enu[keep]
    cuts = np.flatnonzero(np.diff(t) > max_gap) + 1
    segments, lone = [], 0
    for ts, xs in zip(np.split(t, cuts), np.split(enu, cuts), strict=True):
        if ts.size >= 2:
            segments.append((ts, xs))
        else:
            lone += int(ts.size)
    return CleanTrack(segments, duplicates, outliers, lone)


def is_still(enu: Array, min_extent: float) -> bool:
    """Whether every position lies within ``min_extent`` metres of the positions' median (at anchor, moored or
    parked: the target never went anywhere)."""
    enu = np.asarray(enu, dtype=float)
    if enu.size == 0:
        return True
    centre = np.median(enu, axis=0)
    return bool(np.max(np.linalg.norm(enu - centre, axis=1)) < min_extent)


def interpolate_segment(t: Array, enu: Array, times: Array) -> tuple[Array, Array]:
    """Positions and velocities ``(len(times), 3)`` at ``times`` (which must lie within ``[t[0], t[-1]]``) by
    PCHIP through the segment's reports (module docstring)."""
    times = np.asarray(times, dtype=float)
    if times.size and (times[0] < t[0] or times[-1] > t[-1]):
        raise ValueError("interpolation times must lie within the segment")
    curve = PchipInterpolator(t, enu, axis=0, extrapolate=False)
    return curve(times), curve.derivative()(times)


#: a smoothing spline needs this many reports; a shorter segment is interpolated
SMOOTHING_MIN_REPORTS = 5


def smooth_segment(t: Array, enu: Array, times: Array, lam: float) -> tuple[Array, Array]:
    """Positions and velocities at ``times`` (within the segment) of the cubic smoothing spline of penalty
    ``lam`` (s^3) through the segment's reports, each coordinate on its own (module docstring)."""
    times = np.asarray(times, dtype=float)
    if times.size and (times[0] < t[0] or times[-1] > t[-1]):
        raise ValueError("smoothing times must lie within the segment")
    rel = t - t[0]
    pos, vel = np.empty((times.size, 3)), np.empty((times.size, 3))
    for c in range(3):
        spline = make_smoothing_spline(rel, enu[:, c], lam=lam)
        pos[:, c] = spline(times - t[0])
        vel[:, c] = spline.derivative()(times - t[0])
    return pos, vel


def trajectory_at(t: Array, enu: Array, times: Array, smoothing: float) -> tuple[Array, Array]:
    """The segment's positions and velocities at ``times``: smoothed when ``smoothing`` > 0 and the segment has
    at least :data:`SMOOTHING_MIN_REPORTS` reports, else interpolated through every report."""
    if smoothing > 0 and t.size >= SMOOTHING_MIN_REPORTS:
        return smooth_segment(t, enu, times, smoothing)
    return interpolate_segment(t, enu, times)
