"""Scenario configuration files (TOML): the public entry points, by catalogue name or path.

The catalogue of built-in files lives in ``deploy/scenarios/`` (installed as ``zentrack.scenarios``,
:mod:`zentrack.config.catalogue`); its scenarios are addressed by name (``zentrack scenarios`` lists them), any
other argument is a path. :func:`load_scenario_config` reads and validates one (a many-target scenario only
when asked for: ``multitarget=True``; its :meth:`RunConfig.multitarget_data` is its simulated run); :func:`builtin_spec` is a
catalogue scenario's spec, resized like ``--nodes`` and ``--steps`` resize it (:func:`resize`). Every error names
the file, the key (``section.key``) and what is allowed.

The work is done in parts, all re-exported here so callers import from this module alone:
:mod:`zentrack.config.scenario_reader` (checked TOML values, the bounds, the error type),
:mod:`zentrack.config.scenario_sections` (the optional sections) and :mod:`zentrack.config.scenario_parse`
(:func:`parse`, the text to a :class:`RunConfig`), with :mod:`zentrack.config.scenario_multitarget` for the
sections of many targets (``[targets]``, ``[sensing]``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from zentrack.common.argtypes import check_node_steps
from zentrack.config import catalogue
from zentrack.config.scenario_multitarget import not_single_target
from zentrack.config.scenario_parse import RunConfig, parse
from zentrack.config.scenario_reader import BOUNDS, MODES, TS_RANGE, ScenarioConfigError
from zentrack.truth.simulation.scenario_spec import ScenarioSpec, ring_sensor_positions

__all__ = [
    "BOUNDS", "MODES", "TS_RANGE", "RunConfig", "ScenarioConfigError", "builtin_names", "builtin_spec",
    "load_scenario_config", "not_single_target", "parse", "resize", "resolve",
]


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


def load_scenario_config(name_or_path: str, *, multitarget: bool = False) -> RunConfig:
    """Read and validate a scenario file by catalogue name or path. A many-target scenario (``[targets]``) is
    refused in one line unless ``multitarget``: every command that calls this tracks one target."""
    cfg = parse(*resolve(name_or_path))
    if cfg.multitarget is not None and not multitarget:
        raise ScenarioConfigError(not_single_target(cfg.source))
    return cfg


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
    if nodes and cfg.sensor_timing is not None:  # a list of one value per sensor fixes N (one line naming it)
        cfg.sensor_timing = cfg.sensor_timing.resized(spec.nodes)
    if steps:
        spec.steps = steps
    if nodes or steps:
        check_node_steps(1, spec.steps, spec.nodes, f"{cfg.source}: --steps x --nodes")
    return cfg


def builtin_spec(name: str, nodes: int | None = None, steps: int | None = None) -> ScenarioSpec:
    """Catalogue scenario ``name``'s spec (or a TOML path's), optionally with another node count or length."""
    return resize(load_scenario_config(name), nodes, steps).spec
