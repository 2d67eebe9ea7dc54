"""Video-satellite geometry for paper 3 (SecKF): Kepler orbits, Earth rotation, WGS-84 and the ship's ENU frame.

The paper tracks a ship from one video satellite whose orbital elements at the first observation are given in
its Table 4 (notes "Satellite"): a = 7071.004 km, e = 1e-6, i = 97.57 deg, RAAN 300 deg, argument of perigee
203 deg, mean anomaly 157 deg (:data:`PAPER_ORBIT`).  The measurement model works in the local ENU frame at the
ship's initial position (seed Section 2, notes "Model": x East, y North, z Up), so this module provides

* :class:`KeplerOrbit` — two-body propagation (Kepler's equation solved by vectorised Newton iterations) to
  ECI positions/velocities;
* :func:`eci_to_ecef` (rotation by the Greenwich angle ``gmst0 + omega_E t``), WGS-84
  :func:`geodetic_to_ecef` / :func:`ecef_to_geodetic`, :func:`ecef_to_enu` / :func:`enu_to_ecef`;
* :func:`ship_under_ground_track` and :func:`sensor_track_enu` — the paper gives neither epoch nor target
  location ("place the target under the ground track, in view"), so the ship is placed at the sub-satellite
  point at mid-scenario ``t_mid`` (optionally moved ``cross_track_m`` perpendicular to the ground track: an
  exact overhead pass puts the satellite near the zenith, where the azimuth is ill-conditioned);
* :func:`elevation_angle`, :func:`in_view`, :func:`line_of_sight_angles`;
* :data:`CONSTELLATION` — three video satellites on different orbits that see the same ship from different
  directions during one 60 s window (for multi-satellite fusion).

Time ``t`` is seconds since the orbit epoch; ``gmst0`` is the Greenwich sidereal angle at the epoch (the
scenarios use 0: the paper gives no epoch).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

import numpy as np

Array = np.ndarray

MU_EARTH = 3.986004418e14  # m^3/s^2 (WGS-84 / EGM96)
OMEGA_EARTH = 7.2921150e-5  # rad/s, Earth rotation rate (WGS-84)
WGS84_A = 6378137.0  # m
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


def _rot_z(angle: Array | float) -> Array:
    """``(..., 3, 3)`` matrices rotating vectors by ``angle`` about z (active rotation)."""
    c, s = np.cos(np.asarray(angle, dtype=float)), np.sin(np.asarray(angle, dtype=float))
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _rot_x(angle: float) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class KeplerOrbit:
    """Two-body Keplerian orbit; elements are osculating at the epoch ``t = 0`` (angles in radians, ``a_m`` m).

    J2 is deliberately left out.  The satellite ephemeris is shared by the simulated truth and by every filter,
    so J2 only changes the viewing geometry slightly: its secular drifts for this sun-synchronous orbit are
    ~1e-5 deg/s in RAAN and of the same order in the argument of latitude (< 1e-3 deg over 60 s), and its
    acceleration (~1e-2 m/s^2 at 700 km) displaces the satellite from the osculating Kepler arc by
    ~0.5 * 1e-2 * 30^2 ~ 5 m over +/-30 s — under 1e-5 rad of line-of-sight direction at a ~700 km range,
    a tenth of the paper's 1e-4 rad angle noise, and invisible to the filters because they use the same
    ephemeris as the truth.
    """

    a_m: float
    e: float
    i_rad: float
    raan_rad: float
    argp_rad: float
    m0_rad: float
    mu: float = MU_EARTH

    def __post_init__(self) -> None:
        if not self.a_m > 0 or not 0.0 <= self.e < 1.0:
            raise ValueError(f"need a > 0 and 0 <= e < 1, got a={self.a_m}, e={self.e}")

    @property
    def mean_motion(self) -> float:
        """``n = sqrt(mu / a^3)`` (rad/s)."""
        return float(np.sqrt(self.mu / self.a_m**3))

    @property
    def period(self) -> float:
        """``2 pi sqrt(a^3 / mu)`` (s)."""
        return 2.0 * np.pi / self.mean_motion

    def eccentric_anomaly(self, t: Array) -> Array:
        """Solve Kepler's equation ``E - e sin E = M0 + n t`` by Newton's method (element-wise, any shape)."""
        m = np.mod(self.m0_rad + self.mean_motion * np.asarray(t, dtype=float), 2.0 * np.pi)
        e = self.e
        ecc = m + e * np.sin(m) if e < 0.8 else np.full_like(m, np.pi)
        for _ in range(30):
            step = (ecc - e * np.sin(ecc) - m) / (1.0 - e * np.cos(ecc))
            ecc = ecc - step
            if np.all(np.abs(step) < 1e-15):
                break
        return ecc

    def _perifocal_to_eci(self) -> Array:
        return _rot_z(self.raan_rad) @ _rot_x(self.i_rad) @ _rot_z(self.argp_rad)

    @overload
    def eci(self, t: Array | float, velocity: Literal[False] = ...) -> Array: ...

    @overload
    def eci(self, t: Array | float, velocity: Literal[True]) -> tuple[Array, Array]: ...

    def eci(self, t: Array | float, velocity: bool = False) -> Array | tuple[Array, Array]:
        """ECI position ``(..., 3)`` (m) at times ``t`` (``...``, s since epoch); with ``velocity`` also ``(..., 3)`` m/s.

        Perifocal ``r = a (cos E - e, sqrt(1-e^2) sin E)``, ``v = a n / (1 - e cos E) (-sin E, sqrt(1-e^2) cos E)``
        rotated by ``R3(RAAN) R1(i) R3(argp)``.
        """
        ecc = self.eccentric_anomaly(np.asarray(t, dtype=float))
        ce, se = np.cos(ecc), np.sin(ecc)
        root = np.sqrt(1.0 - self.e**2)
        rot = self._perifocal_to_eci()
        zero = np.zeros_like(ce)
        pos = np.stack([self.a_m * (ce - self.e), self.a_m * root * se, zero], -1) @ rot.T
        if not velocity:
            return pos
        k = self.a_m * self.mean_motion / (1.0 - self.e * ce)
        vel = np.stack([-k * se, k * root * ce, zero], -1) @ rot.T
        return pos, vel


#: The paper's satellite at the first observation (seed Table 4).
PAPER_ORBIT = KeplerOrbit(
    a_m=7071.004e3,
    e=1e-6,
    i_rad=np.deg2rad(97.57),
    raan_rad=np.deg2rad(300.0),
    argp_rad=np.deg2rad(203.0),
    m0_rad=np.deg2rad(157.0),
)

#: Mid-scenario time (s after the epoch) used with :data:`PAPER_ORBIT`: the ship sits under the satellite then.
PAPER_T_MID = 30.0

#: Three video satellites for multi-satellite fusion, all seeing the ship placed by
#: ``ship_under_ground_track(PAPER_ORBIT, PAPER_T_MID)`` during ``PAPER_T_MID +/- 30 s`` (gmst0 = 0):
#: the paper's orbit (overhead pass, elevation 72-90 deg) and two copies with (RAAN, mean anomaly) shifted by
#: (+5, +3) deg and (-5, -3) deg, which at ``t_mid`` are ~570 km East and ~370 km North (resp. West and South)
#: of the ship, elevation 40-47 deg, range 915-1020 km.  Pairwise lines of sight differ by 41-47 deg (overhead
#: vs. either) and 88-91 deg (the two side satellites) over the window; ``tests/test_orbit.py`` checks > 20 deg.
CONSTELLATION: tuple[KeplerOrbit, ...] = (
    PAPER_ORBIT,
    KeplerOrbit(7071.004e3, 1e-6, np.deg2rad(97.57), np.deg2rad(305.0), np.deg2rad(203.0), np.deg2rad(160.0)),
    KeplerOrbit(7071.004e3, 1e-6, np.deg2rad(97.57), np.deg2rad(295.0), np.deg2rad(203.0), np.deg2rad(154.0)),
)


def scenario_times(n: int, dt: float, t_mid: float) -> Array:
    """``n`` observation times ``dt`` apart centred on ``t_mid`` (``t_mid + dt (k - (n-1)/2)``)."""
    return t_mid + dt * (np.arange(n) - 0.5 * (n - 1))


def eci_to_ecef(r: Array, t: Array | float, gmst0: float = 0.0) -> Array:
    """Rotate ECI vectors ``r`` ``(..., 3)`` to ECEF: about z by ``-(gmst0 + omega_E t)`` (``t`` broadcasts to ``...``)."""
    theta = gmst0 + OMEGA_EARTH * np.asarray(t, dtype=float)
    r = np.asarray(r, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * r[..., 0] + s * r[..., 1], -s * r[..., 0] + c * r[..., 1], r[..., 2]], -1)


def ecef_to_eci(r: Array, t: Array | float, gmst0: float = 0.0) -> Array:
    """Inverse of :func:`eci_to_ecef`."""
    return eci_to_ecef(r, -np.asarray(t, dtype=float), -gmst0)


def geodetic_to_ecef(lat: Array | float, lon: Array | float, h: Array | float = 0.0) -> Array:
    """WGS-84 geodetic latitude/longitude (rad) and ellipsoidal height (m) to ECEF ``(..., 3)`` (m)."""
    lat, lon, h = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float), np.asarray(h, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sl * sl)
    return np.stack(
        np.broadcast_arrays((n + h) * cl * np.cos(lon), (n + h) * cl * np.sin(lon), (n * (1.0 - WGS84_E2) + h) * sl), -1
    )


def ecef_to_geodetic(r: Array) -> tuple[Array, Array, Array]:
    """ECEF ``(..., 3)`` to WGS-84 ``(lat, lon, h)`` by fixed-point iteration on the latitude.

    ``lat <- atan2(z + e^2 N sin lat, p)`` converges to 1e-15 rad within a few iterations for points from the
    surface to LEO; ``h = p cos lat + z sin lat - a sqrt(1 - e^2 sin^2 lat)`` is stable at the poles too.
    """
    r = np.asarray(r, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(10):
        sl = np.sin(lat)
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sl * sl)
        lat = np.arctan2(z + WGS84_E2 * n * sl, p)
    sl, cl = np.sin(lat), np.cos(lat)
    h = p * cl + z * sl - WGS84_A * np.sqrt(1.0 - WGS84_E2 * sl * sl)
    return lat, lon, h


def enu_rotation(lat0: float, lon0: float) -> Array:
    """``(3, 3)`` matrix whose rows are the East, North, Up unit vectors at ``(lat0, lon0)`` in ECEF."""
    sl, cl, so, co = np.sin(lat0), np.cos(lat0), np.sin(lon0), np.cos(lon0)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def ecef_to_enu(r: Array, lat0: float, lon0: float, h0: float = 0.0) -> Array:
    """ECEF points ``(..., 3)`` to the ENU frame at geodetic ``(lat0, lon0, h0)`` (x East, y North, z Up)."""
    origin = geodetic_to_ecef(lat0, lon0, h0)
    return (np.asarray(r, dtype=float) - origin) @ enu_rotation(lat0, lon0).T


def enu_to_ecef(enu: Array, lat0: float, lon0: float, h0: float = 0.0) -> Array:
    """Inverse of :func:`ecef_to_enu`."""
    return np.asarray(enu, dtype=float) @ enu_rotation(lat0, lon0) + geodetic_to_ecef(lat0, lon0, h0)


def ship_under_ground_track(
    orbit: KeplerOrbit, t_mid: float, gmst0: float = 0.0, cross_track_m: float = 0.0
) -> tuple[float, float]:
    """Geodetic ``(lat, lon)`` (rad, on the ellipsoid) of the sub-satellite point of ``orbit`` at ``t_mid``.

    The paper gives no target location; putting the ship under the satellite at mid-scenario keeps it in view
    (elevation near 90 deg) for the whole observation window.  ``cross_track_m`` moves the ship that far
    perpendicular to the ground track (positive to the right of the direction of travel), for geometries that
    avoid the near-zenith pass.
    """
    r = eci_to_ecef(orbit.eci(t_mid), t_mid, gmst0)
    lat, lon, _ = ecef_to_geodetic(r)
    if cross_track_m == 0.0:
        return float(lat), float(lon)
    ahead = ecef_to_enu(eci_to_ecef(orbit.eci(t_mid + 1.0), t_mid + 1.0, gmst0), float(lat), float(lon))
    track = ahead[:2] / np.hypot(ahead[0], ahead[1])
    right = np.array([track[1], -track[0], 0.0])  # horizontal, 90 deg clockwise of the track
    lat2, lon2, _ = ecef_to_geodetic(enu_to_ecef(cross_track_m * right, float(lat), float(lon)))
    return float(lat2), float(lon2)


def sensor_track_enu(
    orbit: KeplerOrbit, times: Array, lat0: float, lon0: float, h0: float = 0.0, gmst0: float = 0.0
) -> Array:
    """Satellite positions ``(K, 3)`` at ``times`` ``(K,)`` in the ship's ENU frame at ``(lat0, lon0, h0)``."""
    times = np.asarray(times, dtype=float)
    return ecef_to_enu(eci_to_ecef(orbit.eci(times), times, gmst0), lat0, lon0, h0)


