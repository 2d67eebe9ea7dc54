"""Recorded trajectories as truth (issue 34): the geodetic conversion against the WGS 84 formulas, the cleaning
(duplicates, outliers, gaps, vessels at anchor) and interpolation, the readers of AIS CSV and ADS-B JSON, a missing
data package, the presence of targets in the region, and the catalogue's real scenarios on the installed data."""
from __future__ import annotations

import csv
import gzip
import importlib.util
import json
import math

import numpy as np
import pytest

from zentrack.cli import main
from zentrack.config.scenario_config import load_scenario_config, resolve
from zentrack.truth.simulation.recorded import recording, sources
from zentrack.truth.simulation.recorded.clean import clean_track, interpolate_segment, is_still, trajectory_at
from zentrack.truth.simulation.recorded.recording import RecordingSpec, recorded_targets, to_enu, to_geodetic
from zentrack.truth.simulation.recorded.sources import RecordingUnavailable, Reports, read_adsb_json, read_ais_csv

WGS84_A, WGS84_F = 6378137.0, 1 / 298.257223563
NY = (40.66, -74.05, 0.0)


def prime_vertical_radius(lat_deg: float) -> float:
    e2 = WGS84_F * (2 - WGS84_F)
    return WGS84_A / math.sqrt(1 - e2 * math.sin(math.radians(lat_deg)) ** 2)


def meridian_radius(lat_deg: float) -> float:
    e2 = WGS84_F * (2 - WGS84_F)
    return WGS84_A * (1 - e2) / (1 - e2 * math.sin(math.radians(lat_deg)) ** 2) ** 1.5


def test_enu_matches_the_wgs84_radii_of_curvature_for_small_offsets():
    d = 1e-4  # degrees: ~11 m, where the flat-earth formulas hold to well under a millimetre
    enu = to_enu(np.array([NY[0], NY[0] + d]), np.array([NY[1] + d, NY[1]]), np.zeros(2), NY)
    east = prime_vertical_radius(NY[0]) * math.cos(math.radians(NY[0])) * math.radians(d)
    north = meridian_radius(NY[0]) * math.radians(d)
    np.testing.assert_allclose(enu[0], [east, 0.0, 0.0], atol=2e-3)
    np.testing.assert_allclose(enu[1], [0.0, north, 0.0], atol=2e-3)


def test_enu_and_back_is_the_identity_and_the_origin_maps_to_zero():
    rng = np.random.default_rng(1)
    geo = np.column_stack([NY[0] + rng.uniform(-0.2, 0.2, 50), NY[1] + rng.uniform(-0.2, 0.2, 50),
                           rng.uniform(0, 10000, 50)])
    back = to_geodetic(to_enu(geo[:, 0], geo[:, 1], geo[:, 2], NY), NY)
    np.testing.assert_allclose(back[:, :2], geo[:, :2], atol=1e-9)
    np.testing.assert_allclose(back[:, 2], geo[:, 2], atol=1e-5)
    np.testing.assert_allclose(to_enu(np.array([NY[0]]), np.array([NY[1]]), np.array([0.0]), NY), 0.0, atol=1e-6)


def test_cleaning_drops_duplicates_outliers_and_lone_reports_and_splits_at_gaps():
    t = np.array([0.0, 10.0, 10.0, 20.0, 30.0, 40.0, 500.0, 800.0, 810.0, 820.0])
    x = 5.0 * t  # 5 m/s east
    x[4] += 5000.0  # a jump: 500 m/s
    enu = np.column_stack([x, np.zeros_like(t), np.zeros_like(t)])
    track = clean_track(t, enu, max_speed=30.0, max_gap=120.0)
    assert (track.duplicates, track.outliers, track.lone_reports) == (1, 1, 1)  # 10 s twice, 30 s, 500 s alone
    assert [seg_t.tolist() for seg_t, _ in track.segments] == [[0.0, 10.0, 20.0, 40.0], [800.0, 810.0, 820.0]]


def test_non_finite_reports_are_dropped_before_anything_else():
    t = np.array([0.0, np.nan, 20.0, 30.0])
    enu = np.array([[0, 0, 0], [1, 1, 1], [np.nan, 0, 0], [30, 0, 0]], dtype=float)
    track = clean_track(t, enu, max_speed=30.0, max_gap=120.0)
    assert [seg_t.tolist() for seg_t, _ in track.segments] == [[0.0, 30.0]]


def test_a_vessel_that_never_leaves_its_berth_is_still_and_one_that_sails_is_not():
    rng = np.random.default_rng(0)
    berth = rng.normal(0.0, 10.0, (100, 3))  # GPS jitter around a mooring
    assert is_still(berth, min_extent=100.0)
    sailing = np.column_stack([np.linspace(0, 2000, 100), np.zeros(100), np.zeros(100)])
    assert not is_still(sailing, min_extent=100.0)


