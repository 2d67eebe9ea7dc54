"""A many-target scenario's sections: ``[targets]`` (how many, where, when they appear and leave) and
``[sensing]`` (detection probability, range, field of view, clutter), read into a
:class:`~zentrack.truth.simulation.multitarget.MultiTargetSpec`.

Either section asks for the other. Keys (times in seconds, angles in radians, lengths in metres):

``[targets]``: ``layout`` (``crossing``, ``random``, ``explicit``, or ``recorded``: real trajectories,
:func:`recorded_section`), ``count`` (present from the start, or at
their ``birth_times``), ``speed``, ``centre`` ``[x, y, z]`` (where crossing targets meet, what the sensors face),
``region`` ``[[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]]`` (where random and Poisson-born targets start),
``spread`` (crossing: start distance from the centre), ``initial`` (explicit: one ``[x, y, z, vx, vy, vz]`` per
target), ``birth_times``/``death_times`` (one per target), ``birth_rate`` (Poisson births per second),
``survival_prob`` (per step), ``max_targets`` (births stop there) and ``gospa_cutoff`` (m: how far a track may
lie from a target and still be scored as its estimate; default 50 m, larger for targets seen from far away).

``[sensing]``: ``detection_prob``, ``max_range`` (required for point sensors), ``fov_azimuth`` (full width,
default 2 pi), ``fov_elevation`` ``[lo, hi]`` (default [-pi/2, pi/2]) and ``clutter_rate`` (mean clutter returns
per scan, default 0).

A many-target scenario moves its targets by a position-velocity plant (``cv3d``, ``cv3d-cd``), measures
``point`` or ``bearing``, has fixed sensors that all measure, and no single-target sections (``[clutter]``,
``[manoeuvre]``, ``[extent]``, ``[initial] x0``). Every error names the key, in one line.
"""
from __future__ import annotations

import math

import numpy as np

from zentrack.config.scenario_kinds import kind_reader, kind_tables, sensor_kinds
from zentrack.config.scenario_reader import ScenarioReader, short
from zentrack.config.scenario_schema import SCHEMA, unknown_key_message
from zentrack.fusion.defaults import MULTITARGET_TRACKERS
from zentrack.transport.wire import MAX_RETURNS
from zentrack.truth.simulation.multitarget import (
    MULTITARGET_MEASUREMENTS,
    MULTITARGET_PLANTS,
    TARGET_LAYOUTS,
    MultiTargetSpec,
    SensingSpec,
    TargetsSpec,
    clutter_density,
)
from zentrack.truth.simulation.recorded.recording import RecordingSpec
from zentrack.truth.simulation.recorded.sources import SOURCES

#: targets one run may hold (also bounds max_targets)
MAX_TARGETS = 1000
TARGET_KEYS = ("layout", "count", "speed", "centre", "region", "spread", "initial", "birth_times", "death_times",
               "birth_rate", "survival_prob", "max_targets", "gospa_cutoff")
#: a recording's keys (:func:`recording_spec`), in any section that takes one
RECORDING_KEYS = ("source", "origin", "start", "max_speed", "max_gap", "min_extent", "max_targets", "select",
                  "smoothing")
#: ``layout = "recorded"``'s keys
RECORDED_KEYS = ("layout", "centre", "region", "gospa_cutoff", *RECORDING_KEYS)
SENSING_KEYS = ("detection_prob", "max_range", "fov_azimuth", "fov_elevation", "clutter_rate")
#: sections a many-target scenario may not have: they describe one target
SINGLE_TARGET_SECTIONS = ("clutter", "manoeuvre", "extent")
_COORD = (-1e7, 1e7)


def is_multitarget(doc: dict) -> bool:
    """Whether a parsed scenario document describes many targets."""
    return "targets" in doc or "sensing" in doc


