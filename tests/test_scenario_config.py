"""TOML scenario files: the built-ins load and match the paper; every bad value names file, key and choices."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.scenario_config import ScenarioConfigError, builtin_names, load_scenario_config, resolve
from zentrack.truth.simulation.simulate import simulate


def test_builtins_are_installed():
    """(tests/test_catalogue.py checks them against the Python specs they replaced.)"""
    assert {"exp1", "exp2", "exp2-point", "exp2-irregular"} <= set(builtin_names())
    for name in ("exp1", "exp2", "exp2-point"):
        cfg = load_scenario_config(name)
        assert cfg.ts == 0.1 and cfg.filter_kind == "teskf" and cfg.theta is None and cfg.mode == "realtime"
        np.testing.assert_array_equal(cfg.scenario_data().measurements,
                                      simulate(cfg.spec, runs=1, seed=cfg.seed).measurements)


def write(tmp_path, text):
    path = tmp_path / "s.toml"
    path.write_text(text)
    return path


BASE = resolve("exp2")[1]


@pytest.mark.parametrize(
    "old, new, key, allowed",
    [
        ('kind = "bearing"', 'kind = "sonar"', "measurement.kind", "bearing, point, linear"),
        ('kind = "teskf"', 'kind = "kf"', "filter.kind", "teskf, eskf, ekf, ukf, ckf"),
        ('mode = "realtime"', 'mode = "fast"', "timing.mode", "realtime, lockstep"),
        ("steps = 1000", "steps = 0", "scenario.steps", "at least 1"),
        ("steps = 1000", 'steps = "many"', "scenario.steps", "whole number"),
        ("ts = 0.1", "ts = -0.1", "scenario.ts", "positive"),
        ("alpha = 1.2", "alpha = 1.2\nwings = 2", "plant.wings", "sigma_w, alpha, beta"),
        ("deadline_frac = 0.5", "deadline_frac = 1.5", "timing.deadline_frac", "between 0 and 1"),
        ('theta = "auto"', 'theta = "big"', "filter.theta", "auto"),
        ("x0 = [0.0, 0.0, 0.0, 2.0, 1.0, 1.5]", "x0 = [0.0, 1.0]", "initial.x0", "6 entries"),
        ('layout = "ring"', 'layout = "spiral"', "sensors.layout", "ring, explicit, orbits, none, placed"),
        ("[graph]", "[graph]\n[extra]", "extra", "unknown section"),
        ('plant = "cv3d"', 'plant = "boat"', "scenario.plant", "exp1, cv3d"),
        ("noise_std = 0.017453292519943295", "noise_std = nan", "measurement.noise_std", "finite"),
    ],
)
def test_bad_values_name_file_key_and_choices(tmp_path, old, new, key, allowed):
    assert old in BASE
    path = write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(ScenarioConfigError) as err:
        load_scenario_config(str(path))
    msg = str(err.value)
    assert str(path) in msg and key in msg and allowed in msg, msg


def test_not_toml_and_missing(tmp_path):
    with pytest.raises(ScenarioConfigError, match="not valid TOML"):
        load_scenario_config(str(write(tmp_path, "[scenario\nname=")))
    with pytest.raises(ScenarioConfigError, match="cannot read"):
        load_scenario_config(str(tmp_path / "none.toml"))
    with pytest.raises(ScenarioConfigError, match="the catalogue has"):
        load_scenario_config("exp9")
    with pytest.raises(ScenarioConfigError, match="measurement.kind"):
        load_scenario_config(str(write(tmp_path, resolve("exp1")[1].replace('kind = "linear"', 'kind = "bearing"'))))


def test_explicit_sensor_layout(tmp_path):
    text = BASE.replace('layout = "ring"', 'layout = "explicit"\npositions = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]')
    text = text.replace("count = 10", "count = 2")
    cfg = load_scenario_config(str(write(tmp_path, text)))
    np.testing.assert_array_equal(cfg.spec.sensors[1], [100.0, 0.0, 0.0])
    with pytest.raises(ScenarioConfigError, match="sensors.positions"):
        load_scenario_config(str(write(tmp_path, text.replace("count = 2", "count = 3"))))
