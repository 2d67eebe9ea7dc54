"""A mixed many-target network: sensors of different measurement kinds (bearing-only cameras beside point radars)
in one network, read from a scenario file.

``[sensors] kinds`` gives each sensor its measurement kind (``"bearing"`` or ``"point"``; without it every sensor
measures by ``[measurement] kind``). ``[measurement] noise_stds`` then gives each sensor its noise in its own
kind's unit (rad for bearings, m for points). ``[sensing.<kind>]`` overrides any ``[sensing]`` key for the sensors
of one kind (a radar sees all round with more clutter than a camera). Each node builds its tracker for its own
sensor's kind; bearing nodes exchange scans with their bearing neighbours only (a point scan is not a ray), and
every node diffuses its track list by CI to all its neighbours as in a network of one kind.

A network must be able to start tracks (:func:`can_initiate`, checked by :func:`check_network_kinds`): a point node
starts them from its own scans (two-point differencing); a bearing node only from three rays that meet, its own
and two bearing neighbours' (one ray has no range). Every error names the key, in one line.
"""
from __future__ import annotations

import numpy as np

from zentrack.config.scenario_reader import ScenarioReader, short
from zentrack.truth.simulation.multitarget import MULTITARGET_MEASUREMENTS, MultiTargetSpec
from zentrack.truth.simulation.scenario_spec import ScenarioSpec

#: a bearing's noise (rad) is below this
MAX_BEARING_NOISE = float(np.pi)


def sensor_kinds(r: ScenarioReader, kind: str, count: int) -> tuple[str, ...]:
    """``[sensors] kinds``: one measurement kind per sensor (empty: every sensor measures ``kind``)."""
    kinds = r.section("sensors").get("kinds")
    if kinds is None:
        return ()
    if not isinstance(kinds, list) or len(kinds) != count or not all(isinstance(k, str) for k in kinds):
        r.fail("sensors.kinds", f"must be a list of {count} measurement kinds (one per sensor), got {short(kinds)}")
    for k in kinds:
        if k not in MULTITARGET_MEASUREMENTS:
            r.fail("sensors.kinds", f"{k!r} is not a sensor kind of a many-target network; choose one of "
                   f"{', '.join(MULTITARGET_MEASUREMENTS)}")
    if kind not in kinds:
        r.fail("measurement.kind", f"{kind!r} is no sensor's kind in sensors.kinds {short(kinds)}")
    return tuple(kinds)


def check_kinds(r: ScenarioReader, kinds: tuple[str, ...], noise_levels: np.ndarray) -> None:
    """Each sensor's noise fits its kind (a bearing's in radians, below pi), and only the sensors' kinds have a
    ``[sensing.<kind>]`` table."""
    for i, (k, std) in enumerate(zip(kinds, noise_levels)):
        if k == "bearing" and not std < MAX_BEARING_NOISE:
            r.fail("measurement.noise_stds", f"sensor {i} measures bearings: its noise is in radians (below pi), "
                   f"got {std:g}")
    for key, value in r.section("sensing").items():
        if isinstance(value, dict) and key not in (kinds or ()):
            r.fail(f"sensing.{key}", f"a [sensing.<kind>] table is for a kind of sensors.kinds "
                   f"({', '.join(dict.fromkeys(kinds)) or 'none given'})")


def kind_tables(r: ScenarioReader) -> list[str]:
    """The ``[sensing.<kind>]`` tables of the file."""
    return [key for key, value in r.section("sensing").items() if isinstance(value, dict)]


def kind_reader(r: ScenarioReader, kind: str) -> tuple[ScenarioReader, str]:
    """A reader whose section ``sensing.<kind>`` is ``[sensing]`` with the kind's table over it."""
    base = {key: value for key, value in r.section("sensing").items() if not isinstance(value, dict)}
    name = f"sensing.{kind}"
    return ScenarioReader(r.label, {**r.doc, name: {**base, **r.section("sensing").get(kind, {})}}), name


def can_initiate(kinds: tuple[str, ...], adjacency: np.ndarray) -> bool:
    """Whether some node can start a track: a point node, or a bearing node with two bearing neighbours."""
    for i, k in enumerate(kinds):
        if k == "point":
            return True
        bearing_neighbours = [j for j in np.flatnonzero(adjacency[i]) if j != i and kinds[j] == "bearing"]
        if len(bearing_neighbours) >= 2:
            return True
    return False


def check_network_kinds(r: ScenarioReader, spec: ScenarioSpec, mt: MultiTargetSpec) -> None:
    """The sensors' kinds fit their noise (:func:`check_kinds`), and some node can start a track (module
    docstring): a network in which none can is refused."""
    from zentrack.truth.simulation.scenario_spec import graph_weights

    kinds = mt.sensor_kinds(spec.measurement, spec.nodes)
    check_kinds(r, mt.kinds, spec.noise_levels())
    adjacency, _ = graph_weights(spec)
    if not can_initiate(kinds, np.asarray(adjacency)):
        r.fail("graph.kind", "no node can start a track: a bearing-only node needs two bearing neighbours (three "
               "rays meet) and no sensor measures points; add links or a point sensor (sensors.kinds)")
