"""Scenario files: one or more simulated runs in a single ``.npz`` (no pickle), read back exactly.

Keys (R runs, K steps, M nodes, n state, m measurement, l lumped; all float64 unless noted):

==================  ==============  ==========================================================
key                 shape           meaning
==================  ==============  ==========================================================
schema_version      ()  int         1
name                ()  str         scenario name (``exp1``, ``exp2``, ``exp2-point`` or yours)
plant               ()  str         ``exp1`` or ``cv3d`` (motion model, see zentrack.fusion.motion)
plant_params        ()  str         JSON object of the plant's parameters (e.g. sigma_w, alpha, beta)
measurement         ()  str         ``bearing`` (az, el in rad), ``point`` (x, y, z) or ``linear``
linear_matrix       (m, n)          H of a linear measurement (absent otherwise)
ts                  ()              sample period Ts in seconds
seed                ()  int         seed the runs were drawn with (informational)
truth               (R, K, n)       true state at sample k
lumped              (R, K, l)       true lumped term F(x_k, k) (evaluation only)
sensors             (M, 3)          sensor positions
measurements        (R, K, M, m)    node i's measurement at step k (ignored where not present)
present             (R, K, M) bool  whether that measurement exists
noise_cov           (M, m, m)       measurement noise covariance of each node
adjacency           (M, M) bool     communication graph (no self loops)
weights             (M, M)          row-stochastic diffusion weights, w_ii > 0
x0_estimate         (R, n)          every node's initial estimate
p0                  (n, n)          initial kinematic covariance
lumped_var          ()              initial variance of augmented (lumped) states
roles               (M,)  str       ``sensor`` or ``relay`` per node (optional; absent: all sensors)
scan_returns        (R, K, M, J, m) scans with clutter, padded (optional; paper 1, see zentrack.truth.simulation.clutter)
scan_counts         (R, K, M) int   returns per scan, 0 <= count <= J (with scan_returns)
scan_target         (R, K, M) int   the target's return in each scan, -1 when missed (evaluation only)
sensor_track        (K, M, 3)       positions of moving sensors at every step (optional; paper 2)
==================  ==============  ==========================================================
"""
from __future__ import annotations

import json
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from zentrack.common.atomic import replace_atomically
from zentrack.common.limits import MAX_NODES, MAX_STEPS
from zentrack.config.scenario_config import BOUNDS, TS_RANGE
from zentrack.truth.simulation.scenario import ScenarioData

SCHEMA_VERSION = 1
_ARRAYS = (
    "truth", "lumped", "sensors", "measurements", "present", "noise_cov", "adjacency", "weights",
    "x0_estimate", "p0",
)
_SCAN_ARRAYS = ("scan_returns", "scan_counts", "scan_target")
#: measured values besides ``measurements``: refused unless floating point (never rounded to whole numbers)
_REAL = ("scan_returns",)


class ScenarioFileError(ValueError):
    """A scenario file is missing, unreadable or invalid; the message names the file and the key."""


