"""Satellite geometry of paper 3: frame round trips, Kepler propagation, visibility of the paper's scenario."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from zentrack.truth.simulation.orbit import (
    CONSTELLATION,
    PAPER_ORBIT,
    PAPER_T_MID,
    KeplerOrbit,
    ecef_to_eci,
    ecef_to_enu,
    ecef_to_geodetic,
    eci_to_ecef,
    elevation_angle,
    enu_to_ecef,
    geodetic_to_ecef,
    in_view,
    line_of_sight_angles,
    scenario_times,
    sensor_track_enu,
    ship_under_ground_track,
)


def test_enu_ecef_round_trip(rng):
    for lat0, lon0, h0 in [(0.3, -1.05, 0.0), (-1.2, 2.9, 120.0), (1.5, 0.1, -30.0)]:
        enu = rng.normal(0.0, 5e5, (50, 3))
        back = ecef_to_enu(enu_to_ecef(enu, lat0, lon0, h0), lat0, lon0, h0)
        np.testing.assert_allclose(back, enu, atol=1e-6)
    # the frame's axes: Up is the ellipsoid normal, East horizontal, right-handed
    up = enu_to_ecef(np.array([0.0, 0.0, 1000.0]), 0.5, 1.0) - geodetic_to_ecef(0.5, 1.0, 0.0)
    np.testing.assert_allclose(ecef_to_geodetic(geodetic_to_ecef(0.5, 1.0, 0.0) + up)[2], 1000.0, atol=1e-6)


def test_geodetic_ecef_round_trip(rng):
    lat = rng.uniform(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6, 200)
    lon = rng.uniform(-np.pi, np.pi, 200)
    h = rng.uniform(-1e3, 1e6, 200)
    lat2, lon2, h2 = ecef_to_geodetic(geodetic_to_ecef(lat, lon, h))
    np.testing.assert_allclose(lat2, lat, atol=1e-12)
    np.testing.assert_allclose(lon2, lon, atol=1e-12)
    np.testing.assert_allclose(h2, h, atol=1e-6)
    # the equator and the pole of WGS-84
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [6378137.0, 0.0, 0.0])
    np.testing.assert_allclose(geodetic_to_ecef(np.pi / 2, 0.0, 0.0)[2], 6356752.314245, atol=1e-5)


def test_eci_ecef_rotation():
    r = np.array([7e6, 1e5, 2e5])
    t = 1234.5
    np.testing.assert_allclose(ecef_to_eci(eci_to_ecef(r, t, 0.3), t, 0.3), r, atol=1e-6)
    # after a quarter sidereal turn the ECI x axis appears along ECEF -y
    t90 = (np.pi / 2) / 7.2921150e-5
    np.testing.assert_allclose(eci_to_ecef(np.array([1.0, 0.0, 0.0]), t90), [0.0, -1.0, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    "orbit",
    [PAPER_ORBIT, KeplerOrbit(2.4e7, 0.7, 1.1, 0.4, 2.0, 5.5), KeplerOrbit(7.2e6, 0.05, 0.9, 3.0, 1.0, 0.2)],
)
def test_kepler_radius_period_energy(orbit):
    t = np.linspace(0.0, orbit.period, 2001)
    pos, vel = orbit.eci(t, velocity=True)
    r = np.linalg.norm(pos, axis=-1)
    assert np.all(r >= orbit.a_m * (1 - orbit.e) * (1 - 1e-12))
    assert np.all(r <= orbit.a_m * (1 + orbit.e) * (1 + 1e-12))
    assert orbit.period == pytest.approx(2 * np.pi * np.sqrt(orbit.a_m**3 / orbit.mu))
    np.testing.assert_allclose(pos[-1], pos[0], atol=1e-9 * orbit.a_m)  # brief: 1e-3 relative
    energy = 0.5 * np.sum(vel * vel, axis=-1) - orbit.mu / r
    np.testing.assert_allclose(energy, -orbit.mu / (2 * orbit.a_m), rtol=1e-10)
    h = np.cross(pos, vel)  # angular momentum: constant, along the orbit normal
    np.testing.assert_allclose(h, np.broadcast_to(h[0], h.shape), rtol=1e-9, atol=1e-9 * np.linalg.norm(h[0]))
    np.testing.assert_allclose(np.arccos(h[0, 2] / np.linalg.norm(h[0])), orbit.i_rad, atol=1e-12)
    # velocity is the time derivative of position
    dt = 1e-2
    fd = (orbit.eci(t[:50] + dt) - orbit.eci(t[:50] - dt)) / (2 * dt)
    np.testing.assert_allclose(fd, vel[:50], rtol=1e-6, atol=1e-6 * np.linalg.norm(vel[0]))


def test_paper_orbit_elements():
    assert PAPER_ORBIT.a_m == 7071.004e3
    assert np.rad2deg(PAPER_ORBIT.i_rad) == pytest.approx(97.57)
    assert PAPER_ORBIT.period == pytest.approx(5917.5, abs=1.0)  # ~98.6 min, sun-synchronous LEO


def test_paper_scenario_in_view():
    lat, lon = ship_under_ground_track(PAPER_ORBIT, PAPER_T_MID)
    times = scenario_times(20, 1.0, PAPER_T_MID)
    sats = sensor_track_enu(PAPER_ORBIT, times, lat, lon)
    assert sats.shape == (20, 3)
    assert np.all(in_view(sats, 10.0))
    assert np.all(np.rad2deg(elevation_angle(sats)) > 80.0)
    slant = np.linalg.norm(sats, axis=-1)
    assert np.all(slant < 2.0e6) and np.all(slant > 6.0e5)
    # right overhead at t_mid
    mid = sensor_track_enu(PAPER_ORBIT, np.array([PAPER_T_MID]), lat, lon)[0]
    assert np.hypot(mid[0], mid[1]) < 1e-3 and mid[2] > 6.5e5


def test_cross_track_offset_moves_ship_off_the_track():
    lat, lon = ship_under_ground_track(PAPER_ORBIT, PAPER_T_MID)
    lat2, lon2 = ship_under_ground_track(PAPER_ORBIT, PAPER_T_MID, cross_track_m=2e5)
    d = ecef_to_enu(geodetic_to_ecef(lat2, lon2, 0.0), lat, lon)
    assert np.hypot(d[0], d[1]) == pytest.approx(2e5, rel=1e-3)
    mid = sensor_track_enu(PAPER_ORBIT, np.array([PAPER_T_MID]), lat2, lon2)[0]
    assert 70.0 < np.rad2deg(elevation_angle(mid)) < 80.0


def test_constellation_sees_the_ship_from_different_directions():
    lat, lon = ship_under_ground_track(PAPER_ORBIT, PAPER_T_MID)
    times = scenario_times(61, 1.0, PAPER_T_MID)
    tracks = [sensor_track_enu(orbit, times, lat, lon) for orbit in CONSTELLATION]
    assert len(tracks) == 3
    for sats in tracks:
        assert np.all(np.rad2deg(elevation_angle(sats)) > 20.0)
        assert np.all(np.linalg.norm(sats, axis=-1) < 2.0e6)
    for a, b in itertools.combinations(tracks, 2):
        assert np.all(np.rad2deg(line_of_sight_angles(a, b)) > 20.0)
