"""The keys a scenario file may hold, section by section, with what each means: the one schema of the format.

Every section parser reads through :class:`~zentrack.config.scenario_reader.ScenarioReader`, which refuses to
read a key this schema does not list, and :func:`check_keys` refuses a file's key that it does not list, in one
line naming the file, the key and the nearest known key. ``[plant]``, ``[filter]`` and ``[fusion]`` take the
parameters of the plant, filter or rule chosen (their registries), checked where they are read.
``zentrack scenarios --keys`` prints :func:`keys_markdown`, which is also ``docs/scenario-keys.md``.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

from zentrack.common.suggest import did_you_mean

#: a recording's keys (``[targets]`` with ``layout = "recorded"``, and ``[trajectory]``)
_RECORDING = {
    "source": "the recording's name (Real trajectories in the docs)",
    "origin": "[lat, lon, height] of the local east-north-up frame (degrees, metres)",
    "start": "seconds after the recording's first report",
    "max_speed": "m/s: faster jumps are outliers",
    "max_gap": "seconds: a longer silence splits a track",
    "min_extent": "metres: targets that stay within it (at anchor, parked) are left out",
    "select": "the ids or names of the targets to keep",
    "smoothing": "s^3: the smoothing spline's penalty (0: through every report)",
}

#: section -> key -> its meaning (one line)
SCHEMA: dict[str, dict[str, str]] = {
    "scenario": {
        "name": "the scenario's name",
        "description": "one line for `zentrack scenarios`",
        "plant": "the target's motion model (its parameters go in [plant])",
        "steps": "how many steps the run has",
        "ts": "seconds per step",
        "seed": "the seed of the simulated noise",
    },
    "measurement": {
        "kind": "bearing, point, linear, extent-ellipse or extent-rectangle",
        "noise_std": "the noise of every sensor (radians for bearings)",
        "noise_stds": "one noise level per sensor (instead of noise_std)",
        "matrix": "a linear measurement's matrix (rows of state-sized lists)",
    },
    "sensors": {
        "count": "how many sensors (one tracker each)",
        "layout": "ring, explicit, orbits, none or placed",
        "radius": "a ring's radius (m)",
        "height": "a ring's height (m)",
        "positions": "explicit: one [x, y, z] per sensor (m)",
        "velocities": "explicit, moving platforms: one [vx, vy, vz] per sensor (m/s)",
        "accelerations": "explicit, moving platforms: one [ax, ay, az] per sensor (m/s^2)",
        "relays": "the indices of the nodes that only relay (no sensor)",
        "kinds": "many targets: each sensor's measurement kind",
        "orbits": "orbits: one [a_km, e, i_deg, raan_deg, argp_deg, m0_deg] per satellite",
        "site_under": "orbits: the satellite whose ground track the site lies under",
        "t_mid": "orbits: seconds after the epoch at the run's middle step",
        "cross_track_km": "orbits: the site's distance to the side of that ground track",
        "gmst0_deg": "orbits: Greenwich sidereal time at the epoch (degrees)",
    },
    "graph": {
        "kind": "ring, metropolis-ring, explicit, random or placed",
        "self_weight": "a ring's weight of a node's own estimate",
        "weights": "explicit or random: the consensus weights' rule",
        "edges": "explicit: the links, pairs [i, j] of node indices",
        "link_prob": "random: the probability of each link",
        "diameter": "random: the graph's diameter (0: any)",
        "seed": "random: the seed the graph is drawn from",
    },
    "initial": {
        "x0": "the initial state estimate",
        "p0_diag": "the diagonal of the initial covariance",
        "lumped_var": "the variance of the lumped states",
    },
    "filter": {
        "kind": "the local filter (`zentrack sim --list-filters`; its parameters go here too, below)",
    },
    "fusion": {
        "rule": "the fusion rule (`zentrack sim --list-filters`; its parameters go here too, below)",
    },
    "timing": {
        "mode": "realtime or lockstep",
        "deadline_frac": "the share of a step the local update must end within (0 to 1)",
    },
    "clutter": {
        "mode": "fixed or poisson",
        "detection_prob": "the probability the target is detected",
        "count": "fixed: clutter returns per sensor and scan",
        "density": "poisson: returns per rad^2",
        "az_window": "[lo, hi] azimuth window (radians), or one row per sensor",
        "el_window": "[lo, hi] elevation window (radians), or one row per sensor",
    },
    "manoeuvre": {
        "times": "the seconds each acceleration starts at (ca9)",
        "accelerations": "one [ax, ay, az] per time (m/s^2)",
    },
    "extent": {
        "semi_axes": "the object's semi-axes (m)",
        "speed": "the object's speed (m/s)",
        "rate": "measurement points per scan (mean)",
        "max_points": "at most this many points per scan",
        "noise_diag": "the points' noise variances",
        "sensors": "how many sensors are placed along the path",
        "link_range": "sensors within this range (m) are linked",
        "network_seed": "the seed of the sensors' placement",
    },
    "targets": {
        "layout": "random, crossing, explicit or recorded",
        "count": "how many targets at the start",
        "speed": "the targets' speed (m/s)",
        "centre": "the centre of their area [x, y, z] (m)",
        "region": "the box they are present in, [[x0, x1], [y0, y1], [z0, z1]]",
        "spread": "crossing: the distance between the lanes (m)",
        "initial": "explicit: one [x, y, z, vx, vy, vz] per target",
        "birth_times": "one appearance time per target (s)",
        "death_times": "one departure time per target (s)",
        "birth_rate": "new targets per second (Poisson)",
        "survival_prob": "the probability a target stays for a step",
        "max_targets": "at most this many targets at once (recorded: kept)",
        "gospa_cutoff": "GOSPA's cut-off distance c (m)",
        **_RECORDING,
    },
    "sensing": {
        "detection_prob": "the probability a target in view is detected",
        "max_range": "the sensors' range (m)",
        "fov_azimuth": "the azimuth field of view (radians)",
        "fov_elevation": "[lo, hi] elevation field of view (radians)",
        "clutter_rate": "clutter returns per scan (mean)",
    },
    "tracker": {
        "kind": "many targets: each node's tracker, gnn (M of N confirmation, the default) or pmbm (Poisson "
                "multi-Bernoulli mixture, point sensors)",
        "share_scans": "point sensors: each node also steps on its neighbours' scans (default: true for pmbm, false "
                       "for gnn; bearing sensors always do)",
    },
    "trajectory": {
        "kind": "recorded (default) or patrol",
        "region": "recorded: the box the target is present in",
        **{key: f"recorded: {meaning}" for key, meaning in _RECORDING.items()},
        "centre": "patrol: the loop's centre [x, y, z] (m)",
        "semi_axes": "patrol: the loop's semi-axes in x and y (m)",
        "climb": "patrol: how far it climbs and descends, twice a lap (m)",
        "speed": "patrol: the speed along the loop (m/s)",
        "sigma_a": "patrol: the random acceleration per axis (m/s^2)",
        "pull": "patrol: the rate of the pull back to the loop (1/s)",
    },
    "sensor_timing": {
        "rate_hz": "sensors of their own (one value for all, or a list of one per sensor): samples a second "
                   "(default: the run's rate, 1 / ts)",
        "phase_s": "per sensor: its first sample's time after the run's start, below one period (s)",
        "offset_s": "per sensor: its clock's offset to the trackers' (s, sensor - tracker)",
        "drift_ppm": "per sensor: its clock's drift (parts per million)",
        "latency": "per sensor: fixed, uniform or exponential (from measurement to publication)",
        "latency_low_ms": "per sensor: the least latency (fixed: the latency) (ms)",
        "latency_high_ms": "per sensor: uniform: the largest latency; exponential: its cap (ms)",
        "latency_mean_ms": "per sensor: exponential: the mean latency above the least (ms)",
        "reorder": "per sensor: the share of detections held one period more (arriving after the next)",
        "detection_prob": "per sensor: the probability a sample detects the target (times the P_D of [sensing] or [clutter])",
        "lag_ms": "how far (ms) the trackers' schedule runs behind the run's, so late detections still count",
        "clock": "estimated (default: each tracker estimates the sensors' and its neighbours' clock offsets from "
                 "the stream) or configured (the trackers are told each sensor's offset_s; their own clocks are "
                 "taken as synchronised)",
        "takes": "one list of sensor ids per tracker (default: tracker i takes sensor i)",
    },
}
#: sections whose keys are parameters of what the file chose (checked against its registry where it is read)
OPEN_SECTIONS = {"plant": "the parameters of the plant chosen ([scenario] plant)",
                 "filter": "kind, and the parameters of the filter chosen",
                 "fusion": "rule, and the parameters of the rule chosen"}
#: the top-level keys that are not sections
TOP_LEVEL = {"plugins": "modules to import first (their filters and rules become names)"}
#: sections whose sub-tables are named by a value (``[sensing.<kind>]``: a sensor kind's own sensing keys)
SUBTABLES = {"sensing": "sensing"}


def known(section: str) -> dict[str, str]:
    """The keys of ``section`` and their meanings (an open section: its fixed keys only)."""
    return SCHEMA.get(section, {})


def unknown_key_message(section: str, key: str, allowed: Iterable[str]) -> str:
    """``"unknown key; did you mean 'self_weight'?"`` (or the allowed keys when none is near)."""
    allowed = sorted(allowed)
    hint = did_you_mean(key, allowed)
    return f"unknown key{hint}" if hint else f"unknown key; allowed: {', '.join(allowed)}"


def check_keys(doc: Mapping, fail) -> None:
    """Every key of every fixed section of ``doc`` is in :data:`SCHEMA` (``fail(key, message)`` otherwise);
    a ``[sensing.<kind>]`` table's keys are ``[sensing]``'s."""
    for section, table in doc.items():
        if section not in SCHEMA or section in OPEN_SECTIONS or not isinstance(table, dict):
            continue  # (open sections, top-level keys and a section that is not a table are checked where read)
        for key, value in table.items():
            if section in SUBTABLES and isinstance(value, dict):
                for sub in value:
                    if sub not in SCHEMA[section]:
                        fail(f"{section}.{key}.{sub}", unknown_key_message(section, sub, SCHEMA[section]))
            elif key not in SCHEMA[section]:
                fail(f"{section}.{key}", unknown_key_message(section, key, SCHEMA[section]))


def _own(registry) -> list[str]:
    """The registry's names that zentrack itself defines (a plug-in imported in this process is left out)."""
    return [name for name in registry.names() if registry.entry(name).factory.__module__.startswith("zentrack.")]