def not_single_target(source: str) -> str:
    """Why a command that tracks one target refuses the many-target scenario ``source`` (one line)."""
    return (f"{source}: a many-target scenario ([targets]): this command tracks one target; `zentrack run`, "
            "`zentrack soak` and `zentrack bench multitarget` run it (`zentrack scenarios` lists the single-target ones)")


def check_network(r: ScenarioReader, plant: str, kind: str) -> None:
    """What the rest of a many-target file must be: its plant, measurement and sections."""
    for name in ("targets", "sensing"):
        r.section(name)  # either asks for the other
    for name in SINGLE_TARGET_SECTIONS:
        if name in r.doc:
            r.fail(name, "a many-target scenario ([targets]) takes no [" + name + "] section; clutter and detection "
                   "are [sensing]'s")
    if plant not in MULTITARGET_PLANTS:
        r.fail("scenario.plant", f"a many-target scenario moves its targets by {' or '.join(MULTITARGET_PLANTS)}, "
               f"not {plant!r}")
    if kind not in MULTITARGET_MEASUREMENTS:
        r.fail("measurement.kind", f"a many-target scenario measures {' or '.join(MULTITARGET_MEASUREMENTS)}, "
               f"not {kind!r}")
    sensors = r.section("sensors")
    if sensors.get("layout") not in ("ring", "explicit"):
        r.fail("sensors.layout", "a many-target scenario needs fixed sensors: layout \"ring\" or \"explicit\"")
    for key in ("velocities", "accelerations", "relays"):
        if key in sensors:
            r.fail(f"sensors.{key}", "a many-target scenario has fixed sensors that all measure (no moving "
                   "platforms or relays yet)")
    if "x0" in r.section("initial"):
        r.fail("initial.x0", "a many-target scenario's initial states are its [targets]; give p0_diag only (the "
               "covariance a new track starts with)")


def _unknown(r: ScenarioReader, section: str, known: tuple[str, ...], context: str) -> None:
    """Every key of ``[section]`` is one ``context`` takes (a key of the schema that another layout takes is
    named as such; one of no layout was refused with the file's other unknown keys)."""
    for key in sorted(set(r.section(section)) - set(known)):
        if key in SCHEMA.get(section.split(".", 1)[0], {}):
            r.fail(f"{section}.{key}", f"not a key of {context}; its keys: {', '.join(known)}")
        r.fail(f"{section}.{key}", unknown_key_message(section, key, known))


def _per_target(r: ScenarioReader, key: str, count: int, duration: float) -> np.ndarray | None:
    if key not in r.section("targets"):
        return None
    times = r.get("targets", key, "vector", bounds=(0.0, 1e9))
    if times.shape != (count,):
        r.fail(f"targets.{key}", f"must have one time per target ({count}), got {times.size}")
    if key == "birth_times" and np.any(times >= duration):
        r.fail("targets.birth_times", f"must be within the run (before {duration:g} s), got {short(times)}")
    return times


def _region(r: ScenarioReader, centre: np.ndarray, required: bool) -> np.ndarray:
    region = r.get("targets", "region", "matrix", required=required, bounds=_COORD)
    if region is None:
        return np.column_stack([centre, centre])
    if region.shape != (3, 2) or np.any(region[:, 1] < region[:, 0]):
        r.fail("targets.region", f"must be [[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]] with lo <= hi, got "
               f"{short(region)}")
    return region


def _centre(r: ScenarioReader) -> np.ndarray:
    centre = r.get("targets", "centre", "vector", bounds=_COORD)
    if centre.shape != (3,):
        r.fail("targets.centre", f"must be [x, y, z], got {short(centre)}")
    return centre