def save_scenario(path: str | os.PathLike, scn: ScenarioData) -> Path:
    """Write ``scn`` to ``path`` atomically (a temporary file renamed into place, removed on failure)."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ScenarioFileError(f"{path}: scenario files end in .npz")
    scn.validate()
    data: dict[str, np.ndarray | np.generic] = {key: np.asarray(getattr(scn, key)) for key in _ARRAYS}
    data.update(
        schema_version=np.int64(SCHEMA_VERSION),
        name=np.str_(scn.name),
        plant=np.str_(scn.plant),
        plant_params=np.str_(json.dumps(scn.plant_params, sort_keys=True)),
        measurement=np.str_(scn.measurement),
        ts=np.float64(scn.ts),
        seed=np.int64(scn.seed),
        lumped_var=np.float64(scn.lumped_var),
    )
    if scn.linear_matrix is not None:
        data["linear_matrix"] = np.asarray(scn.linear_matrix, dtype=float)
    if np.any(np.asarray(scn.roles) != "sensor"):
        data["roles"] = np.asarray(scn.roles, dtype=str)
    if scn.sensor_track is not None:
        data["sensor_track"] = np.asarray(scn.sensor_track, dtype=float)
    if scn.scan_returns is not None:
        data.update(scan_returns=np.asarray(scn.scan_returns, dtype=float),
                    scan_counts=np.asarray(scn.scan_counts, dtype=np.int64),
                    scan_target=np.asarray(scn.scan_target, dtype=np.int64))
    return replace_atomically(path, lambda tmp: np.savez(tmp, **data), suffix=".tmp.npz")  # type: ignore[arg-type]  # numpy stub: **kwds vs allow_pickle: bool


# what reading a damaged file raises: a truncated or empty zip (EOFError, BadZipFile), a bad CRC (BadZipFile),
# a damaged deflate stream (zlib.error), a bad array header or short data (ValueError), a huge claimed shape
_UNREADABLE = (OSError, EOFError, ValueError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, MemoryError,
               OverflowError, KeyError, NotImplementedError)


def _why(exc: BaseException) -> str:
    if isinstance(exc, MemoryError):
        return "an array is too large to load"
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def load_scenario(path: str | os.PathLike) -> ScenarioData:
    """Read and validate a scenario file; raise :class:`ScenarioFileError` naming the file and key."""
    path = Path(path)
    if path.is_dir():
        raise ScenarioFileError(f"{path}: is a folder, not a scenario .npz file")
    if path.is_file() and path.stat().st_size == 0:
        raise ScenarioFileError(f"{path}: not a readable .npz file (the file is empty)")
    try:
        npz = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ScenarioFileError(f"{path}: no such scenario file") from None
    except _UNREADABLE as exc:
        raise ScenarioFileError(f"{path}: not a readable .npz file ({_why(exc)})") from None
    try:
        scn = _read(path, npz)
    except ScenarioFileError:
        raise
    except _UNREADABLE as exc:  # damage inside a member shows only when it is read
        raise ScenarioFileError(f"{path}: not a readable .npz file ({_why(exc)})") from None
    finally:
        npz.close()
    _check_counts(path, scn)
    try:
        scn.validate()
    except (ValueError, TypeError) as exc:
        raise ScenarioFileError(f"{path}: {exc}") from None
    _check_values(path, scn)
    if not TS_RANGE[0] <= scn.ts <= TS_RANGE[1]:
        raise ScenarioFileError(f"{path}: key 'ts' must be from {TS_RANGE[0]:g} to {TS_RANGE[1]:g} s, got {scn.ts:g}")
    if scn.steps > MAX_STEPS or scn.nodes > MAX_NODES:
        raise ScenarioFileError(f"{path}: key 'truth'/'sensors': at most {MAX_STEPS} steps and {MAX_NODES} nodes, "
                                f"got {scn.steps} steps and {scn.nodes} nodes")
    return scn


def _check_counts(path: Path, scn: ScenarioData) -> None:
    """At least one run, one step and one node: an empty axis passed every shape check and then broke the
    simulation (an IndexError) or gave a run with nothing to estimate ("run OK")."""
    if np.ndim(scn.truth) == 3 and 0 in np.shape(scn.truth)[:2]:
        runs, steps = np.shape(scn.truth)[:2]
        raise ScenarioFileError(f"{path}: key 'truth': needs at least 1 run and 1 step, got {runs} run(s) and "
                                f"{steps} step(s)")
    if np.ndim(scn.sensors) == 2 and np.shape(scn.sensors)[0] == 0:
        raise ScenarioFileError(f"{path}: key 'sensors': needs at least 1 node, got 0")


def _check_values(path: Path, scn: ScenarioData) -> None:
    """The values the shape checks let through: the lumped variance within its TOML key's bounds (a negative
    one divided by zero in the simulation and killed every tracker), and an undirected graph (a link only one
    end knows of is a neighbour that never hears back)."""
    lo, hi = BOUNDS["initial.lumped_var"]
    if not lo <= scn.lumped_var <= hi:
        raise ScenarioFileError(f"{path}: key 'lumped_var' must be from {lo:g} to {hi:g}, got {scn.lumped_var!r}")
    adj = np.asarray(scn.adjacency, dtype=bool)
    if np.any(np.diag(adj)):
        raise ScenarioFileError(f"{path}: key 'adjacency' has self loops (node {int(np.flatnonzero(np.diag(adj))[0])})")
    one_way = np.argwhere(adj != adj.T)
    if one_way.size:
        i, j = (int(v) for v in one_way[0])
        raise ScenarioFileError(f"{path}: key 'adjacency' must be symmetric (an undirected graph): "
                                f"[{i}, {j}] is {bool(adj[i, j])} but [{j}, {i}] is {bool(adj[j, i])}")


def _roles(path: Path, npz, nodes: int) -> np.ndarray:
    try:
        value = npz["roles"]
    except (ValueError, *_UNREADABLE) as exc:
        raise ScenarioFileError(f"{path}: key 'roles' cannot be read ({_why(exc)})") from None
    if value.dtype.kind != "U" or value.shape != (nodes,) or not set(value.tolist()) <= {"sensor", "relay"}:
        raise ScenarioFileError(f"{path}: key 'roles' must be {nodes} strings, each 'sensor' or 'relay'")
    return value.astype(str)


def _read(path: Path, npz) -> ScenarioData:
    def get(key: str, kind: type | None = None):
        if key not in npz.files:
            raise ScenarioFileError(f"{path}: missing key {key!r}")
        try:
            value = npz[key]
        except ValueError as exc:  # object arrays need pickle: refused
            raise ScenarioFileError(f"{path}: key {key!r} is not a plain array ({_why(exc)})") from None
        except _UNREADABLE as exc:  # a bad CRC, a truncated member, a damaged stream
            raise ScenarioFileError(f"{path}: key {key!r} cannot be read ({_why(exc)})") from None
        if kind is str:
            if value.dtype.kind != "U" or value.ndim != 0:
                raise ScenarioFileError(f"{path}: key {key!r} must be a string")
            return str(value)
        if kind in (int, float):
            if value.ndim != 0 or value.dtype.kind not in "iuf":
                raise ScenarioFileError(f"{path}: key {key!r} must be a number")
            return kind(value)
        if value.dtype.kind not in "biuf":
            raise ScenarioFileError(f"{path}: key {key!r} must be numeric, got dtype {value.dtype}")
        return value

    version = get("schema_version", int)
    if version != SCHEMA_VERSION:
        raise ScenarioFileError(f"{path}: schema_version {version} is not supported (expected {SCHEMA_VERSION})")
    try:
        params = json.loads(get("plant_params", str))
    except json.JSONDecodeError as exc:
        raise ScenarioFileError(f"{path}: key 'plant_params' is not JSON ({exc})") from None
    if not isinstance(params, dict) or not all(isinstance(v, (int, float)) for v in params.values()):
        raise ScenarioFileError(f"{path}: key 'plant_params' must be a JSON object of numbers")
    for name, value in params.items():
        lo, hi = BOUNDS.get(f"plant.{name}", (-float("inf"), float("inf")))
        if not lo <= value <= hi:
            raise ScenarioFileError(f"{path}: key 'plant_params': {name} must be from {lo:g} to {hi:g}, got {value!r}")
    arrays = {key: get(key) for key in _ARRAYS}
    for key, value in [("measurements", arrays["measurements"]), *((k, get(k)) for k in _REAL if k in npz.files)]:
        if value.dtype.kind != "f":
            raise ScenarioFileError(f"{path}: key {key!r} must hold floating-point values, got dtype {value.dtype} "
                                    "(measured values stored as whole numbers have lost their fractions)")
    arrays = {k: (v.astype(bool) if k in ("present", "adjacency") else v.astype(float)) for k, v in arrays.items()}
    scans = {key: get(key) for key in _SCAN_ARRAYS if key in npz.files}
    if scans and set(scans) != set(_SCAN_ARRAYS):
        raise ScenarioFileError(f"{path}: keys {', '.join(_SCAN_ARRAYS)} come together, got only {', '.join(scans)}")
    for key in ("scan_counts", "scan_target"):
        if key in scans:
            if scans[key].dtype.kind not in "iu":
                raise ScenarioFileError(f"{path}: key {key!r} must hold whole numbers")
            scans[key] = scans[key].astype(np.int64)
    if "scan_returns" in scans:
        scans["scan_returns"] = scans["scan_returns"].astype(float)
    scn = ScenarioData(
        name=get("name", str),
        plant=get("plant", str),
        plant_params=params,
        measurement=get("measurement", str),
        ts=get("ts", float),
        seed=get("seed", int),
        lumped_var=get("lumped_var", float),
        linear_matrix=get("linear_matrix").astype(float) if "linear_matrix" in npz.files else None,
        # ScenarioData.roles is declared Array but defaults to None (filled in by __post_init__)
        roles=_roles(path, npz, arrays["sensors"].shape[0]) if "roles" in npz.files else None,  # type: ignore[arg-type]
        sensor_track=get("sensor_track").astype(float) if "sensor_track" in npz.files else None,
        **arrays,
        **scans,
    )
    return scn