def elevation_angle(sat_enu: Array, target_enu: Array | None = None) -> Array:
    """Elevation (rad) of ``sat_enu`` ``(..., 3)`` above the local horizontal at ``target_enu`` (default origin).

    This is the paper's beta with the sign reversed (beta looks from the satellite down to the target).
    """
    d = np.asarray(sat_enu, dtype=float) - (0.0 if target_enu is None else np.asarray(target_enu, dtype=float))
    return np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1]))


def in_view(sat_enu: Array, min_elevation_deg: float = 10.0, target_enu: Array | None = None) -> Array:
    """Boolean ``(...)``: the satellite is at least ``min_elevation_deg`` above the target's horizon."""
    return elevation_angle(sat_enu, target_enu) >= np.deg2rad(min_elevation_deg)


def line_of_sight_angles(sat_a_enu: Array, sat_b_enu: Array, target_enu: Array | None = None) -> Array:
    """Angle (rad) between the lines of sight from the target to two satellites, element-wise over ``(..., 3)``."""
    origin = 0.0 if target_enu is None else np.asarray(target_enu, dtype=float)
    a = np.asarray(sat_a_enu, dtype=float) - origin
    b = np.asarray(sat_b_enu, dtype=float) - origin
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.arctan2(cross, np.sum(a * b, axis=-1))
