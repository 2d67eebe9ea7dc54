"""A scenario file's TOML text to a validated :class:`RunConfig`: :func:`parse`, one part per group of sections.

The file fixes everything every process must agree on (plant, sensors and their roles, noise, graph, initial
estimate, filter, fusion rule, timing), so truth and every node derive identical data. Filters (``[filter]
kind`` and its parameters) and fusion rules (``[fusion] rule`` and its parameters, e.g. ``rounds``) are looked
up in their registries, so a plug-in's name and parameters are checked like the built-ins'; a top-level
``plugins = ["package.module", ...]`` imports extra plug-in modules first. Every error is one line naming the
file and the key (:class:`~zentrack.config.scenario_reader.ScenarioReader`).
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from zentrack.common.limits import MAX_NODE_STEPS, MAX_NODES, MAX_SEED, MAX_STEPS
from zentrack.common.suggest import did_you_mean, with_hint
from zentrack.config.scenario_kinds import check_network_kinds
from zentrack.config.scenario_multitarget import (
    is_multitarget,
    multitarget_section,
    not_single_target,
    tracker_section,
)
from zentrack.config.scenario_reader import BOUNDS, MODES, TS_RANGE, ScenarioConfigError, ScenarioReader, short
from zentrack.config.scenario_schema import check_keys
from zentrack.config.scenario_sections import (
    clutter_section,
    extent_section,
    graph_section,
    manoeuvre_section,
    orbits_section,
    place_extent_network,
)
from zentrack.config.scenario_sensor_timing import SensorTiming, asynchronous_refusal, sensor_timing_section
from zentrack.config.scenario_trajectory import trajectory_section
from zentrack.fusion.defaults import (
    CENTRALIZED,
    DEFAULT_DEADLINE_FRAC,
    DEFAULT_FUSION,
    DEFAULT_QBAR,
)
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.models import PLANT_PARAMS
from zentrack.fusion.registry import load_plugins
from zentrack.fusion.rules import RULE_REGISTRY
from zentrack.truth.simulation.multitarget import MultiTargetData, MultiTargetSpec, simulate_multitarget
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.scenario_spec import ScenarioSpec, ring_sensor_positions
from zentrack.truth.simulation.simulate import simulate

#: the sections a scenario file may have
SECTIONS = ("scenario", "plant", "sensors", "measurement", "graph", "initial", "filter", "fusion", "timing",
            "plugins", "clutter", "manoeuvre", "extent", "targets", "sensing", "trajectory", "sensor_timing",
            "tracker")
#: the state dimension of each plant (6 for the others: position and velocity)
STATE_DIM = {"exp1": 2, "ca9": 9, "ship-turn": 5, "ship-power": 5, "eot": 7}


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
    #: the targets and sensing of a many-target scenario (``[targets]``, ``[sensing]``); None: one target
    multitarget: MultiTargetSpec | None = None
    #: sensors of their own (``[sensor_timing]``, issue 52); None: the truth measures every step
    sensor_timing: SensorTiming | None = None
    #: many targets: each node's tracker (``[tracker] kind``: gnn or pmbm), and whether point sensors' nodes share
    #: their scans (``[tracker] share_scans``; None: the tracker's default, :func:`shares_scans`)
    tracker: str = "gnn"
    share_scans: bool | None = None

    def scenario_data(self) -> ScenarioData:
        """The single run every process of a cluster derives from this file (deterministic in ``seed``)."""
        if self.multitarget is not None:
            raise ScenarioConfigError(not_single_target(self.source))
        return simulate(self.spec, runs=1, seed=self.seed, ts=self.ts)

    def multitarget_data(self, seed: int | None = None) -> MultiTargetData:
        """One run of a many-target scenario (seed: the file's unless given)."""
        if self.multitarget is None:
            raise ScenarioConfigError(f"{self.source}: not a many-target scenario (it has no [targets] section)")
        return simulate_multitarget(self.spec, self.multitarget, self.seed if seed is None else seed, self.ts)


def parse(label: str, text: str) -> RunConfig:
    """Validate the TOML ``text`` (``label`` names it in errors)."""
    r, plugins = _document(label, text)
    name, plant, steps, ts, seed, params = _header(r)
    kind, noise_std, noise_stds, linear = _measurement(r, plant)
    many = multitarget_section(r, plant, kind, steps, ts) if is_multitarget(r.doc) else None
    trajectory = trajectory_section(r, plant, ts) if "trajectory" in r.doc else None
    count, sensors, ring, orbital, motion, roles = _sensors(r, plant, kind, steps, ts, noise_stds)
    graph = r.get("graph", "kind", "str", choices=("ring", "metropolis-ring", "explicit", "random", "placed"))
    if (graph == "placed") != (sensors is None):
        r.fail("graph.kind", "graph kind \"placed\" (links within [extent] link_range) goes with layout \"placed\"")
    self_weight = r.get("graph", "self_weight", "positive", default=0.5, required=False)
    extent = extent_section(r, count) if plant == "eot" else None
    if "extent" in r.doc and extent is None:
        r.fail("extent", "only an extended object (plant eot) takes an [extent] section")
    adjacency, consensus_weights = (None, "metropolis") if graph == "placed" else graph_section(r, graph, count)
    if adjacency is not None:
        graph = "explicit"
    x0, p0_diag, lumped_var = _initial(r, plant, linear, many, trajectory is not None)
    filter_kind, qbar, filter_params, fusion, fusion_params, theta = _filter_and_fusion(r)
    mode = r.get("timing", "mode", "str", choices=MODES)
    deadline_frac = r.get("timing", "deadline_frac", "positive", default=DEFAULT_DEADLINE_FRAC, required=False)
    if not 0 < deadline_frac < 1:
        r.fail("timing.deadline_frac", f"must be between 0 and 1 (exclusive), got {deadline_frac}")
    clutter = clutter_section(r, count, kind) if "clutter" in r.doc else None
    schedule = manoeuvre_section(r, plant, steps * ts) if "manoeuvre" in r.doc else None
    spec = ScenarioSpec(
        name=name, plant=plant, plant_params=params, measurement=kind, noise_std=noise_std,
        sensors=np.zeros((count, 3)) if sensors is None else sensors,
        x0=x0, p0=np.diag(p0_diag), steps=steps, lumped_var=lumped_var, linear_matrix=linear, graph=graph,
        self_weight=self_weight, roles=roles, clutter=clutter, noise_stds=noise_stds,
        sensor_velocity=motion.get("velocities"), sensor_accel=motion.get("accelerations"), adjacency=adjacency,
        consensus_weights=consensus_weights, accel_schedule=schedule, extent=extent, trajectory=trajectory,
        **orbital,
    )
    if extent is not None:
        place_extent_network(r, spec, ts)
    try:
        spec.validate()
    except ValueError as exc:
        r.fail("scenario", str(exc))
    if many is not None:
        check_network_kinds(r, spec, many)
    elif "kinds" in r.section("sensors"):
        r.fail("sensors.kinds", "only a many-target scenario ([targets]) mixes sensor kinds")
    timing = None
    if "sensor_timing" in r.doc:
        timing = sensor_timing_section(label, r.doc["sensor_timing"], spec.nodes, ts, r.fail)
        why = asynchronous_refusal(mode, fusion, fusion_params, spec, many)
        if why is not None:
            r.fail("sensor_timing", why)
    tracker, share_scans = tracker_section(r, kind, many, spec.nodes, timing is not None)
    return RunConfig(label, spec, seed, ts, filter_kind, qbar, theta, mode, deadline_frac, ring,
                     filter_params=filter_params, fusion=fusion, fusion_params=fusion_params, plugins=plugins,
                     multitarget=many, sensor_timing=timing, tracker=tracker, share_scans=share_scans)


def _document(label: str, text: str) -> tuple[ScenarioReader, list[str]]:
    """The TOML document (its sections known) and its plug-in modules, imported."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioConfigError(f"{label}: not valid TOML ({exc})") from None
    except RecursionError:  # the parser recurses once per level of nested arrays or inline tables
        raise ScenarioConfigError(f"{label}: not valid TOML (arrays or inline tables nested too deeply)") from None
    r = ScenarioReader(label, doc)
    for extra in sorted(set(doc) - set(SECTIONS)):
        r.fail(extra, f"unknown section{did_you_mean(extra, SECTIONS) or '; allowed: ' + ', '.join(sorted(SECTIONS))}")
    check_keys(doc, r.fail)
    plugins = doc.get("plugins", [])
    if not isinstance(plugins, list) or not all(isinstance(m, str) and m for m in plugins):
        r.fail("plugins", f"must be a list of module names, got {plugins!r}")
    try:
        load_plugins(plugins)
    except ValueError as exc:
        r.fail("plugins", str(exc))
    return r, plugins


def _header(r: ScenarioReader) -> tuple[str, str, int, float, int, dict[str, float]]:
    """``[scenario]`` (name, plant, steps, ts, seed) and ``[plant]``'s parameters."""
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
            r.fail(f"plant.{key}", f"not a parameter of plant {plant!r}{did_you_mean(key, PLANT_PARAMS[plant])}; "
                   f"allowed: {', '.join(PLANT_PARAMS[plant]) or 'none'}")
        params[key] = r.get("plant", key, "int" if key == "em_steps" else "float")
        if key == "em_steps" and not BOUNDS["plant.em_steps"][0] <= params[key] <= BOUNDS["plant.em_steps"][1]:
            r.fail("plant.em_steps", f"must be from 1 to {BOUNDS['plant.em_steps'][1]:g}, got {params[key]}")
    return name, plant, steps, ts, seed, params


def _measurement(r: ScenarioReader, plant: str) -> tuple[str, float, np.ndarray | None, np.ndarray | None]:
    """``[measurement]``: the kind (fitting the plant), the noise level(s) and a linear model's matrix."""
    kind = r.get("measurement", "kind", "str", choices=("bearing", "point", "linear", "extent-ellipse", "extent-rectangle"))
    if (kind == "linear") != (plant == "exp1"):
        r.fail("measurement.kind", f"{kind!r} does not fit plant {plant!r} (exp1 takes linear; cv3d bearing or point)")
    if kind.startswith("extent-") != (plant == "eot"):
        r.fail("measurement.kind", f"{kind!r} does not fit plant {plant!r} (eot takes extent-ellipse or extent-rectangle)")
    mixed = "kinds" in r.doc.get("sensors", {})  # each sensor's noise in its own kind's unit (scenario_kinds)
    noise_bounds = (BOUNDS["measurement.noise_std"][0], math.pi) if kind == "bearing" and not mixed else None
    if "noise_stds" in r.section("measurement"):  # one level per sensor
        if "noise_std" in r.section("measurement"):
            r.fail("measurement.noise_stds", "give noise_std (every sensor) or noise_stds (one per sensor), not both")
        noise_stds = r.get("measurement", "noise_stds", "vector", bounds=noise_bounds or BOUNDS["measurement.noise_std"])
        if np.any(noise_stds <= 0):
            r.fail("measurement.noise_stds", f"must be positive, got {short(noise_stds)}")
        noise_std = float(noise_stds[0]) if noise_stds.size else 1.0
    elif plant == "eot":  # the noise of the points is [extent] noise_diag
        noise_stds, noise_std = None, 1.0
    else:
        noise_stds = None
        noise_std = r.get("measurement", "noise_std", "positive", bounds=noise_bounds)
    linear = r.get("measurement", "matrix", "matrix") if kind == "linear" else None
    if linear is not None and not 1 <= linear.shape[0] <= 10:
        r.fail("measurement.matrix", f"must have 1 to 10 rows, got {linear.shape[0]}")
    return kind, noise_std, noise_stds, linear


def _sensors(r: ScenarioReader, plant: str, kind: str, steps: int, ts: float, noise_stds: np.ndarray | None):
    """``[sensors]``: the count, the positions of the layout (None: placed later with an extended object's
    network), a ring's (radius, height), orbits, moving platforms and relay roles."""
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
    sensors: np.ndarray | None
    if layout == "placed":  # placed with the extended object's network
        sensors = None
    elif layout == "orbits":
        orbital = orbits_section(r, count, steps, ts)
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
    return count, sensors, ring, orbital, motion, roles


def _initial(r: ScenarioReader, plant: str, linear: np.ndarray | None, many: MultiTargetSpec | None,
             recorded: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """``[initial]``: the initial state x0, the diagonal of P0 and the lumped states' variance. Many targets have
    no one initial state: x0 is then their ``centre`` at rest (P0 is the covariance a new track starts with); a
    recorded ``[trajectory]``'s is its state at step 0 (x0 is a placeholder the simulation does not use)."""
    n = STATE_DIM.get(plant, 6)
    if many is not None:
        x0 = np.concatenate([many.targets.centre, np.zeros(3)])
    elif recorded:  # trajectory_section refused an x0
        x0 = np.zeros(n)
    elif plant == "eot":  # the truth is the paper's path: its first state is where the prior is centred
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
        r.fail("initial.p0_diag", f"must be {n} positive numbers from {lo:g} to {hi:g}, got {short(p0_diag)}")
    if linear is not None and linear.shape[1] != n:
        r.fail("measurement.matrix", f"must have {n} columns for plant {plant!r}")
    lumped_var = r.get("initial", "lumped_var", "positive", default=1.0, required=False)
    return x0, p0_diag, lumped_var


def _filter_and_fusion(r: ScenarioReader):
    """``[filter]`` (kind, qbar, theta and the filter's own parameters) and ``[fusion]`` (rule and parameters),
    checked against their registries."""
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
        r.fail("filter", with_hint(exc))
    fusion_sec = r.doc.get("fusion", {"rule": DEFAULT_FUSION})
    if not isinstance(fusion_sec, dict):
        r.fail("fusion", "must be a table")
    r.doc["fusion"] = fusion_sec
    fusion = r.get("fusion", "rule", "str", default=DEFAULT_FUSION, required=False,
                   choices=(*RULE_REGISTRY.names(), CENTRALIZED))
    fusion_params = {k: v for k, v in fusion_sec.items() if k != "rule"}
    if fusion == CENTRALIZED and fusion_params:
        r.fail("fusion", f"the centralized filter takes no fusion parameters, got {', '.join(sorted(fusion_params))}")
    try:
        fusion_params = fusion_params if fusion == CENTRALIZED else RULE_REGISTRY.validate(fusion, fusion_params)
    except ValueError as exc:
        r.fail("fusion", with_hint(exc))
    theta_raw = r.section("filter").get("theta", "auto")
    if theta_raw == "auto":
        theta = None
    elif isinstance(theta_raw, (int, float)) and not isinstance(theta_raw, bool) and theta_raw > 0 and math.isfinite(theta_raw):
        theta = r.get("filter", "theta", "positive")
    else:
        r.fail("filter.theta", f'must be "auto" or a positive number, got {theta_raw!r}')
    return filter_kind, qbar, filter_params, fusion, fusion_params, theta
