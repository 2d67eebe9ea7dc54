"""Scenario configuration files (TOML): reading, validation with precise errors, and conversion to a spec.

The catalogue of built-in files lives in ``deploy/scenarios/`` (installed as ``zentrack.scenarios``,
:mod:`zentrack.config.catalogue`); its scenarios are addressed by name (``zentrack scenarios`` lists them), any
other argument is a path. :func:`builtin_spec` is a catalogue scenario's spec, resized like ``--nodes`` and
``--steps`` resize it (:func:`resize`). Every error names the file, the key
(``section.key``) and what is allowed. The file fixes everything every process must agree on (plant,
sensors and their roles, noise, graph, initial estimate, filter, fusion rule, timing), so truth and every
node derive identical data.

Filters (``[filter] kind`` and its parameters) and fusion rules (``[fusion] rule`` and its parameters, e.g.
``rounds``) are looked up in their registries, so a plug-in's name and parameters are checked like the
built-ins'; a top-level ``plugins = ["package.module", ...]`` imports extra plug-in modules first.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from zentrack.common.argtypes import check_node_steps
from zentrack.common.limits import MAX_NODE_STEPS, MAX_NODES, MAX_SEED, MAX_STEPS, QBAR_RANGE, THETA_RANGE
from zentrack.config import catalogue
from zentrack.fusion.defaults import CENTRALIZED, DEFAULT_DEADLINE_FRAC, DEFAULT_FUSION, DEFAULT_QBAR
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.graphs import is_connected
from zentrack.fusion.models import PLANT_PARAMS
from zentrack.fusion.registry import load_plugins
from zentrack.fusion.rules import RULE_REGISTRY
from zentrack.transport.wire import MAX_RETURNS
from zentrack.truth.simulation.clutter import CLUTTER_MODES, ClutterSpec
from zentrack.truth.simulation.eot_scenario import extent_network, extent_truth
from zentrack.truth.simulation.scenario import (
    CONSENSUS_WEIGHTS,
    ExtentSpec,
    ScenarioData,
    ScenarioSpec,
    ring_sensor_positions,
)
from zentrack.truth.simulation.simulate import simulate

MODES = ("realtime", "lockstep")

# Bounds of every number a scenario can hold (TOML keys, the matching flags and .npz files): generous for any
# real tracker, tight enough that no value reaches a MemoryError, an overflow or a degenerate covariance. The
# counts (MAX_STEPS, MAX_NODES, MAX_RUNS, MAX_NODE_STEPS, MAX_SEED) and the filter's ranges, which flags share,
# are zentrack.common.limits'.
TS_RANGE = (1e-3, 3600.0)  # sample period, seconds
BOUNDS: dict[str, tuple[float, float]] = {
    # key: (low, high); both inclusive
    "plant.sigma_w": (1e-6, 1e4),  # process noise std (m/s^2-ish): Q = sigma_w^2 I
    "plant.alpha": (-1e4, 1e4),
    "plant.beta": (-1e4, 1e4),
    "plant.q": (1e-12, 1e8),  # process noise variance (exp1: Q = q I; cv3d-cd: diffusion intensity, m^2/s^3)
    "plant.em_steps": (1, 1000),  # cv3d-cd: Euler-Maruyama steps per scan period
    "plant.d_amp": (-1e6, 1e6),
    "plant.d_freq": (-1e6, 1e6),
    "sensors.radius": (1e-3, 1e7),  # metres
    "sensors.height": (-1e7, 1e7),
    "sensors.positions": (-1e7, 1e7),
    "measurement.noise_std": (1e-6, 1e6),  # radians for bearings (at most pi), metres or units otherwise
    "measurement.matrix": (-1e6, 1e6),
    "initial.x0": (-1e9, 1e9),
    "initial.p0_diag": (1e-12, 1e12),
    "initial.lumped_var": (1e-12, 1e12),
    "filter.qbar": QBAR_RANGE,
    "filter.theta": THETA_RANGE,
    "graph.self_weight": (1e-6, 1.0),
    "graph.link_prob": (1e-3, 1.0),
    "sensors.velocities": (-1e5, 1e5),  # m/s of moving sensor platforms
    "sensors.accelerations": (-1e3, 1e3),  # m/s^2
    "manoeuvre.times": (0.0, 1e9),  # seconds
    "plant.a_m": (-1e3, 1e3),  # ship-turn: acceleration along the track, m/s^2
    "plant.k_psi": (-1.0, 1.0),  # ship-turn: turn rate, rad/s
    "plant.power": (0.0, 1e9),  # ship-power: W
    "plant.eta": (1e-6, 1e6),  # ship-power: drag coefficient, kg/m
    "plant.mass": (1.0, 1e9),  # ship-power: kg
    "sensors.orbits": (-1e9, 1e9),
    "sensors.t_mid": (0.0, 1e7),  # s after the orbits' epoch
    "manoeuvre.accelerations": (-1e3, 1e3),  # m/s^2
    "clutter.detection_prob": (0.0, 1.0),
    "clutter.count": (0, MAX_RETURNS - 1),  # clutter returns per scan (fixed); the target's may come on top
    "clutter.density": (0.0, 1e6),  # returns per rad^2 (poisson)
}


class ScenarioConfigError(ValueError):
    """A scenario file is missing or invalid; the message names the file, the key and the allowed values."""


@dataclass
class RunConfig:
    """A validated scenario file."""

    source: str
    spec: ScenarioSpec
    seed: int
    ts: float
    filter_kind: str
    qbar: float
    theta: float | None
    mode: str
    deadline_frac: float
    ring: tuple[float, float] | None = None  # (radius, height) of a ring layout, to rebuild it for another N
    filter_params: dict[str, Any] = field(default_factory=dict)  # besides qbar/theta (validated by the registry)
    fusion: str = DEFAULT_FUSION
    fusion_params: dict[str, Any] = field(default_factory=dict)
    plugins: list[str] = field(default_factory=list)

    def scenario_data(self) -> ScenarioData:
        """The single run every process of a cluster derives from this file (deterministic in ``seed``)."""
        return simulate(self.spec, runs=1, seed=self.seed, ts=self.ts)


def builtin_names() -> list[str]:
    """The catalogue's scenario names (:func:`zentrack.config.catalogue.names`)."""
    return catalogue.names()