def recording_spec(r: ScenarioReader, section: str, ts: float, region: np.ndarray) -> RecordingSpec:
    """A recording's keys in ``[section]`` (``[targets]`` of a many-target scenario, ``[trajectory]`` of a
    single-target one): ``source``, ``origin`` ``[lat, lon, height]`` of the local east-north-up frame (degrees,
    metres), ``start`` (s after the recording's first report), ``max_speed`` (m/s: faster jumps are outliers),
    ``max_gap`` (s: longer silences split a track), ``min_extent`` (m: targets that stay within it are at anchor
    or parked and left out), ``max_targets``, ``select`` (ids or names) and ``smoothing`` (s^3: the penalty of the
    smoothing spline through the reports, 0: interpolate through each); ``region`` the ENU box a target is
    present in."""
    name = r.get(section, "source", "str", choices=tuple(SOURCES))
    origin = r.get(section, "origin", "vector")
    if origin.shape != (3,) or not (-90 <= origin[0] <= 90 and -180 <= origin[1] <= 180 and abs(origin[2]) < 1e4):
        r.fail(f"{section}.origin", f"must be [latitude, longitude, height] in degrees and metres, got {short(origin)}")
    select = r.section(section).get("select", [])
    if not isinstance(select, list) or not all(isinstance(x, str) and x for x in select):
        r.fail(f"{section}.select", f"must be a list of target ids or names, got {select!r}")
    max_targets = r.get(section, "max_targets", "int", default=200, required=False) if section == "targets" else 200
    if not 1 <= max_targets <= MAX_TARGETS:
        r.fail(f"{section}.max_targets", f"must be from 1 to {MAX_TARGETS}, got {max_targets}")
    return RecordingSpec(
        source=name, origin=(float(origin[0]), float(origin[1]), float(origin[2])), region=region,
        start=r.get(section, "start", "float", default=0.0, required=False, bounds=(0.0, 1e7)),
        max_speed=r.get(section, "max_speed", "positive", default=50.0, required=False, bounds=(0.1, 1e4)),
        max_gap=r.get(section, "max_gap", "positive", default=60.0, required=False, bounds=(ts, 1e5)),
        min_extent=r.get(section, "min_extent", "float", default=100.0, required=False, bounds=(0.0, 1e6)),
        max_targets=max_targets, select=tuple(select),
        smoothing=r.get(section, "smoothing", "float", default=0.0, required=False, bounds=(0.0, 1e9)))


def recorded_section(r: ScenarioReader, steps: int, ts: float) -> TargetsSpec:
    """``[targets]`` with ``layout = "recorded"``: a recording's keys (:func:`recording_spec`), ``centre`` (what
    the sensors face, ENU m) and ``region`` (the ENU box a target is present in)."""
    _unknown(r, "targets", RECORDED_KEYS, 'layout "recorded"')
    centre = _centre(r)
    region = _region(r, centre, required=True)
    recording = recording_spec(r, "targets", ts, region)
    return TargetsSpec(layout="recorded", count=0, speed=0.0, centre=centre, region=region,
                       max_targets=recording.max_targets, recording=recording, gospa_cutoff=_gospa_cutoff(r))


def _gospa_cutoff(r: ScenarioReader) -> float | None:
    return r.get("targets", "gospa_cutoff", "positive", default=None, required=False, bounds=(1e-3, 1e6))


