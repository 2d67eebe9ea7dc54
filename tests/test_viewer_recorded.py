"""The many-target viewer on a recorded truth (``zentrack.viewer.map_view``): the targets named as the recording
names them, and the region on Rerun's map view (``map/``: the targets, their paths, the sensors and each node's
confirmed tracks in latitude and longitude, as ``to_geodetic`` converts the run's east-north-up positions); a
simulated truth draws no map. The recorded run is mt-crossing's truth given names and a geodetic origin by hand,
so no data package is needed; its recording is read back with Rerun's reader. Each target's name is drawn beside
it on the map as the outlines of its glyphs (``zentrack.viewer.map_text``)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import rerun.blueprint as rrb
from test_viewer import column, read_rrd
from test_viewer_multitarget import fed_viewer, node0_tracks

from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.truth.simulation.recorded.recording import RecordedTargets, to_geodetic
from zentrack.viewer.map_text import NAME_POINTS, glyph_outlines
from zentrack.viewer.map_view import (
    EQUATOR_M,
    MAP_KEY,
    MAP_NAME_RGB,
    NAME_REDRAW,
    MapLayer,
    map_zoom,
    metres_per_point,
    region_name_height,
    region_zoom,
)
from zentrack.viewer.multi_target import track_label
from zentrack.viewer.multi_target_layout import multitarget_blueprint, multitarget_key

STEPS = 6
#: New York's Upper Bay, as ais-nyharbor's frame
ORIGIN = (40.66, -74.05, 0.0)


@pytest.fixture(scope="module")
def simulated():
    return resize(load_scenario_config("mt-crossing", multitarget=True), None, STEPS).multitarget_data(seed=0)


@pytest.fixture(scope="module")
def recorded_data(simulated):
    """The same run with a recorded truth's names (``VESSEL <id>``) and geodetic origin."""
    count = simulated.truth.shape[1]
    names = RecordedTargets(simulated.truth, simulated.alive, [f"36700{i}" for i in range(count)],
                            [f"VESSEL {i}" for i in range(count)], t0=1.6e9)
    return dataclasses.replace(simulated, recorded=names, geodetic_origin=ORIGIN)


def record(data, path):
    """The viewer fed every step's truth and node 0's lists, node 1's only at step 2 and an empty one at step 3."""
    viewer, rec = fed_viewer(data, path, "recorded-test")
    viewer.canvas.buf.flush()
    viewer.close()
    rec.flush()
    rec.disconnect()
    return read_rrd(path)


@pytest.fixture(scope="module")
def recorded(recorded_data, tmp_path_factory):
    return record(recorded_data, tmp_path_factory.mktemp("recorded") / "rec.rrd")


def lat_lon_of(enu) -> np.ndarray:
    return to_geodetic(np.reshape(enu, (-1, 3)), ORIGIN)[:, :2]