def test_interpolation_passes_through_the_reports_and_is_exact_on_straight_lines():
    t = np.array([0.0, 7.0, 30.0, 45.0])
    enu = np.column_stack([3.0 * t + 1.0, -2.0 * t, np.full(4, 5.0)])
    times = np.linspace(0.0, 45.0, 10)
    pos, vel = interpolate_segment(t, enu, times)
    np.testing.assert_allclose(pos, np.column_stack([3.0 * times + 1.0, -2.0 * times, np.full(10, 5.0)]), atol=1e-9)
    np.testing.assert_allclose(vel, np.tile([3.0, -2.0, 0.0], (10, 1)), atol=1e-9)
    with pytest.raises(ValueError, match="within the segment"):
        interpolate_segment(t, enu, np.array([50.0]))


def test_ais_reader_takes_mmsi_names_speed_and_status(tmp_path):
    path = tmp_path / "ais.csv"
    header = ["BaseDateTime", "LON", "LAT", "MMSI", "SOG", "COG", "Heading", "VesselName", "IMO", "CallSign",
              "VesselType", "Status"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerow(["2020-06-30T00:00:00", "-74.0", "40.6", "111", "10.0", "0", "0", "FERRY ONE", "", "WX1", "60", "0"])
        w.writerow(["2020-06-30T00:01:00", "-74.1", "40.7", "222", "0.0", "0", "0", "", "", "CALL2", "60", "5"])
    r = read_ais_csv(path)
    assert r.ids.tolist() == ["111", "222"]
    assert r.labels == {"111": "FERRY ONE", "222": "CALL2"}
    np.testing.assert_allclose(r.t[1] - r.t[0], 60.0)
    np.testing.assert_allclose(r.speed[0], 10.0 * 1852 / 3600)
    assert r.still.tolist() == [False, True]  # status 5: moored


def test_adsb_reader_converts_feet_knots_and_milliseconds(tmp_path):
    path = tmp_path / "states.json.gz"
    states = [{"timestamp": 1_000_000, "icao24": "abc123", "callsign": "AFR12 ", "latitude": 48.9, "longitude": 2.3,
               "altitude": 10000.0, "groundspeed": 300.0, "onground": False},
              {"timestamp": 1_001_000, "icao24": "abc123", "callsign": "AFR12", "latitude": 48.91, "longitude": 2.3,
               "altitude": None, "groundspeed": 300.0, "onground": True}]
    with gzip.open(path, "wt") as fh:
        json.dump(states, fh)
    r = read_adsb_json(path)
    np.testing.assert_allclose(r.t, [1000.0, 1001.0])
    np.testing.assert_allclose(r.height[0], 3048.0)
    assert np.isnan(r.height[1]) and r.still.tolist() == [False, True]
    assert r.labels == {"abc123": "AFR12"}


def test_a_missing_data_package_is_one_line_naming_what_to_install(monkeypatch):
    monkeypatch.setattr(sources.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(RecordingUnavailable) as err:
        sources.source("adsb-paris").locate()
    assert "'traffic' is not installed" in str(err.value) and "pip install" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_missing_data_package_fails_the_command_with_exit_2(monkeypatch, capsys):
    monkeypatch.setattr(sources.importlib.util, "find_spec", lambda name: None)
    recording.read_source.cache_clear()
    try:
        assert main(["sim", "--scenario", "ais-nyharbor-radar", "--steps", "5"]) == 2
    finally:
        recording.read_source.cache_clear()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tracktable-data" in err[0]


def _fake_reports() -> Reports:
    """Three targets reporting every 10 s for 600 s: one sailing east through the region, one moored, one that
    stays outside the region."""
    t = np.arange(0.0, 600.0, 10.0)
    n = t.size
    lat0, lon0 = NY[0], NY[1]
    east = 1e-5 * t  # ~0.85 m/s east
    rows = [("sail", lat0 + 0 * t, lon0 - 0.01 + east), ("moor", lat0 + 1e-6 * np.sin(t), lon0 + 0 * t),
            ("far", lat0 + 0.5 + 0 * t, lon0 + east)]
    ids = np.concatenate([np.full(n, name) for name, _, _ in rows])
    return Reports(ids=ids, t=np.tile(t, 3) + 1e9, lat=np.concatenate([r[1] for r in rows]),
                   lon=np.concatenate([r[2] for r in rows]), height=np.zeros(3 * n), speed=np.full(3 * n, np.nan),
                   still=np.zeros(3 * n, dtype=bool), labels={"sail": "SAILOR", "moor": "MOORED", "far": "FAR"})


def test_recorded_targets_keep_the_moving_target_inside_the_region(monkeypatch):
    monkeypatch.setattr(recording, "read_source", lambda name: _fake_reports())
    region = np.array([[-1000.0, 1000.0], [-1000.0, 1000.0], [-50.0, 50.0]])
    spec = RecordingSpec("ais-nyharbor", NY, region, start=50.0, max_gap=60.0, min_extent=50.0)
    rt = recorded_targets(spec, steps=20, ts=10.0)
    assert rt.ids == ["sail"] and rt.labels == ["SAILOR"]
    assert rt.stats["still_targets"] == 1 and rt.stats["never_present"] == 1
    assert rt.alive[:, 0].all()
    lon = NY[1] - 0.01 + 1e-5 * (50.0 + 10.0 * np.arange(20))
    expected = to_enu(np.full(20, NY[0]), lon, np.zeros(20), NY)
    np.testing.assert_allclose(rt.truth[:, 0, :3], expected, atol=1e-6)
    assert np.all(rt.truth[:, 0, 3] > 0.8) and np.all(np.abs(rt.truth[:, 0, 4]) < 1e-3)


def test_a_target_is_absent_where_it_is_outside_the_region(monkeypatch):
    monkeypatch.setattr(recording, "read_source", lambda name: _fake_reports())
    region = np.array([[-1000.0, -600.0], [-1000.0, 1000.0], [-50.0, 50.0]])  # the sailor crosses x = -600
    rt = recorded_targets(RecordingSpec("ais-nyharbor", NY, region, max_gap=60.0, min_extent=50.0), 60, 10.0)
    present = rt.alive[:, 0]
    assert present[0] and not present[-1] and np.all(np.diff(present.astype(int)) <= 0)
    assert np.all(np.isnan(rt.truth[~present, 0]))
    assert np.all(rt.truth[present, 0, 0] <= -600.0)


def test_scenario_errors_name_the_key(tmp_path):
    _, base = resolve("ais-nyharbor")
    for old, new, key in [('origin = [40.66, -74.05, 0.0]', 'origin = [140.0, -74.05, 0.0]', "targets.origin"),
                          ('source = "ais-nyharbor"', 'source = "nowhere"', "targets.source"),
                          ('max_gap = 300.0', 'max_gap = "long"', "targets.max_gap")]:
        assert old in base
        path = tmp_path / "bad.toml"
        path.write_text(base.replace(old, new))
        with pytest.raises(ValueError, match=key.replace(".", r"\.")):
            load_scenario_config(str(path), multitarget=True)


needs_data = pytest.mark.skipif(importlib.util.find_spec("tracktable_data") is None
                                or importlib.util.find_spec("traffic") is None,
                                reason="the real-trajectory data packages are not installed (pip install 'zentrack[real]')")


@needs_data
@pytest.mark.cpu_only
@pytest.mark.slow  # reads the whole ADS-B recording (284,505 states, several seconds)
@pytest.mark.parametrize("name, least", [("ais-nyharbor", 15), ("adsb-paris", 10)])
def test_the_real_scenarios_hold_moving_targets_inside_their_region(name, least):
    cfg = load_scenario_config(name, multitarget=True)
    data = cfg.multitarget_data()
    spec = cfg.multitarget.targets.recording
    assert data.recorded is not None and data.truth.shape[1] >= least
    present = data.truth[data.alive]
    assert np.all(np.isfinite(present))
    assert np.all(np.linalg.norm(present[:, 3:], axis=1) <= spec.max_speed * 1.5)
    region = np.asarray(spec.region)
    assert np.all((present[:, :3] >= region[:, 0]) & (present[:, :3] <= region[:, 1]))
    assert data.alive.sum(axis=1).max() >= least // 2  # many at once
    assert all(label for label in data.recorded.labels)
    assert data.counts.sum() > 0


def test_smoothing_takes_a_noisy_recordings_jitter_out_of_the_velocity():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 1.0)
    true = np.column_stack([200.0 * t, 50.0 * t, 3000.0 + 0 * t])
    noisy = true + rng.normal(0.0, 15.0, true.shape)  # ADS-B-like scatter at 1 s
    times = np.arange(20.0, 280.0, 1.0)
    _, v_interp = trajectory_at(t, noisy, times, smoothing=0.0)
    pos, v_smooth = trajectory_at(t, noisy, times, smoothing=100.0)
    err = lambda v: float(np.sqrt(np.mean(np.sum((v - [200.0, 50.0, 0.0]) ** 2, axis=1))))  # noqa: E731
    assert err(v_smooth) < err(v_interp) / 5
    assert np.sqrt(np.mean((pos - np.column_stack([200.0 * times, 50.0 * times, 3000.0 + 0 * times])) ** 2)) < 10.0
    few = trajectory_at(t[:4], noisy[:4], t[:4], smoothing=100.0)[0]  # too few reports to smooth: interpolated
    np.testing.assert_allclose(few, noisy[:4], atol=1e-9)


def test_a_scenarios_gospa_cutoff_reaches_the_data_and_the_scores(tmp_path, capsys):
    _, text = resolve("mt-crossing")
    assert load_scenario_config("mt-crossing", multitarget=True).multitarget_data().gospa_cutoff == 50.0
    path = tmp_path / "far.toml"
    path.write_text(text.replace("[targets]\n", "[targets]\ngospa_cutoff = 123.0\n", 1))
    assert load_scenario_config(str(path), multitarget=True).multitarget_data().gospa_cutoff == 123.0
    out = tmp_path / "sim.json"
    assert main(["sim", "--scenario", str(path), "--steps", "8", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["cutoff"] == 123.0 and "c 123 m" in capsys.readouterr().out