def keys_markdown() -> str:
    """The schema as a Markdown page: every section's keys and meanings, and the parameters of every plant,
    filter and fusion rule (from their registries)."""
    from zentrack.fusion.filters import FILTER_REGISTRY
    from zentrack.fusion.models import PLANT_PARAMS
    from zentrack.fusion.rules import RULE_REGISTRY

    lines = ["# Scenario file keys", "",
             "Generated from `zentrack/config/scenario_schema.py` (`zentrack scenarios --keys`); a key not listed "
             "here is refused with the nearest known one.", ""]
    for name, meaning in TOP_LEVEL.items():
        lines += [f"- top level `{name}`: {meaning}"]
    for section, keys in SCHEMA.items():
        lines += ["", f"## [{section}]", "", "| key | meaning |", "|---|---|"]
        lines += [f"| `{key}` | {meaning} |" for key, meaning in keys.items()]
        if section in SUBTABLES:
            lines += ["", f"A `[{section}.<kind>]` table holds the same keys for one sensor kind."]
        if section == "filter":
            lines += ["", "| filter | its parameters |", "|---|---|"]
            lines += [f"| `{kind}` | {', '.join(f'`{p.name}`' for p in FILTER_REGISTRY.params(kind)) or '-'} |"
                      for kind in _own(FILTER_REGISTRY)]
        if section == "fusion":
            lines += ["", "| rule | its parameters |", "|---|---|"]
            lines += [f"| `{rule}` | {', '.join(f'`{p.name}`' for p in RULE_REGISTRY.params(rule)) or '-'} |"
                      for rule in _own(RULE_REGISTRY)]
    lines += ["", "## [plant]", "", OPEN_SECTIONS["plant"] + ":", "", "| plant | its parameters |", "|---|---|"]
    lines += [f"| `{plant}` | {', '.join(f'`{p}`' for p in params) or '-'} |" for plant, params in PLANT_PARAMS.items()]
    return "\n".join(lines) + "\n"