def halves(values) -> tuple:
    """A rimmed point set: (the rims, the markers), the same points twice."""
    values = np.asarray(values)
    return values[: len(values) // 2], values[len(values) // 2:]


def test_the_targets_are_named_and_mapped_to_their_latitude_and_longitude(recorded, recorded_data):
    targets = recorded["/map/truth/targets"]
    steps = column(targets, "step")
    assert sorted(steps) == list(range(STEPS))
    for k in range(STEPS):
        ids, states = recorded_data.truth_at(k)
        expected = lat_lon_of(states[:, :3])
        assert abs(expected[:, 0] - ORIGIN[0]).max() < 0.1 and abs(expected[:, 1] - ORIGIN[1]).max() < 0.1
        rims, markers = halves(column(targets, "GeoPoints:positions")[steps.index(k)])
        np.testing.assert_allclose(markers, expected, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rims, expected, rtol=0, atol=1e-9)
        names = [f"VESSEL {i}" for i in ids]
        assert list(column(targets, "GeoPoints:labels")[steps.index(k)]) == names * 2
        assert list(column(recorded["/world/truth/targets"], "Points3D:labels")[k]) == names, "the 3-D view too"
    rim_r, marker_r = halves(column(targets, "GeoPoints:radii")[0])
    assert np.all(rim_r < marker_r) and np.all(marker_r < 0), "in UI points, the rim larger"


def test_the_paths_are_segments_in_latitude_and_longitude(recorded, recorded_data):
    paths = recorded["/map/truth/paths"]
    steps, strips = column(paths, "step"), column(paths, "GeoLineStrings:line_strings")
    assert sorted(steps) == list(range(1, STEPS)), "a segment per target and step after the first"
    k = STEPS - 1
    before, now = recorded_data.truth_at(k - 1)[1][:, :3], recorded_data.truth_at(k)[1][:, :3]
    row = np.asarray(strips[steps.index(k)])
    assert row.shape == (len(now), 2, 2)
    np.testing.assert_allclose(row[:, 0], lat_lon_of(before), rtol=0, atol=1e-9)
    np.testing.assert_allclose(row[:, 1], lat_lon_of(now), rtol=0, atol=1e-9)


def test_the_sensors_are_static_named_points(recorded, recorded_data):
    sensors = recorded["/map/sensors"]
    assert not column(sensors, "step"), "static"
    rims, markers = halves(column(sensors, "GeoPoints:positions")[0])
    np.testing.assert_allclose(markers, lat_lon_of(recorded_data.sensors), rtol=0, atol=1e-9)
    np.testing.assert_allclose(rims, markers)
    assert list(column(sensors, "GeoPoints:labels")[0]) == [f"s{i}" for i in range(recorded_data.nodes)] * 2


def test_each_nodes_confirmed_tracks_are_on_the_map_in_its_colour(recorded, recorded_data):
    confirmed = recorded["/map/nodes/0/confirmed"]
    steps = column(confirmed, "step")
    assert sorted(steps) == list(range(STEPS))
    for k in range(STEPS):
        held = [e for e in node0_tracks(recorded_data, k) if e.status == "confirmed"]
        np.testing.assert_allclose(column(confirmed, "GeoPoints:positions")[steps.index(k)],
                                   lat_lon_of([e.mean[:3] for e in held]), rtol=0, atol=1e-9)
        assert list(column(confirmed, "GeoPoints:labels")[steps.index(k)]) == [track_label(e.id) for e in held]
    colours = np.asarray(column(confirmed, "GeoPoints:colors")[0])
    assert len(set(colours.tolist())) == 1
    assert colours[0] == np.asarray(column(recorded["/world/nodes/0/confirmed"], "Points3D:colors")[0])[0]
    assert "/map/nodes/0/tentative" not in recorded, "tentative tracks stay off the map"
    steps1, points1 = column(recorded["/map/nodes/1/confirmed"], "step"), column(recorded["/map/nodes/1/confirmed"],
                                                                                  "GeoPoints:positions")
    assert sorted(steps1) == [2, 3] and len(points1[steps1.index(2)]) == 1
    assert not points1[steps1.index(3)], "an empty list clears the node's tracks"


def name_box(strips, name: str, state, height: float) -> tuple[float, float, float, float]:
    """Where a name's strokes lie from its target: (east min, east max, north min, north max) in metres."""
    lat_m = 111_000.0  # metres per degree of latitude (and of longitude times cos(lat)), to 1 %
    lon_m = lat_m * np.cos(np.radians(ORIGIN[0]))
    assert len(strips) == len(glyph_outlines(name)) >= len(name.replace(" ", "")), "an outline per glyph at least"
    lat, lon = np.concatenate([np.asarray(s) for s in strips]).T
    t_lat, t_lon = lat_lon_of(state[:3])[0]
    east, north = (lon - t_lon) * lon_m, (lat - t_lat) * lat_m
    return east.min(), east.max(), north.min(), north.max()


def test_each_name_is_drawn_as_glyph_outlines_beside_its_target_on_the_map(recorded, recorded_data):
    """Rerun's map view draws no text: a named target's name is line strings just east of it, a capital
    NAME_POINTS UI points tall at the zoom the map opens at, redrawn as the target moves."""
    height = region_name_height(recorded_data)
    assert height == pytest.approx(NAME_POINTS * metres_per_point(ORIGIN[0], region_zoom(recorded_data)))
    redrawn = 0
    for k in range(STEPS):
        ids, states = recorded_data.truth_at(k)
        for target, state in zip(ids, states):
            rows = recorded[f"/map/truth/names/{target}"]
            steps = column(rows, "step")
            last = max(s for s in steps if s <= k)  # what the map shows at step k
            redrawn += k > 0 and last == k
            slack = NAME_REDRAW * height if k > 0 else 0.0  # at most this far behind its target
            strips = column(rows, "GeoLineStrings:line_strings")[steps.index(last)]
            east_lo, east_hi, north_lo, north_hi = name_box(strips, f"VESSEL {target}", state, height)
            assert 0.4 * height - slack < east_lo < 1.0 * height + slack, "starting just east of the target"
            assert east_hi < 0.8 * height * len(f"VESSEL {target}") + height + slack, "a capital's width a letter"
            assert -0.55 * height - slack < north_lo and north_hi < 0.55 * height + slack, "at the target's latitude"
            assert north_hi - north_lo > 0.95 * height, "a capital tall"
    assert redrawn > 0, "names follow their moving targets"
    colours = np.asarray(column(recorded["/map/truth/names/0"], "GeoLineStrings:colors")[0])
    assert np.all(colours == int.from_bytes(bytes([*MAP_NAME_RGB, 255]), "big")), "packed RGBA, dark grey"


def test_a_name_is_redrawn_only_once_its_target_moved_and_cleared_when_it_leaves():
    class Rows:
        def __init__(self) -> None:
            self.rows: list = []

        def add(self, entity, kind, k, strips, colors, radii) -> None:
            self.rows.append((entity, k, len(strips)))

    buf = Rows()
    layer = MapLayer(buf, ORIGIN, [[255, 0, 0]], name_height=100.0)
    here = np.array([[0.0, 0.0, 0.0], [500.0, 0.0, 0.0]])
    layer.names(0, [3, 4], here, ["PILOT", None])
    layer.names(1, [3, 4], here + [0.2 * NAME_REDRAW * 100.0, 0, 0], ["PILOT", None])  # hardly moved
    layer.names(2, [3, 4], here + [1.5 * NAME_REDRAW * 100.0, 0, 0], ["PILOT", None])
    layer.names(3, [4], here[1:], [None])  # PILOT gone
    outlines = len(glyph_outlines("PILOT"))
    assert buf.rows == [("map/truth/names/3", 0, outlines), ("map/truth/names/3", 2, outlines),
                        ("map/truth/names/3", 3, 0)], "no name for a target without one"


def test_a_simulated_truth_draws_no_map(simulated, tmp_path):
    rec = record(simulated, tmp_path / "sim.rrd")
    assert "/world/truth/targets" in rec
    assert not [path for path in rec if path.startswith("/map")]
    ids = simulated.truth_at(0)[0]
    assert list(column(rec["/world/truth/targets"], "Points3D:labels")[0]) == [f"t{i}" for i in ids]
    assert region_zoom(simulated) is None


def views(layout: rrb.Blueprint) -> list:
    return list(layout.root_container.contents)


def test_a_recorded_layout_has_a_map_view_beside_the_scene(recorded_data, simulated):
    zoom = region_zoom(recorded_data)
    assert zoom is not None and 10.0 < zoom < 18.0
    scene, geo, _ = views(multitarget_blueprint(recorded_data.nodes, ((0.0, 0.0, 0.0), 1000.0), 4, zoom))
    assert isinstance(geo, rrb.MapView) and str(geo.origin) == "map"
    assert isinstance(scene, rrb.Spatial3DView) and "- map/**" in str(scene.contents)
    plain = views(multitarget_blueprint(simulated.nodes, ((0.0, 0.0, 0.0), 1000.0), 4))
    assert not [v for v in plain if isinstance(v, rrb.MapView)] and len(plain) == 2
    assert MAP_KEY in multitarget_key(True, 50.0) and MAP_KEY not in multitarget_key(False, 50.0)


def test_the_zoom_fits_the_region_in_the_map_view():
    assert map_zoom(EQUATOR_M / 2, 0.0, points=256.0) == 0.0, "zoom 0: one 256-point tile spans the equator"
    assert map_zoom(1000.0, 60.0) == pytest.approx(map_zoom(2000.0, 0.0), abs=0.05), "cos(60°) halves the metres"
    assert map_zoom(500.0, 40.0) == pytest.approx(map_zoom(1000.0, 40.0) + 1.0, abs=0.05)