def resolve(name_or_path: str) -> tuple[str, str]:
    """Return ``(label, text)`` of a catalogue name or a file path."""
    if not catalogue.is_path(name_or_path):
        found = catalogue.text(name_or_path)
        if found is None:
            raise ScenarioConfigError(catalogue.unknown_scenario(name_or_path))
        return f"{name_or_path} (built-in)", found
    path = Path(name_or_path)
    try:
        return str(path), path.read_text()
    except OSError as exc:
        raise ScenarioConfigError(f"{path}: cannot read scenario file ({exc.strerror or exc})") from None


class _Reader:
    def __init__(self, label: str, doc: dict) -> None:
        self.label = label
        self.doc = doc

    def fail(self, key: str, msg: str) -> NoReturn:
        raise ScenarioConfigError(f"{self.label}: {key}: {msg}")

    def section(self, name: str) -> dict:
        sec = self.doc.get(name)
        if not isinstance(sec, dict):
            self.fail(name, "missing section [" + name + "]")
        return sec

    def get(self, section: str, key: str, kind: str, default: Any = None, choices: tuple = (), required: bool = True,
            bounds: tuple[float, float] | None = None):
        """The value of ``section.key`` checked against ``kind``, ``choices`` and ``bounds`` (default: the
        key's entry in :data:`BOUNDS`)."""
        full = f"{section}.{key}"
        value = self._get(section, key, kind, default, choices, required)
        lo, hi = bounds or BOUNDS.get(full) or (None, None)
        if lo is not None and value is not None and kind not in ("str", "int"):
            arr = np.asarray(value, dtype=float)
            if arr.size and not (np.all(arr >= lo) and np.all(arr <= hi)):
                self.fail(full, f"must be from {lo:g} to {hi:g}, got {_short(value)}")
        return value

    def _get(self, section: str, key: str, kind: str, default: Any, choices: tuple, required: bool):
        sec = self.section(section)
        full = f"{section}.{key}"
        if key not in sec:
            if required and default is None:
                self.fail(full, "missing" + (f" (allowed: {', '.join(map(str, choices))})" if choices else ""))
            return default
        v = sec[key]
        if kind == "str":
            if not isinstance(v, str):
                self.fail(full, f"must be a string, got {v!r}")
            if choices and v not in choices:
                self.fail(full, f"{v!r} is not allowed; choose one of {', '.join(choices)}")
            return v
        if kind == "int":
            if not isinstance(v, int) or isinstance(v, bool):
                self.fail(full, f"must be a whole number, got {v!r}")
            return v
        if kind in ("float", "positive"):
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                self.fail(full, f"must be a finite number, got {v!r}")
            if kind == "positive" and v <= 0:
                self.fail(full, f"must be positive, got {v!r}")
            return float(v)
        if kind == "vector":
            if not isinstance(v, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
                self.fail(full, f"must be a list of numbers, got {v!r}")
            a = np.array(v, dtype=float)
            if not np.all(np.isfinite(a)):
                self.fail(full, "must be finite")
            return a
        if kind == "matrix":
            if not isinstance(v, list) or not v or not all(isinstance(r, list) for r in v):
                self.fail(full, f"must be a list of rows, got {v!r}")
            try:
                a = np.array(v, dtype=float)
            except (TypeError, ValueError):
                self.fail(full, "rows must be lists of numbers of equal length")
            if a.ndim != 2 or not np.all(np.isfinite(a)):
                self.fail(full, "must be a finite matrix with rows of equal length")
            return a
        raise AssertionError(kind)


def _short(value: Any) -> str:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def parse(label: str, text: str) -> RunConfig:
    """Validate the TOML ``text`` (``label`` names it in errors)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioConfigError(f"{label}: not valid TOML ({exc})") from None
    except RecursionError:  # the parser recurses once per level of nested arrays or inline tables
        raise ScenarioConfigError(f"{label}: not valid TOML (arrays or inline tables nested too deeply)") from None
    r = _Reader(label, doc)
    known = {"scenario", "plant", "sensors", "measurement", "graph", "initial", "filter", "fusion", "timing",
             "plugins", "clutter", "manoeuvre", "extent"}
    for extra in sorted(set(doc) - known):
        r.fail(extra, f"unknown section; allowed: {', '.join(sorted(known))}")
    plugins = doc.get("plugins", [])
    if not isinstance(plugins, list) or not all(isinstance(m, str) and m for m in plugins):
        r.fail("plugins", f"must be a list of module names, got {plugins!r}")
    try:
        load_plugins(plugins)
    except ValueError as exc:
        r.fail("plugins", str(exc))
    name = r.get("scenario", "name", "str")
    r.get("scenario", "description", "str", default="", required=False)  # one line for `zentrack scenarios`
    plant = r.get("scenario", "plant", "str", choices=tuple(PLANT_PARAMS))
    steps = r.get("scenario", "steps", "int")
    if steps < 1:
        r.fail("scenario.steps", f"must be at least 1, got {steps}")
    if steps > MAX_STEPS:
        r.fail("scenario.steps", f"must be from 1 to {MAX_STEPS}, got {steps}")
    ts = r.get("scenario", "ts", "positive", bounds=TS_RANGE)
    seed = r.get("scenario", "seed", "int", default=0, required=False)
    if not 0 <= seed <= MAX_SEED:
        r.fail("scenario.seed", f"must be from 0 to 2**63 - 1, got {seed}")
    params = {}
    for key, _value in r.section("plant").items():
        if key not in PLANT_PARAMS[plant]:
            r.fail(f"plant.{key}", f"not a parameter of plant {plant!r}; allowed: {', '.join(PLANT_PARAMS[plant])}")
        params[key] = r.get("plant", key, "int" if key == "em_steps" else "float")
        if key == "em_steps" and not BOUNDS["plant.em_steps"][0] <= params[key] <= BOUNDS["plant.em_steps"][1]:
            r.fail("plant.em_steps", f"must be from 1 to {BOUNDS['plant.em_steps'][1]:g}, got {params[key]}")
    kind = r.get("measurement", "kind", "str", choices=("bearing", "point", "linear", "extent-ellipse", "extent-rectangle"))
    if (kind == "linear") != (plant == "exp1"):
        r.fail("measurement.kind", f"{kind!r} does not fit plant {plant!r} (exp1 takes linear; cv3d bearing or point)")
    if kind.startswith("extent-") != (plant == "eot"):
        r.fail("measurement.kind", f"{kind!r} does not fit plant {plant!r} (eot takes extent-ellipse or extent-rectangle)")
    noise_bounds = (BOUNDS["measurement.noise_std"][0], math.pi) if kind == "bearing" else None
    if "noise_stds" in r.section("measurement"):  # one level per sensor
        if "noise_std" in r.section("measurement"):
            r.fail("measurement.noise_stds", "give noise_std (every sensor) or noise_stds (one per sensor), not both")
        noise_stds = r.get("measurement", "noise_stds", "vector", bounds=noise_bounds or BOUNDS["measurement.noise_std"])
        if np.any(noise_stds <= 0):
            r.fail("measurement.noise_stds", f"must be positive, got {_short(noise_stds)}")
        noise_std = float(noise_stds[0]) if noise_stds.size else 1.0
    elif plant == "eot":  # the noise of the points is [extent] noise_diag
        noise_stds, noise_std = None, 1.0
    else:
        noise_stds = None
        noise_std = r.get("measurement", "noise_std", "positive", bounds=noise_bounds)
    linear = r.get("measurement", "matrix", "matrix") if kind == "linear" else None
    if linear is not None and not 1 <= linear.shape[0] <= 10:
        r.fail("measurement.matrix", f"must have 1 to 10 rows, got {linear.shape[0]}")
    count = r.get("sensors", "count", "int")
    if not 1 <= count <= MAX_NODES:
        r.fail("sensors.count", f"must be from 1 to {MAX_NODES}, got {count}")
    if steps * count > MAX_NODE_STEPS:
        r.fail("scenario.steps", f"{steps} steps x {count} sensors is more than {MAX_NODE_STEPS} node-steps; "
               "use fewer steps or sensors")
    layout = r.get("sensors", "layout", "str", choices=("ring", "explicit", "orbits", "none", "placed"))
    if (layout == "placed") != (plant == "eot"):
        r.fail("sensors.layout", "an extended object (plant eot) takes layout = \"placed\", and only it does")
    ring = None
    orbital: dict = {}
    if layout == "placed":  # placed with the extended object's network below
        sensors = np.zeros((count, 3))
    elif layout == "orbits":
        orbital = _orbits(r, count, steps, ts)
        sensors = orbital.pop("initial")
    elif layout == "ring":
        ring = (r.get("sensors", "radius", "positive"), r.get("sensors", "height", "float", default=0.0, required=False))
        sensors = ring_sensor_positions(count, *ring)
    elif layout == "explicit":
        sensors = r.get("sensors", "positions", "matrix")
        if sensors.shape != (count, 3):
            r.fail("sensors.positions", f"must be {count} rows of [x, y, z], got shape {list(sensors.shape)}")
    else:
        if kind != "linear":
            r.fail("sensors.layout", "'none' only fits linear measurements; use ring or explicit")
        sensors = np.zeros((count, 3))
    if noise_stds is not None and noise_stds.shape != (count,):
        r.fail("measurement.noise_stds", f"must have one entry per sensor ({count}), got {noise_stds.size}")
    motion = {}
    for key in ("velocities", "accelerations"):
        if key in r.section("sensors"):
            if layout != "explicit":
                r.fail(f"sensors.{key}", "moving sensors need layout = \"explicit\"")
            value = r.get("sensors", key, "matrix")
            if value.shape != (count, 3):
                r.fail(f"sensors.{key}", f"must be {count} rows of [x, y, z], got shape {list(value.shape)}")
            motion[key] = value
    relays = r.section("sensors").get("relays", [])
    if not isinstance(relays, list) or not all(isinstance(j, int) and not isinstance(j, bool) for j in relays) \
            or any(not 0 <= j < count for j in relays) or len(set(relays)) != len(relays):
        r.fail("sensors.relays", f"must be a list of distinct node indices from 0 to {count - 1}, got {relays!r}")
    if len(relays) == count:
        r.fail("sensors.relays", "at least one node must be a sensor")
    roles = ["relay" if j in relays else "sensor" for j in range(count)] if relays else None
    graph = r.get("graph", "kind", "str", choices=("ring", "metropolis-ring", "explicit", "random", "placed"))
    if (graph == "placed") != (layout == "placed"):
        r.fail("graph.kind", "graph kind \"placed\" (links within [extent] link_range) goes with layout \"placed\"")
    self_weight = r.get("graph", "self_weight", "positive", default=0.5, required=False)
    extent = _extent(r, count) if plant == "eot" else None
    if "extent" in doc and extent is None:
        r.fail("extent", "only an extended object (plant eot) takes an [extent] section")
    adjacency, consensus_weights = (None, "metropolis") if graph == "placed" else _graph(r, graph, count)
    if adjacency is not None:
        graph = "explicit"
    n = {"exp1": 2, "ca9": 9, "ship-turn": 5, "ship-power": 5, "eot": 7}.get(plant, 6)
    if plant == "eot":  # the truth is the paper's path: its first state is where the prior is centred
        if "x0" in r.section("initial"):
            r.fail("initial.x0", "an extended object's initial state is the start of its path; give p0_diag only")
        x0 = np.zeros(n)
    else:
        x0 = r.get("initial", "x0", "vector")
    if x0.shape != (n,):
        r.fail("initial.x0", f"must have {n} entries for plant {plant!r}, got {x0.size}")
    p0_diag = r.get("initial", "p0_diag", "vector", bounds=(-math.inf, math.inf))
    lo, hi = BOUNDS["initial.p0_diag"]
    if p0_diag.shape != (n,) or not np.all((p0_diag >= lo) & (p0_diag <= hi)):
        r.fail("initial.p0_diag", f"must be {n} positive numbers from {lo:g} to {hi:g}, got {_short(p0_diag)}")
    if linear is not None and linear.shape[1] != n:
        r.fail("measurement.matrix", f"must have {n} columns for plant {plant!r}")
    lumped_var = r.get("initial", "lumped_var", "positive", default=1.0, required=False)
    filter_kind = r.get("filter", "kind", "str", choices=FILTER_REGISTRY.names())
    qbar = r.get("filter", "qbar", "positive", default=DEFAULT_QBAR, required=False)
    filter_params = {k: v for k, v in r.section("filter").items() if k not in ("kind", "qbar", "theta")}
    known_params = {p.name for p in FILTER_REGISTRY.params(filter_kind)}
    for key in ("qbar", "theta"):
        if key in r.section("filter") and key not in known_params:
            r.fail(f"filter.{key}", f"not a parameter of filter {filter_kind!r}")
    try:
        FILTER_REGISTRY.validate(filter_kind, filter_params)
    except ValueError as exc:
        r.fail("filter", str(exc))
    fusion_sec = doc.get("fusion", {"rule": DEFAULT_FUSION})
    if not isinstance(fusion_sec, dict):
        r.fail("fusion", "must be a table")
    doc["fusion"] = fusion_sec
    fusion = r.get("fusion", "rule", "str", default=DEFAULT_FUSION, required=False,
                   choices=(*RULE_REGISTRY.names(), CENTRALIZED))
    fusion_params = {k: v for k, v in fusion_sec.items() if k != "rule"}
    if fusion == CENTRALIZED and fusion_params:
        r.fail("fusion", f"the centralized filter takes no fusion parameters, got {', '.join(sorted(fusion_params))}")
    try:
        fusion_params = fusion_params if fusion == CENTRALIZED else RULE_REGISTRY.validate(fusion, fusion_params)
    except ValueError as exc:
        r.fail("fusion", str(exc))
    theta_raw = r.section("filter").get("theta", "auto")
    if theta_raw == "auto":
        theta = None
    elif isinstance(theta_raw, (int, float)) and not isinstance(theta_raw, bool) and theta_raw > 0 and math.isfinite(theta_raw):
        theta = r.get("filter", "theta", "positive")
    else:
        r.fail("filter.theta", f'must be "auto" or a positive number, got {theta_raw!r}')
    mode = r.get("timing", "mode", "str", choices=MODES)
    deadline_frac = r.get("timing", "deadline_frac", "positive", default=DEFAULT_DEADLINE_FRAC, required=False)
    if not 0 < deadline_frac < 1:
        r.fail("timing.deadline_frac", f"must be between 0 and 1 (exclusive), got {deadline_frac}")
    clutter = _clutter(r, count, kind) if "clutter" in doc else None
    schedule = _manoeuvre(r, plant, steps * ts) if "manoeuvre" in doc else None
    spec = ScenarioSpec(
        name=name, plant=plant, plant_params=params, measurement=kind, noise_std=noise_std, sensors=sensors,
        x0=x0, p0=np.diag(p0_diag), steps=steps, lumped_var=lumped_var, linear_matrix=linear, graph=graph,
        self_weight=self_weight, roles=roles, clutter=clutter, noise_stds=noise_stds,
        sensor_velocity=motion.get("velocities"), sensor_accel=motion.get("accelerations"), adjacency=adjacency,
        consensus_weights=consensus_weights, accel_schedule=schedule, extent=extent, **orbital,
    )
    if extent is not None:
        _place_extent_network(r, spec, ts)
    try:
        spec.validate()
    except ValueError as exc:
        r.fail("scenario", str(exc))
    return RunConfig(label, spec, seed, ts, filter_kind, qbar, theta, mode, deadline_frac, ring,
                     filter_params=filter_params, fusion=fusion, fusion_params=fusion_params, plugins=plugins)


def _extent(r: _Reader, nodes: int) -> ExtentSpec:
    """``[extent]`` (seed 004): the object (semi_axes, speed), its points (rate, max_points, noise_diag) and
    the network (sensors, link_range, network_seed)."""
    known = {"semi_axes", "speed", "rate", "max_points", "noise_diag", "sensors", "link_range", "network_seed"}
    for key in sorted(set(r.section("extent")) - known):
        r.fail(f"extent.{key}", f"unknown key; allowed: {', '.join(sorted(known))}")
    axes = r.get("extent", "semi_axes", "vector")
    noise = r.get("extent", "noise_diag", "vector")
    if axes.shape != (2,):
        r.fail("extent.semi_axes", f"must be two semi-axes [l1, l2], got {_short(axes)}")
    if noise.shape != (2,):
        r.fail("extent.noise_diag", f"must be two variances (the diagonal of C^v), got {_short(noise)}")
    max_points = r.get("extent", "max_points", "int", default=40, required=False)
    if not 1 <= max_points <= MAX_RETURNS:
        r.fail("extent.max_points", f"must be from 1 to {MAX_RETURNS}, got {max_points}")
    spec = ExtentSpec(
        semi_axes=(float(axes[0]), float(axes[1])), speed=r.get("extent", "speed", "positive", default=500 / 36,
                                                                 required=False),
        rate=r.get("extent", "rate", "positive"), max_points=max_points, noise_diag=(float(noise[0]), float(noise[1])),
        sensors=r.get("extent", "sensors", "int"), link_range=r.get("extent", "link_range", "positive"),
        network_seed=r.get("extent", "network_seed", "int", default=0, required=False))
    try:
        spec.validate(nodes)
    except ValueError as exc:
        r.fail("extent", str(exc))
    return spec


def _place_extent_network(r: _Reader, spec: ScenarioSpec, ts: float) -> None:
    """Place the extended-object network into ``spec``: positions, relays and the links within range."""
    try:
        positions, roles, adjacency = extent_network(spec, ts)
    except ValueError as exc:
        r.fail("extent", str(exc))
    spec.sensors, spec.roles, spec.adjacency, spec.graph = positions, roles.tolist(), adjacency, "explicit"
    spec.x0 = extent_truth(spec, ts)[0]


def _graph(r: _Reader, kind: str, nodes: int) -> tuple[np.ndarray | None, str]:
    """An explicit graph (``edges``) or a random one (``link_prob``, ``diameter``, ``seed``: redrawn from that
    seed until connected with that diameter), and its consensus weights; ``(None, ...)`` for the rings."""
    weights = r.get("graph", "weights", "str", default="metropolis", required=False, choices=CONSENSUS_WEIGHTS)
    if kind in ("ring", "metropolis-ring"):
        if "weights" in r.section("graph"):
            r.fail("graph.weights", "rings have their own weights; consensus weights need an explicit or random graph")
        return None, "metropolis"
    if kind == "explicit":
        edges = r.get("graph", "edges", "matrix")
        if edges.shape[1:] != (2,) or np.any(edges != np.round(edges)) or np.any((edges < 0) | (edges >= nodes)) \
                or np.any(edges[:, 0] == edges[:, 1]):
            r.fail("graph.edges", f"must be pairs [i, j] of distinct node indices from 0 to {nodes - 1}")
        adj = np.zeros((nodes, nodes), dtype=bool)
        adj[edges[:, 0].astype(int), edges[:, 1].astype(int)] = True
        adj |= adj.T
    else:
        from zentrack.fusion.consensus import random_graph

        p = r.get("graph", "link_prob", "positive")
        diameter = r.get("graph", "diameter", "int", default=0, required=False)
        seed = r.get("graph", "seed", "int", default=0, required=False)
        try:
            adj = random_graph(nodes, p, np.random.default_rng(seed), diameter=diameter or None)
        except ValueError as exc:
            r.fail("graph", str(exc))
    if not is_connected(adj):
        r.fail("graph", "the communication graph is not connected: some nodes can never share information")
    return adj, weights


def _orbits(r: _Reader, count: int, steps: int, ts: float) -> dict:
    """``layout = "orbits"`` (seed 003): one satellite per node, ``orbits = [[a_km, e, i_deg, raan_deg, argp_deg,
    m0_deg], ...]``; the ENU origin (the target's start) lies under satellite ``site_under``'s ground track at
    ``t_mid`` s after the epoch, ``cross_track_km`` to its side; the steps are centred on ``t_mid``."""
    from zentrack.truth.simulation.orbit import KeplerOrbit, sensor_track_enu, ship_under_ground_track

    rows = r.get("sensors", "orbits", "matrix")
    if rows.shape != (count, 6):
        r.fail("sensors.orbits", f"must be {count} rows of [a_km, e, i_deg, raan_deg, argp_deg, m0_deg]")
    if np.any(rows[:, 0] < 6378.137 + 100) or np.any((rows[:, 1] < 0) | (rows[:, 1] >= 1)):
        r.fail("sensors.orbits", "a must be above the atmosphere (> 6478 km) and 0 <= e < 1")
    orbits = [KeplerOrbit(a * 1e3, e, *np.radians([i, raan, argp, m0])) for a, e, i, raan, argp, m0 in rows]
    under = r.get("sensors", "site_under", "int", default=0, required=False)
    if not 0 <= under < count:
        r.fail("sensors.site_under", f"must be a satellite index from 0 to {count - 1}, got {under}")
    t_mid = r.get("sensors", "t_mid", "float", default=30.0, required=False)
    side = r.get("sensors", "cross_track_km", "float", default=0.0, required=False, bounds=(-3000.0, 3000.0))
    gmst0 = float(np.radians(r.get("sensors", "gmst0_deg", "float", default=0.0, required=False, bounds=(-360, 360))))
    lat, lon = ship_under_ground_track(orbits[under], t_mid, gmst0, side * 1e3)
    t0 = t_mid - (steps - 1) * ts / 2
    initial = np.stack([sensor_track_enu(o, np.array([t0]), float(lat), float(lon), 0.0, gmst0)[0] for o in orbits])
    if np.any(initial[:, 2] <= 0):
        r.fail("sensors.orbits", "a satellite is below the horizon of the site at the first step")
    return {"initial": initial, "orbits": orbits, "site": (float(lat), float(lon)), "orbit_t0": float(t0),
            "gmst0": gmst0}


def _manoeuvre(r: _Reader, plant: str, duration: float) -> list[tuple[float, list[float]]]:
    """``[manoeuvre]``: the target's acceleration set to ``accelerations[j]`` from ``times[j]`` on (ca9)."""
    if plant != "ca9":
        r.fail("manoeuvre", f"an acceleration schedule needs plant = \"ca9\", not {plant!r}")
    times = r.get("manoeuvre", "times", "vector")
    accels = r.get("manoeuvre", "accelerations", "matrix")
    if times.ndim != 1 or not times.size or np.any(np.diff(times) <= 0) or times[0] > duration:
        r.fail("manoeuvre.times", f"must be increasing start times within the run (0 to {duration:g} s)")
    if accels.shape != (times.size, 3):
        r.fail("manoeuvre.accelerations", f"must be {times.size} rows of [ax, ay, az], got shape {list(accels.shape)}")
    return [(float(t), a.tolist()) for t, a in zip(times, accels)]


def _clutter(r: _Reader, sensors: int, kind: str) -> ClutterSpec:
    """The ``[clutter]`` table (seed 001): detection probability and uniform clutter per sensor and scan, over
    an (azimuth, elevation) window in radians, ``[lo, hi]`` for every sensor or one ``[lo, hi]`` row each."""
    if kind != "bearing":
        r.fail("clutter", f"clutter needs bearing measurements, got {kind!r}")
    mode = r.get("clutter", "mode", "str", choices=CLUTTER_MODES)
    p_d = r.get("clutter", "detection_prob", "float", default=1.0, required=False)
    count = r.get("clutter", "count", "int", default=0, required=mode == "fixed")
    lo, hi = BOUNDS["clutter.count"]
    if not lo <= count <= hi:
        r.fail("clutter.count", f"must be from {lo:g} to {hi:g}, got {count}")
    density = r.get("clutter", "density", "float", default=0.0, required=mode == "poisson")
    windows = {}
    for key, limit in (("az_window", 2 * math.pi), ("el_window", math.pi / 2)):
        raw = r.section("clutter").get(key)
        w = np.asarray(r.get("clutter", key, "matrix" if isinstance(raw, list) and raw and isinstance(raw[0], list)
                             else "vector"), dtype=float)
        if w.shape not in ((2,), (sensors, 2)) or np.any(w[..., 1] <= w[..., 0]) or np.any(np.abs(w) > limit):
            r.fail(f"clutter.{key}", f"must be [lo, hi] (radians, lo < hi, |.| <= {limit:.4g}) or one such row "
                   f"per sensor ({sensors}), got {_short(w)}")
        windows[key] = w
    spec = ClutterSpec(p_d=p_d, mode=mode, count=count, density=density, **windows)
    mean = float(np.max(spec.mean_clutter(sensors)))
    if mode == "poisson" and mean > (MAX_RETURNS - 1) / 2:
        r.fail("clutter.density", f"{mean:.0f} clutter returns per scan on average; a scan holds at most "
               f"{MAX_RETURNS} returns")
    return spec


def load_scenario_config(name_or_path: str) -> RunConfig:
    """Read and validate a scenario file by catalogue name or path."""
    return parse(*resolve(name_or_path))


def resize(cfg: RunConfig, nodes: int | None = None, steps: int | None = None) -> RunConfig:
    """``cfg`` with ``nodes`` trackers and ``steps`` steps (None: the file's), in place: a ring is rebuilt for N
    and sensors without geometry (linear measurements) repeated; explicit positions, orbits, placed networks and
    relays fix N (ValueError naming the scenario)."""
    spec = cfg.spec
    if nodes and nodes != spec.nodes:
        if spec.roles is not None:
            raise ValueError(f"{cfg.source}: --nodes cannot resize a scenario with relay nodes (N = {spec.nodes})")
        if spec.measurement == "linear":
            spec.sensors = np.zeros((nodes, 3))
        elif cfg.ring is not None:
            spec.sensors = ring_sensor_positions(nodes, *cfg.ring)
        else:
            raise ValueError(f"{cfg.source}: --nodes needs a ring layout; explicit sensors fix N = {spec.nodes}")
    if steps:
        spec.steps = steps
    if nodes or steps:
        check_node_steps(1, spec.steps, spec.nodes, f"{cfg.source}: --steps x --nodes")
    return cfg


def builtin_spec(name: str, nodes: int | None = None, steps: int | None = None) -> ScenarioSpec:
    """Catalogue scenario ``name``'s spec (or a TOML path's), optionally with another node count or length."""
    return resize(load_scenario_config(name), nodes, steps).spec
