"""What each sensor of a many-target network reports: detections in its field of view, measurement noise and
Poisson clutter, for sensors of one measurement kind or of several (a mixed network: bearing-only cameras beside
point radars, each sensor measuring by its own kind's model with its kind's sensing).

:func:`sense` turns the targets' truth into every sensor's shuffled scans (the model of
:mod:`~zentrack.truth.simulation.multitarget`). A mixed network's returns and noise covariances are stored at the
largest measurement dimension (a bearing sensor's third component is padding, 0):
:meth:`~zentrack.truth.simulation.multitarget.MultiTargetData.scan` cuts each sensor's scan to its own dimension.
One kind draws exactly what it drew before kinds could differ.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.models import make_measurement

from .scenario_spec import ScenarioSpec

Array = np.ndarray
#: ``origin`` of a clutter return and of a padding slot
CLUTTER, PADDING = -1, -2


@dataclass(frozen=True)
class SensingSpec:
    """What each sensor sees: ``detection_prob`` (P_D), ``max_range`` (m; ``inf``: unlimited, bearing sensors
    only), ``fov_azimuth`` (full width, rad, centred on the sensor's boresight; 2 pi: all round),
    ``fov_elevation`` ``(lo, hi)`` rad and ``clutter_rate`` (mean clutter returns per scan)."""

    detection_prob: float
    max_range: float
    fov_azimuth: float
    fov_elevation: tuple[float, float]
    clutter_rate: float


@dataclass
class Sensed:
    """Every sensor's scans of a run (:class:`~zentrack.truth.simulation.multitarget.MultiTargetData`'s fields)."""

    kinds: tuple[str, ...]
    boresight: Array
    noise_cov: Array
    in_view: Array
    returns: Array
    counts: Array
    origin: Array


def boresights(sensors: Array, centre: Array) -> Array:
    """The azimuth ``(M,)`` from each sensor to ``centre`` (what its field of view is centred on)."""
    d = np.asarray(centre, dtype=float)[None, :2] - np.asarray(sensors, dtype=float)[:, :2]
    return np.arctan2(d[:, 1], d[:, 0])


def in_field_of_view(points: Array, sensors: Array, boresight: Array, sensing: SensingSpec) -> Array:
    """Whether each of ``points`` ``(..., M, P, 3)`` lies in range and in the field of view of sensor m
    (``sensors`` ``(M, 3)``, ``boresight`` ``(M,)``): a ``(..., M, P)`` bool array (NaN points: False)."""
    d = points - sensors[:, None, :]
    horizontal = np.hypot(d[..., 0], d[..., 1])
    az_off = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - boresight[:, None])
    el = np.arctan2(d[..., 2], horizontal)
    lo, hi = sensing.fov_elevation
    with np.errstate(invalid="ignore"):
        return ((np.hypot(horizontal, d[..., 2]) <= sensing.max_range) & (np.abs(az_off) <= sensing.fov_azimuth / 2)
                & (el >= lo) & (el <= hi))


def kind_groups(kinds: tuple[str, ...]) -> dict[str, Array]:
    """Each measurement kind and the indices of its sensors, in order of first appearance."""
    return {kind: np.array([i for i, k in enumerate(kinds) if k == kind]) for kind in dict.fromkeys(kinds)}


def sense(spec: ScenarioSpec, kinds: tuple[str, ...], sensing_of: Mapping[str, SensingSpec], centre: Array,
          truth: Array, alive: Array, detect_rng: np.random.Generator, clutter_rng: np.random.Generator) -> Sensed:
    """Detections, noisy measurements and clutter of every sensor at every step, shuffled per scan: sensor i
    measures by ``kinds[i]`` and sees what ``sensing_of`` its kind says, its field of view facing ``centre``."""
    return sense_at(np.asarray(spec.sensors, dtype=float), spec.noise_levels(), kinds, sensing_of, centre, truth, alive,
                    detect_rng, clutter_rng)


def sense_at(sensors: Array, stds: Array, kinds: tuple[str, ...], sensing_of: Mapping[str, SensingSpec],
             centre: Array, truth: Array, alive: Array, detect_rng: np.random.Generator,
             clutter_rng: np.random.Generator) -> Sensed:
    """:func:`sense` for the sensors at ``sensors`` ``(M, 3)`` with noise levels ``stds`` ``(M,)``, of the targets
    ``truth`` ``(K, T, 6)`` present where ``alive`` ``(K, T)``: the K instants may be the run's steps or any
    times (a sensor of its own samples at its own, ``sensor_stream.py``)."""
    steps, n_targets = alive.shape
    n_sensors = sensors.shape[0]
    groups = kind_groups(kinds)
    models = {kind: make_measurement(kind) for kind in groups}
    dims = np.array([models[k].dim for k in kinds])
    m = int(dims.max())
    boresight = boresights(sensors, centre)
    positions = np.broadcast_to(truth[:, None, :, :3], (steps, n_sensors, n_targets, 3))
    in_view = np.zeros((steps, n_sensors, n_targets), dtype=bool)
    pd, rate = np.zeros(n_sensors), np.zeros(n_sensors)
    for kind, idx in groups.items():
        sensing = sensing_of[kind]
        in_view[:, idx] = in_field_of_view(positions[:, idx], sensors[idx], boresight[idx], sensing)
        pd[idx], rate[idx] = sensing.detection_prob, sensing.clutter_rate
    in_view &= alive[:, None, :]
    detected = in_view & (detect_rng.random(in_view.shape) < pd[None, :, None])
    flat = np.nan_to_num(truth).reshape(steps * n_targets, 6)
    z = np.zeros((steps, n_sensors, n_targets, m))
    for kind, idx in groups.items():
        mk = models[kind].dim
        zk = models[kind].h(flat, np.broadcast_to(sensors[idx], (flat.shape[0], idx.size, 3)))  # (K*T, M_k*m_k)
        z[:, idx, :, :mk] = zk.reshape(steps, n_targets, idx.size, mk).transpose(0, 2, 1, 3)
    used = (np.arange(m)[None, :] < dims[:, None]).astype(float)  # (M, m): a sensor's own components
    z = z + stds[None, :, None, None] * detect_rng.standard_normal(z.shape) * used[None, :, None, :]
    n_clutter = clutter_rng.poisson(rate[0] if len(groups) == 1 else rate, (steps, n_sensors))
    u = clutter_rng.random((steps, n_sensors, int(n_clutter.max(initial=0)), 3))
    clutter = np.zeros((steps, n_sensors, u.shape[2], m))
    for kind, idx in groups.items():
        clutter[:, idx, :, : models[kind].dim] = _clutter(kind, sensors[idx], boresight[idx], sensing_of[kind],
                                                          u[:, idx])
    if "bearing" in groups:
        bearing = groups["bearing"]
        z[:, bearing, :, 0] = wrap_angle(z[:, bearing, :, 0])
    # every candidate of a scan (each target, then each clutter slot), shuffled by random keys; invalid ones last
    values = np.concatenate([z, clutter], axis=2)
    ids = np.concatenate([np.broadcast_to(np.arange(n_targets), (steps, n_sensors, n_targets)),
                          np.full((steps, n_sensors, clutter.shape[2]), CLUTTER)], axis=2)
    valid = np.concatenate([detected, np.arange(clutter.shape[2]) < n_clutter[..., None]], axis=2)
    keys = np.where(valid, clutter_rng.random(valid.shape), 2.0)
    counts = valid.sum(axis=2)
    order = np.argsort(keys, axis=2, kind="stable")[..., : int(counts.max(initial=0))]
    kept = np.take_along_axis(valid, order, axis=2)
    returns = np.where(kept[..., None], np.take_along_axis(values, order[..., None], axis=2), 0.0)
    origin = np.where(kept, np.take_along_axis(ids, order, axis=2), PADDING)
    noise_cov = (stds**2)[:, None, None] * (used[:, :, None] * np.eye(m)[None])
    return Sensed(kinds, boresight, noise_cov, in_view, returns, counts, origin)


def _clutter(kind: str, sensors: Array, boresight: Array, sensing: SensingSpec, u: Array) -> Array:
    """Clutter returns ``(K, M, J, m)`` uniform in each sensor's field of view from uniform draws ``u``
    ``(K, M, J, 3)``: in angle (azimuth, elevation) for bearing sensors, in volume for point sensors
    (range ~ R u^(1/3), sin(elevation) uniform), positions in the world frame."""
    az = boresight[:, None] + (u[..., 0] - 0.5) * min(sensing.fov_azimuth, 2 * np.pi)
    lo, hi = sensing.fov_elevation
    if kind == "bearing":
        return np.stack([wrap_angle(az), lo + u[..., 1] * (hi - lo)], axis=-1)
    el = np.arcsin(np.sin(lo) + u[..., 1] * (np.sin(hi) - np.sin(lo)))
    r = sensing.max_range * np.cbrt(u[..., 2])
    offset = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=-1)
    return sensors[:, None, :] + offset