def targets_section(r: ScenarioReader, steps: int, ts: float) -> TargetsSpec:
    """``[targets]`` (module docstring)."""
    layout = r.get("targets", "layout", "str", choices=TARGET_LAYOUTS)
    if layout == "recorded":
        return recorded_section(r, steps, ts)
    _unknown(r, "targets", TARGET_KEYS, f"layout {layout!r}")
    count = r.get("targets", "count", "int")
    if not 0 <= count <= MAX_TARGETS:
        r.fail("targets.count", f"must be from 0 to {MAX_TARGETS}, got {count}")
    speed = r.get("targets", "speed", "float", bounds=(0.0, 1e5))
    centre = _centre(r)
    birth_rate = r.get("targets", "birth_rate", "float", default=0.0, required=False, bounds=(0.0, 1e3))
    region = _region(r, centre, required=layout == "random" or birth_rate > 0)
    spread = r.get("targets", "spread", "positive", required=layout == "crossing", default=None, bounds=(1e-3, 1e7))
    initial = None
    if layout == "explicit":
        initial = r.get("targets", "initial", "matrix", bounds=_COORD)
        if initial.shape != (count, 6):
            r.fail("targets.initial", f"must be {count} rows of [x, y, z, vx, vy, vz], got shape "
                   f"{list(initial.shape)}")
    elif "initial" in r.section("targets"):
        r.fail("targets.initial", f"only layout \"explicit\" takes initial states, not {layout!r}")
    if layout != "crossing" and "spread" in r.section("targets"):
        r.fail("targets.spread", f"only layout \"crossing\" takes a spread, not {layout!r}")
    duration = steps * ts
    birth_times = _per_target(r, "birth_times", count, duration)
    death_times = _per_target(r, "death_times", count, duration)
    if birth_times is not None and death_times is not None and np.any(death_times <= birth_times):
        r.fail("targets.death_times", "every target must leave after it appears (death_times > birth_times)")
    survival = r.get("targets", "survival_prob", "float", default=1.0, required=False, bounds=(0.5, 1.0))
    max_targets = r.get("targets", "max_targets", "int", default=max(count, 200), required=False)
    if not count <= max_targets <= MAX_TARGETS:
        r.fail("targets.max_targets", f"must be from count ({count}) to {MAX_TARGETS}, got {max_targets}")
    return TargetsSpec(layout=layout, count=count, speed=speed, centre=centre, region=region,
                       spread=1000.0 if spread is None else spread, initial=initial, birth_times=birth_times,
                       death_times=death_times, birth_rate=birth_rate, survival_prob=survival, max_targets=max_targets,
                       gospa_cutoff=_gospa_cutoff(r))


def sensing_section(r: ScenarioReader, kind: str, max_targets: int, section: str = "sensing") -> SensingSpec:
    """``[sensing]`` (module docstring), or a kind's ``[sensing.<kind>]`` (``section``)."""
    _unknown(r, section, (*SENSING_KEYS, *kind_tables(r)), f"[{section}]")
    pd = r.get(section, "detection_prob", "float", bounds=(0.0, 1.0))
    if pd <= 0:
        r.fail(f"{section}.detection_prob", f"must be above 0 (at most 1), got {pd:g}")
    max_range = r.get(section, "max_range", "positive", required=kind == "point", default=None, bounds=(1e-3, 1e8))
    fov_azimuth = r.get(section, "fov_azimuth", "positive", default=2 * math.pi, required=False,
                        bounds=(1e-6, 2 * math.pi))
    fov_el = r.get(section, "fov_elevation", "vector", default=np.array([-math.pi / 2, math.pi / 2]),
                   required=False, bounds=(-math.pi / 2, math.pi / 2))
    if fov_el.shape != (2,) or not fov_el[0] < fov_el[1]:
        r.fail(f"{section}.fov_elevation", f"must be [lo, hi] with lo < hi (radians), got {short(fov_el)}")
    rate = r.get(section, "clutter_rate", "float", default=0.0, required=False, bounds=(0.0, MAX_RETURNS / 2))
    if max_targets + 2 * rate > MAX_RETURNS - 1:
        r.fail(f"{section}.clutter_rate", f"{max_targets} targets and {rate:g} clutter returns per scan on average "
               f"do not fit a scan of at most {MAX_RETURNS} returns")
    return SensingSpec(detection_prob=pd, max_range=math.inf if max_range is None else max_range,
                       fov_azimuth=fov_azimuth, fov_elevation=(float(fov_el[0]), float(fov_el[1])),
                       clutter_rate=rate)


def multitarget_section(r: ScenarioReader, plant: str, kind: str, steps: int, ts: float) -> MultiTargetSpec:
    """The many-target part of a scenario file, checked with the rest of the file (:func:`check_network`)."""
    check_network(r, plant, kind)
    targets = targets_section(r, steps, ts)
    kinds = sensor_kinds(r, kind, r.get("sensors", "count", "int"))
    others = []
    for other in dict.fromkeys(kinds):  # every other kind's sensing: [sensing] with its table over it
        if other != kind:
            sub, section = kind_reader(r, other)
            others.append((other, sensing_section(sub, other, targets.max_targets, section)))
    return MultiTargetSpec(targets=targets, sensing=sensing_section(r, kind, targets.max_targets), kinds=kinds,
                           kind_sensing=tuple(others))


