"""The region of a recorded many-target run on Rerun's map view: its truth, sensors and confirmed tracks as
geographic points and lines (WGS 84 latitude and longitude), beside the 3-D view.

Only a run whose truth is recorded has a map (``MultiTargetData.geodetic_origin`` set): the local east-north-up
positions are converted with :func:`~zentrack.truth.simulation.recorded.recording.to_geodetic`, once per entity and
step, on the step's whole batch. Entities (sizes in UI points):

- ``map/truth/targets``: the targets present at each step (white with a dark rim), ``map/truth/paths`` one segment
  per target and step (the map view keeps the whole path: :func:`map_view`);
- ``map/sensors`` (static, in their node's colour with a dark rim);
- ``map/nodes/<i>/confirmed``: node i's confirmed tracks, small dots in its colour;
- ``map/truth/names/<target>``: a named target's vessel name or call sign beside it, drawn as the outlines of its
  glyphs (:mod:`~zentrack.viewer.map_text`): drawn when the target appears, redrawn once it has moved
  :data:`NAME_REDRAW` of a capital's height from where its name was last drawn (a name is ~150 points: drawn at
  every step, the names would be most of a recording), cleared when it leaves.

A rimmed marker is its point twice in one set, first larger in the rim's colour (a map view draws a set's points in
order, but entities in no fixed order: the tracks' dots are smaller than a target's white, so on top they show
inside it and beneath it wherever they are off their target). Rerun 0.41's map view draws no text (``GeoPoints`` has
no labels: rerun-io/rerun#9452), so the targets' names are drawn as line strings (``map/truth/names``), and each point
set carries its names in a text component :data:`LABELS` (vessel names or call signs, ``s<i>``,
``born/node/serial``), shown where Rerun shows a point's data (the selection panel); the 3-D view labels the same
targets.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.truth.simulation.multitarget import MultiTargetData
from zentrack.truth.simulation.recorded.recording import to_geodetic
from zentrack.viewer.map_text import name_height, name_strokes

#: the names of a point set's points, as the field of ``GeoPoints`` a later Rerun may draw (0.41 shows them with a
#: point's data)
LABELS = rr.ComponentDescriptor("GeoPoints:labels", archetype="rerun.archetypes.GeoPoints",
                                component_type="rerun.components.Text")
#: the truth on the map: white as in the 3-D view, its paths mid grey, a dark rim around the targets and the sensors
#: (visible on a light or dark background, with or without map tiles)
MAP_TARGET_RGB, MAP_PATH_RGB, MAP_RIM_RGB = [255, 255, 255], [110, 110, 110], [30, 30, 30]
#: sizes in UI points: truth, confirmed track and sensor markers (a rim adds MAP_RIM_R), path width
MAP_TARGET_R, MAP_CONFIRMED_R, MAP_SENSOR_R, MAP_PATH_R = -3.5, -2.5, -5.0, -0.8
MAP_RIM_R = -1.5
#: the names on the map: dark grey outlines (readable on the map's tiles and on its blank background), line width
MAP_NAME_RGB, MAP_NAME_R = [20, 20, 20], -0.6
#: a name is redrawn once its target has moved this many capital heights from where it was drawn
NAME_REDRAW = 0.25
MAP_TITLE = "map: truth (white, rimmed) and paths · confirmed tracks per node (dots) · sensors (rimmed, node colour)"
MAP_KEY = (
    "\n\n**Map**: the same scene in latitude and longitude (WGS 84): the targets (white) with their paths, the "
    "sensors (rimmed) and each node's confirmed tracks (dots) in its colour, each ship or aircraft's name or call sign "
    "beside it (drawn as lines: the map view draws no text; a point's name is also in its data, in the selection "
    "panel). Its OpenStreetMap "
    "background needs internet; without it the points and lines are drawn on a blank background.")
#: the map view's width and height (UI points, less a margin) on a 1600 x 1000 screen: its zoom fits the region in it
MAP_VIEW_POINTS = (520.0, 780.0)
#: the equator's length (m, WGS 84): a 256-point tile spans it at OpenStreetMap's zoom 0
EQUATOR_M = 40_075_016.686


def lat_lon(enu: np.ndarray, origin: tuple[float, float, float]) -> np.ndarray:
    """East-north-up positions ``(..., 3)`` (m) at ``origin`` as ``(n, 2)`` latitude, longitude (deg)."""
    enu = np.asarray(enu, dtype=float).reshape(-1, 3)
    if not len(enu):
        return np.zeros((0, 2))
    return to_geodetic(enu, origin)[:, :2]


def rimmed(positions: np.ndarray, colors: np.ndarray, radii: np.ndarray, names: list[str]) -> tuple:
    """Markers with a dark rim: each point twice, first larger in :data:`MAP_RIM_RGB`, then in its colour on top
    (a map view draws a point set's points in order); the names twice too (either point carries its name)."""
    n = len(positions)
    return (np.concatenate([positions, positions]), np.concatenate([np.tile(MAP_RIM_RGB, (n, 1)), colors]),
            np.concatenate([np.asarray(radii) + MAP_RIM_R, radii]), [*names, *names])


def named_points(points: np.ndarray, colors: np.ndarray, radii: np.ndarray, names: list[str]) -> list:
    """``GeoPoints`` (lat/lon ``(n, 2)``, colours ``(n, 3)``, radii ``(n,)``) with their names, as one row."""
    geo = rr.GeoPoints(lat_lon=np.reshape(points, (-1, 2)), colors=np.reshape(colors, (-1, 3)).astype(np.uint8),
                       radii=np.reshape(radii, -1))
    return [*geo.as_component_batches(), rr.components.TextBatch(names).described(LABELS)]


def geo_points(rows: list) -> list[rr.ComponentColumn]:
    """Rows of (lat/lon (n, 2), colours (n, 3), radii (n,), names (n,)), any n per row (0 included)."""
    lengths = [len(r[0]) for r in rows]
    points = rr.GeoPoints.columns(
        positions=np.concatenate([np.reshape(r[0], (-1, 2)) for r in rows]),
        colors=np.concatenate([np.reshape(r[1], (-1, 3)) for r in rows]).astype(np.uint8),
        radii=np.concatenate([np.reshape(r[2], -1) for r in rows])).partition(lengths)
    names = rr.ComponentColumn(LABELS, rr.components.TextBatch([name for r in rows for name in r[3]]))
    return [*points, names.partition(lengths)]


def geo_strips(rows: list) -> rr.ComponentColumnList:
    """Rows of (n line strings, each ``(m, 2)`` lat/lon (segments: an ``(n, 2, 2)`` array), colours (n, 3), radii
    (n,)), any n per row (0 included)."""
    return rr.GeoLineStrings.columns(
        line_strings=[np.reshape(s, (-1, 2)) for r in rows for s in r[0]],
        colors=np.concatenate([np.reshape(r[1], (-1, 3)) for r in rows]).astype(np.uint8),
        radii=np.concatenate([np.reshape(r[2], -1) for r in rows])).partition([len(r[0]) for r in rows])


#: the column buffer's kinds for the map's rows
GEO_KINDS: dict[str, Any] = {"geoset": geo_points, "geosegset": geo_strips}


def metres_per_point(lat_deg: float, zoom: float = 0.0) -> float:
    """The metres one UI point spans at latitude ``lat_deg`` and OpenStreetMap zoom ``zoom`` (Web Mercator:
    ``EQUATOR_M cos(lat) / 256 / 2^zoom``)."""
    return float(EQUATOR_M * np.cos(np.radians(lat_deg)) / 256.0 / 2.0**zoom)


def map_zoom(half_m: float, lat_deg: float, points: float = MAP_VIEW_POINTS[0]) -> float:
    """The OpenStreetMap zoom level (to a tenth) at which ``2 half_m`` metres at latitude ``lat_deg`` fill
    ``points`` UI points (:func:`metres_per_point`)."""
    return round(float(np.log2(metres_per_point(lat_deg) * points / (2.0 * max(half_m, 1.0)))), 1)


def region_zoom(data: MultiTargetData) -> float | None:
    """The zoom (:func:`map_zoom`) fitting a recorded run's targets over the run and its sensors in the map view
    (east-west across its width, north-south along its height: Web Mercator keeps both scales equal); None: no map."""
    if data.geodetic_origin is None:
        return None
    seen = np.concatenate([data.truth[..., :3].reshape(-1, 3), data.sensors[:, :3]])
    seen = seen[np.all(np.isfinite(seen), axis=1)]
    half_east, half_north = (seen[:, :2].max(axis=0) - seen[:, :2].min(axis=0)) / 2
    lat = data.geodetic_origin[0]
    return min(map_zoom(float(half_east), lat, MAP_VIEW_POINTS[0]), map_zoom(float(half_north), lat, MAP_VIEW_POINTS[1]))


def region_name_height(data: MultiTargetData) -> float | None:
    """The height (m) of a name on the map of a recorded run, readable at the zoom its map view opens at
    (:func:`region_zoom`); None: no map."""
    zoom = region_zoom(data)
    if zoom is None or data.geodetic_origin is None:
        return None
    return name_height(metres_per_point(data.geodetic_origin[0], zoom))


def map_view(zoom: float, whole_run: rrb.VisibleTimeRanges) -> rrb.MapView:
    """The map view of ``map/`` at ``zoom`` on OpenStreetMap's background, the truth's paths over ``whole_run``."""
    return rrb.MapView(origin="map", name=MAP_TITLE, zoom=zoom, background=rrb.MapProvider.OpenStreetMap,
                       overrides={"map/truth/paths": [whole_run]})


class MapLayer:
    """Adds a run's map rows (module docstring) to the column buffer ``buf`` (kinds :data:`GEO_KINDS`) next to its
    3-D rows; ``origin`` the geodetic origin (lat deg, lon deg, height m) of the run's east-north-up frame,
    ``colors`` the nodes', ``name_height`` a name's capital height (m)."""

    def __init__(self, buf, origin: tuple[float, float, float], colors: list[list[int]], name_height: float) -> None:
        self.buf, self.origin, self.colors, self.name_height = buf, origin, colors, name_height
        #: target -> where (ENU) its name was last drawn
        self.named_at: dict[int, np.ndarray] = {}

    def log_sensors(self, rec: rr.RecordingStream, sensors: np.ndarray) -> None:
        """The sensors (static), in their node's colour, rimmed, named ``s<i>``."""
        m = len(sensors)
        rimmed_sensors = rimmed(lat_lon(sensors, self.origin), np.reshape(self.colors, (-1, 3)), np.full(m, MAP_SENSOR_R),
                                [f"s{i}" for i in range(m)])
        rec.log("map/sensors", named_points(*rimmed_sensors), static=True)

    def targets(self, k: int, positions: np.ndarray, names: list[str]) -> None:
        """The targets present at step k (ENU ``(n, 3)``), named: white, rimmed."""
        n = len(names)
        self.buf.add("map/truth/targets", "geoset", k, *rimmed(lat_lon(positions, self.origin),
                                                               np.tile(MAP_TARGET_RGB, (n, 1)), np.full(n, MAP_TARGET_R),
                                                               names))

    def names(self, k: int, ids: list[int], positions: np.ndarray, names: list[str | None]) -> None:
        """The names of the targets ``ids`` present at step k (ENU ``(n, 3)``; None: a target without a name) as
        the outlines of their glyphs beside them (module docstring: drawn, redrawn as they move, cleared)."""
        positions = np.reshape(positions, (-1, 3))
        present = set()
        for target, p, name in zip(ids, positions, names):
            if not name:
                continue
            present.add(target)
            last = self.named_at.get(target)
            if last is not None and np.linalg.norm(p - last) < NAME_REDRAW * self.name_height:
                continue
            self.named_at[target] = p
            strokes = name_strokes(p[None], [name], self.name_height)
            points = lat_lon(np.concatenate(strokes), self.origin)
            geo = np.split(points, np.cumsum([len(s) for s in strokes])[:-1])
            self._name_row(target, k, geo)
        for target in set(self.named_at) - present:  # gone: its name goes too
            del self.named_at[target]
            self._name_row(target, k, [])

    def _name_row(self, target: int, k: int, geo: list) -> None:
        n = len(geo)
        self.buf.add(f"map/truth/names/{target}", "geosegset", k, geo, np.tile(MAP_NAME_RGB, (n, 1)),
                     np.full(n, MAP_NAME_R))

    def paths(self, k: int, segments: list) -> None:
        """The truth's segments of step k (``[[a, b], ...]`` ENU)."""
        if segments:
            ends = lat_lon(np.asarray(segments), self.origin).reshape(-1, 2, 2)
            self.buf.add("map/truth/paths", "geosegset", k, ends, np.tile(MAP_PATH_RGB, (len(ends), 1)),
                         np.full(len(ends), MAP_PATH_R))

    def confirmed(self, node: int, k: int, positions: np.ndarray, names: list[str]) -> None:
        """Node ``node``'s confirmed tracks at step k (ENU ``(n, 3)``), named by their identity."""
        n = len(names)
        self.buf.add(f"map/nodes/{node}/confirmed", "geoset", k, lat_lon(positions, self.origin),
                     np.tile(self.colors[node], (n, 1)), np.full(n, MAP_CONFIRMED_R), names)
