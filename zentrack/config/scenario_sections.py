"""The optional and layout-specific sections of a scenario file: the communication graph (``[graph]`` explicit
or random), satellites on orbits (``[sensors] layout = "orbits"``), the extended object (``[extent]``), the
target's acceleration schedule (``[manoeuvre]``) and paper 1's clutter (``[clutter]``).

Each parser reads through a :class:`~zentrack.config.scenario_reader.ScenarioReader` and fails with one line
naming the key; :func:`zentrack.config.scenario_parse.parse` calls them.
"""
from __future__ import annotations

import math

import numpy as np

from zentrack.config.scenario_reader import BOUNDS, ScenarioReader, short
from zentrack.fusion.graphs import is_connected
from zentrack.transport.wire import MAX_RETURNS
from zentrack.truth.simulation.clutter import CLUTTER_MODES, ClutterSpec
from zentrack.truth.simulation.eot_scenario import extent_network, extent_truth
from zentrack.truth.simulation.scenario_spec import CONSENSUS_WEIGHTS, ExtentSpec, ScenarioSpec


def extent_section(r: ScenarioReader, nodes: int) -> ExtentSpec:
    """``[extent]`` (paper 4): the object (semi_axes, speed), its points (rate, max_points, noise_diag) and
    the network (sensors, link_range, network_seed)."""
    axes = r.get("extent", "semi_axes", "vector")
    noise = r.get("extent", "noise_diag", "vector")
    if axes.shape != (2,):
        r.fail("extent.semi_axes", f"must be two semi-axes [l1, l2], got {short(axes)}")
    if noise.shape != (2,):
        r.fail("extent.noise_diag", f"must be two variances (the diagonal of C^v), got {short(noise)}")
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


def place_extent_network(r: ScenarioReader, spec: ScenarioSpec, ts: float) -> None:
    """Place the extended-object network into ``spec``: positions, relays and the links within range."""
    try:
        positions, roles, adjacency = extent_network(spec, ts)
    except ValueError as exc:
        r.fail("extent", str(exc))
    spec.sensors, spec.roles, spec.adjacency, spec.graph = positions, roles.tolist(), adjacency, "explicit"
    spec.x0 = extent_truth(spec, ts)[0]


def graph_section(r: ScenarioReader, kind: str, nodes: int) -> tuple[np.ndarray | None, str]:
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
        from zentrack.fusion.consensus_weights import random_graph

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


def orbits_section(r: ScenarioReader, count: int, steps: int, ts: float) -> dict:
    """``layout = "orbits"`` (paper 3): one satellite per node, ``orbits = [[a_km, e, i_deg, raan_deg, argp_deg,
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


def manoeuvre_section(r: ScenarioReader, plant: str, duration: float) -> list[tuple[float, list[float]]]:
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


def clutter_section(r: ScenarioReader, sensors: int, kind: str) -> ClutterSpec:
    """The ``[clutter]`` table (paper 1): detection probability and uniform clutter per sensor and scan, over
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
                   f"per sensor ({sensors}), got {short(w)}")
        windows[key] = w
    spec = ClutterSpec(p_d=p_d, mode=mode, count=count, density=density, **windows)
    mean = float(np.max(spec.mean_clutter(sensors)))
    if mode == "poisson" and mean > (MAX_RETURNS - 1) / 2:
        r.fail("clutter.density", f"{mean:.0f} clutter returns per scan on average; a scan holds at most "
               f"{MAX_RETURNS} returns")
    return spec
