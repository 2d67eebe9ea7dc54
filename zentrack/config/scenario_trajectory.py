"""A single-target scenario's ``[trajectory]`` section: the target's path taken from a recording (issue 34)
instead of simulated by the plant.

The keys are a recording's (:func:`~zentrack.config.scenario_multitarget.recording_spec`, one parser for
``[targets] layout = "recorded"`` and for this section): ``source``, ``origin`` ``[lat, lon, height]`` of the
local east-north-up frame (degrees, metres), ``start`` (s after the recording's first report), ``max_speed``
(m/s), ``max_gap`` (s), ``min_extent`` (m), ``select`` (exactly one target id or name) and, optionally,
``region`` ``[[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]]`` (ENU m; default: everywhere), the box the target
must stay in. Every run's truth is then that one path (:func:`zentrack.truth.simulation.simulate.simulate`;
its state at step 0 is the initial state, so ``[initial]`` gives ``p0_diag`` only) and the plant (``cv3d`` or
``cv3d-cd``: position and velocity) is what the filters and the bound assume, not how the target moved.
Every error names the key, in one line.

``kind = "patrol"`` (issue 36) instead simulates a patrol loop inside the sensors' field
(:mod:`zentrack.truth.simulation.patrol`): keys ``centre`` ``[x, y, z]``, ``semi_axes`` ``[a, b]`` (m),
``climb`` (m), ``speed`` (m/s), ``sigma_a`` (m/s^2, the process noise) and ``pull`` (1/s, the pull back to the
loop); the plant is again what the filters assume.
"""
from __future__ import annotations

import numpy as np

from zentrack.config.scenario_multitarget import RECORDING_KEYS, recording_spec
from zentrack.config.scenario_reader import ScenarioReader, short
from zentrack.config.scenario_schema import SCHEMA, unknown_key_message
from zentrack.truth.simulation.patrol import PATROL_KEYS, PatrolSpec
from zentrack.truth.simulation.recorded.recording import RecordingSpec
from zentrack.truth.simulation.scenario_spec import TRAJECTORY_PLANTS

#: the keys ``[trajectory]`` takes
TRAJECTORY_KEYS = ("region", *(key for key in RECORDING_KEYS if key != "max_targets"))
#: the default region: anywhere the recording goes (ENU metres)
EVERYWHERE = np.array([[-1e7, 1e7], [-1e7, 1e7], [-1e7, 1e7]])


def trajectory_section(r: ScenarioReader, plant: str, ts: float) -> RecordingSpec | PatrolSpec:
    """``[trajectory]`` (module docstring), checked with the plant and the sections it excludes."""
    section = r.section("trajectory")
    kind = section.get("kind", "recorded")
    if kind not in ("recorded", "patrol"):
        r.fail("trajectory.kind", f"must be \"recorded\" or \"patrol\", got {kind!r}")
    allowed = PATROL_KEYS if kind == "patrol" else TRAJECTORY_KEYS
    for key in sorted(set(section) - set(allowed)):
        if key in SCHEMA["trajectory"]:
            r.fail(f"trajectory.{key}", f"not a key of kind {kind!r}; its keys: {', '.join(allowed)}")
        r.fail(f"trajectory.{key}", unknown_key_message("trajectory", key, allowed))
    if plant not in TRAJECTORY_PLANTS:
        r.fail("scenario.plant", f"a recorded trajectory is a position and velocity: plant "
               f"{' or '.join(TRAJECTORY_PLANTS)}, not {plant!r}")
    for name in ("targets", "sensing", "extent", "manoeuvre"):
        if name in r.doc:
            r.fail(name, f"a scenario with a recorded [trajectory] takes no [{name}] section")
    if "x0" in r.section("initial"):
        r.fail("initial.x0", "a recorded trajectory's initial state is its state at step 0; give p0_diag only")
    if kind == "patrol":
        return patrol_section(r)
    select = section.get("select")
    if not isinstance(select, list) or len(select) != 1:
        r.fail("trajectory.select", f"must name exactly one target (one id or name in a list), got {select!r}")
    region = EVERYWHERE.copy()
    if "region" in section:
        region = r.get("trajectory", "region", "matrix", bounds=(-1e7, 1e7))
        if region.shape != (3, 2) or np.any(region[:, 1] < region[:, 0]):
            r.fail("trajectory.region", f"must be [[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]] with lo <= hi, got "
                   f"{short(region)}")
    return recording_spec(r, "trajectory", ts, region)


def patrol_section(r: ScenarioReader) -> PatrolSpec:
    """``[trajectory]`` with ``kind = "patrol"``: a loop with process noise (module docstring)."""
    centre = r.get("trajectory", "centre", "vector", bounds=(-1e7, 1e7))
    axes = r.get("trajectory", "semi_axes", "vector", bounds=(1.0, 1e7))
    if centre.shape != (3,) or axes.shape != (2,):
        r.fail("trajectory.centre", f"centre must be [x, y, z] and semi_axes [a, b], got {short(centre)} and "
               f"{short(axes)}")
    figures = {key: r.get("trajectory", key, "positive", default=default, required=False, bounds=(1e-6, 1e4))
               for key, default in (("speed", 15.0), ("pull", 0.1))}
    figures.update({key: r.get("trajectory", key, "float", default=default, required=False, bounds=(0.0, 1e4))
                    for key, default in (("climb", 0.0), ("sigma_a", 2.0))})
    return PatrolSpec(centre=(float(centre[0]), float(centre[1]), float(centre[2])),
                      semi_axes=(float(axes[0]), float(axes[1])), **figures)
