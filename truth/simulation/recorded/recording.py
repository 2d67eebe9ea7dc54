"""Recorded targets as the truth of a many-target run: what a scenario's ``[targets] layout = "recorded"`` asks
for (:class:`RecordingSpec`) and the targets' states at every scan (:func:`recorded_targets`).

The reports of a :mod:`~zentrack.truth.simulation.recorded.sources` source are converted from geodetic
coordinates (WGS 84 latitude, longitude, height) to the scenario's local east-north-up frame at ``origin`` by
``pymap3d.geodetic2enu`` (exact, through ECEF), cleaned and interpolated (or, with ``smoothing``, smoothed) per
target (:mod:`~zentrack.truth.simulation.recorded.clean`). Scan k is at ``t_first + start + k ts``, where ``t_first`` is
the recording's first report; a target is present at scan k while a segment of its reports covers the scan time
and its position lies in ``region``: it appears when it enters the region or starts reporting and leaves when it
goes out or falls silent for more than ``max_gap`` seconds. Targets that never move
(:func:`~zentrack.truth.simulation.recorded.clean.is_still`: at anchor, moored, parked) and those that
reported themselves so throughout are left out, as are targets never present. Of the rest at most
``max_targets`` are kept, those present longest (ties by id); ``select`` keeps only the named ids or labels (one
vessel or aircraft, for the single-target benches).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .sources import Reports, source

Array = np.ndarray


@dataclass(frozen=True)
class RecordingSpec:
    """A recorded truth (module docstring). ``origin`` ``(lat deg, lon deg, height m)``; ``region`` ``(3, 2)``
    ``[lo, hi]`` per ENU axis (m); times in seconds; speeds in m/s."""

    source: str
    origin: tuple[float, float, float]
    region: Array
    start: float = 0.0
    max_speed: float = 50.0
    max_gap: float = 60.0
    min_extent: float = 100.0
    max_targets: int = 200
    select: tuple[str, ...] = ()
    smoothing: float = 0.0  #: s^3, the smoothing spline's penalty (0: interpolate through every report)


@dataclass
class RecordedTargets:
    """The recorded truth over K scans of T targets: ``truth`` ``(K, T, 6)`` ENU position and velocity (NaN where
    absent), ``alive`` ``(K, T)``, ``ids`` and ``labels`` ``(T,)``, ``t0`` the first scan's UTC epoch time (s) and
    ``stats`` the cleaning's counts."""

    truth: Array
    alive: Array
    ids: list[str]
    labels: list[str]
    t0: float
    stats: dict = field(default_factory=dict)


@lru_cache(maxsize=4)
def read_source(name: str) -> Reports:
    """A source's reports, read once per process."""
    return source(name).read()


def to_enu(lat: Array, lon: Array, height: Array, origin: tuple[float, float, float]) -> Array:
    """WGS 84 geodetic coordinates to the east-north-up frame at ``origin``: ``(n, 3)`` metres."""
    import pymap3d  # here: a tracker process reads scenario files but never converts

    e, n, u = pymap3d.geodetic2enu(lat, lon, height, *origin)
    return np.column_stack([e, n, u])


def to_geodetic(enu: Array, origin: tuple[float, float, float]) -> Array:
    """East-north-up positions ``(n, 3)`` at ``origin`` back to WGS 84 ``(n, 3)`` latitude, longitude (deg),
    height (m)."""
    import pymap3d

    enu = np.asarray(enu, dtype=float).reshape(-1, 3)
    lat, lon, h = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], *origin)
    return np.column_stack([lat, lon, h])


def _in_region(points: Array, region: Array) -> Array:
    with np.errstate(invalid="ignore"):
        return np.all((points >= region[:, 0]) & (points <= region[:, 1]), axis=-1)


def recorded_targets(spec: RecordingSpec, steps: int, ts: float) -> RecordedTargets:
    """The recorded truth of ``steps`` scans ``ts`` apart (module docstring)."""
    from .clean import clean_track, is_still, trajectory_at  # SciPy's interpolation: the truth's side only

    reports = read_source(spec.source)
    if len(reports) == 0:
        raise ValueError(f"{spec.source}: the recording holds no report")
    t_first = float(np.nanmin(reports.t))
    times = t_first + spec.start + ts * np.arange(steps)
    window = (reports.t >= times[0] - spec.max_gap) & (reports.t <= times[-1] + spec.max_gap)
    if spec.select:
        wanted = set(spec.select)
        window &= np.array([i in wanted or reports.labels.get(i, "") in wanted for i in reports.ids.tolist()])
    ids_all, inverse = np.unique(reports.ids[window], return_inverse=True)
    enu_all = to_enu(reports.lat[window], reports.lon[window], reports.height[window], spec.origin)
    t_all, still_all = reports.t[window], reports.still[window]
    region = np.asarray(spec.region, dtype=float)
    stats = {"reports": int(window.sum()), "duplicates": 0, "outliers": 0, "lone_reports": 0, "still_targets": 0,
             "never_present": 0, "targets_read": int(ids_all.size)}
    kept: list[tuple[str, Array, Array]] = []
    for j, target in enumerate(ids_all.tolist()):
        rows = inverse == j
        track = clean_track(t_all[rows], enu_all[rows], spec.max_speed, spec.max_gap)
        stats["duplicates"] += track.duplicates
        stats["outliers"] += track.outliers
        stats["lone_reports"] += track.lone_reports
        points = np.vstack([x for _, x in track.segments]) if track.segments else np.zeros((0, 3))
        if bool(np.all(still_all[rows])) or is_still(points, spec.min_extent):
            stats["still_targets"] += 1
            continue
        states = np.full((steps, 6), np.nan)
        for seg_t, seg_x in track.segments:
            inside = (times >= seg_t[0]) & (times <= seg_t[-1])
            if inside.any():
                pos, vel = trajectory_at(seg_t, seg_x, times[inside], spec.smoothing)
                states[inside] = np.hstack([pos, vel])
        present = _in_region(states[:, :3], region) & np.all(np.isfinite(states), axis=1)
        if not present.any():
            stats["never_present"] += 1
            continue
        states[~present] = np.nan
        kept.append((target, states, present))
    kept.sort(key=lambda item: (-int(item[2].sum()), item[0]))
    kept = kept[: spec.max_targets]
    kept.sort(key=lambda item: (int(np.argmax(item[2])), item[0]))  # target id = order of first appearance
    stats["targets"] = len(kept)
    if kept:
        truth = np.stack([s for _, s, _ in kept], axis=1)
        alive = np.stack([p for _, _, p in kept], axis=1)
    else:
        truth, alive = np.full((steps, 0, 6), np.nan), np.zeros((steps, 0), dtype=bool)
    ids = [i for i, _, _ in kept]
    return RecordedTargets(truth=truth, alive=alive, ids=ids, labels=[reports.labels.get(i, i) for i in ids],
                           t0=float(times[0]), stats=stats)