def tracking_params(mt: MultiTargetSpec, measurement: str, where: str) -> dict[str, float]:
    """What a many-target scenario tells each node's multi-target tracker besides the models
    (:class:`~zentrack.fusion.multitarget.network.TrackerSettings` fields): P_D, the clutter density (per m^3 for
    point sensors, per rad^2 for bearing sensors), for bearing sensors (whose tracks start by triangulating
    the neighbours' scans) the sensing range and, for recorded targets, their ``max_speed`` (the two-point
    initiation's velocity gate: the same bound that tells a bad report). ValueError naming ``where`` for another
    measurement."""
    if measurement not in ("point", "bearing"):
        raise ValueError(f"{where}: {measurement} sensors; zentrack's multi-target trackers take point or bearing "
                         "sensors")
    sensing = mt.sensing_of(measurement)
    params = {"detection_prob": float(sensing.detection_prob), "clutter_density": clutter_density(sensing, measurement)}
    if math.isfinite(sensing.max_range):  # (bearing: where rays may meet; a PMBM's P_D is 0 beyond it)
        params["max_range"] = float(sensing.max_range)
    if mt.targets.recording is not None:
        params["max_speed"] = float(mt.targets.recording.max_speed)
    return params


def tracker_refusal(tracker: str, measurement: str, mt: MultiTargetSpec | None, nodes: int,
                    asynchronous: bool) -> str | None:
    """Why a run cannot give its nodes the tracker ``tracker`` (``[tracker] kind`` or ``--tracker``), in one line;
    None when it can."""
    if mt is None:
        return "only a many-target scenario ([targets]) chooses its tracker"
    if tracker == "pmbm":
        if set(mt.sensor_kinds(measurement, nodes)) != {"point"}:
            return "the PMBM tracker takes point sensors only (bearing-only births are not built)"
        if asynchronous:
            return "the PMBM tracker steps on the run's grid; sensors of their own ([sensor_timing]) need gnn"
    return None


def shares_scans(tracker: str, share_scans: bool | None) -> bool:
    """Whether point sensors' nodes step on their neighbours' scans: ``share_scans`` when given, else for a PMBM
    tracker (a network of PMBM nodes sharing scans comes near the centralized filter; docs/multitarget.md)."""
    return tracker == "pmbm" if share_scans is None else share_scans


def scan_sharing_refusal(share_scans: bool | None, asynchronous: bool) -> str | None:
    """Why a run cannot share its nodes' scans, in one line; None when it can (or does not ask to)."""
    if share_scans and asynchronous:
        return "nodes share the scans of each step; sensors of their own ([sensor_timing]) cannot"
    return None


def tracker_section(r: ScenarioReader, kind: str, mt: MultiTargetSpec | None, nodes: int,
                    asynchronous: bool) -> tuple[str, bool | None]:
    """``[tracker]``: each node's tracker (``kind``, default gnn) and ``share_scans`` (None: the tracker's
    default), refused in one line naming the key where the run cannot have them."""
    if "tracker" not in r.doc:
        return "gnn", None
    tracker = r.get("tracker", "kind", "str", choices=MULTITARGET_TRACKERS, default="gnn", required=False)
    share_scans = r.get("tracker", "share_scans", "bool", default=None, required=False)
    why = tracker_refusal(tracker, kind, mt, nodes, asynchronous)
    if why is not None:
        r.fail("tracker.kind", why)
    why = scan_sharing_refusal(share_scans, asynchronous)
    if why is not None:
        r.fail("tracker.share_scans", why)
    return tracker, share_scans
