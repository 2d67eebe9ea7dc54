"""One scenario catalogue: every built-in scenario is a TOML file in deploy/scenarios/, `zentrack scenarios` lists
them all with a description, every command takes every name, and the files reproduce the Python specs they
replaced to the last bit."""
from __future__ import annotations

import argparse
import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from zentrack.cli import build_parser, main
from zentrack.config import catalogue
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_config import builtin_spec, load_scenario_config
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.scenario_spec import ScenarioSpec, ring_sensor_positions
from zentrack.truth.simulation.simulate import simulate

ROOT = Path(__file__).resolve().parent.parent
FILES = sorted(p.stem for p in (ROOT / "deploy" / "scenarios").glob("*.toml"))
SINGLE = [name for name in FILES if "[targets]" not in catalogue.text(name)]


# ------------------------------------------------------------------ the Python specs the catalogue replaced
# Frozen copies of fusion/scenario.py's exp1_spec, exp2_spec and irregular_spec as they were when their TOML
# files took their place: the reference the files must reproduce exactly (same numbers in `zentrack sim` and the
# benches). Do not edit them to make a test pass.

def _old_exp1(nodes: int = 10, steps: int = 2500) -> ScenarioSpec:
    return ScenarioSpec(name="exp1", plant="exp1", plant_params={"q": 0.1, "d_amp": 0.3, "d_freq": 0.1},
                        measurement="linear", noise_std=5.0, sensors=np.zeros((nodes, 3)), x0=np.array([0.0, 1.0]),
                        p0=np.eye(2), steps=steps, linear_matrix=np.array([[1.0, 0.0]]))


def _old_exp2(nodes: int = 10, steps: int = 1000, measurement: str = "bearing") -> ScenarioSpec:
    return ScenarioSpec(name="exp2" if measurement == "bearing" else "exp2-point", plant="cv3d",
                        plant_params={"sigma_w": 1.0, "alpha": 1.2, "beta": 2.5}, measurement=measurement,
                        noise_std=np.pi / 180.0 if measurement == "bearing" else 5.0,
                        sensors=ring_sensor_positions(nodes), x0=np.array([0.0, 0.0, 0.0, 2.0, 1.0, 1.5]),
                        p0=np.eye(6), steps=steps)


def _old_irregular(nodes: int = 10, steps: int = 1000) -> ScenarioSpec:
    from zentrack.fusion.consensus_weights import random_graph

    rng = np.random.default_rng(16)
    sensors = np.column_stack([rng.uniform(-500.0, 500.0, (nodes, 2)), rng.uniform(0.0, 100.0, nodes)])
    adj = random_graph(nodes, 0.3, rng)
    return ScenarioSpec(
        name="exp2-irregular", plant="cv3d", plant_params={"sigma_w": 0.2, "alpha": 1.2, "beta": 2.5, "turn_rate": 0.2},
        measurement="bearing", noise_std=np.pi / 180.0, sensors=sensors, x0=np.array([0.0, 0.0, 0.0, 2.0, 1.0, 1.5]),
        p0=np.eye(6), steps=steps, graph="explicit", adjacency=adj, consensus_weights="metropolis")


OLD = {"exp1": _old_exp1, "exp2": _old_exp2, "exp2-point": lambda **kw: _old_exp2(measurement="point", **kw),
       "exp2-irregular": _old_irregular}


def assert_same_data(a: ScenarioData, b: ScenarioData) -> None:
    for f in dataclasses.fields(ScenarioData):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert (x is None) == (y is None) and (x is None or np.array_equal(x, y)), f.name
            assert x is None or np.asarray(x).dtype == np.asarray(y).dtype, f.name
        else:
            assert x == y, f.name


@pytest.mark.parametrize("name, size", [("exp1", {}), ("exp1", {"nodes": 3, "steps": 200}), ("exp2", {}),
                                        ("exp2", {"nodes": 4, "steps": 50}), ("exp2-point", {}),
                                        ("exp2-point", {"nodes": 3, "steps": 20}), ("exp2-irregular", {}),
                                        ("exp2-irregular", {"steps": 300})])
def test_the_catalogue_files_reproduce_the_python_specs_they_replaced(name, size):
    old, new = OLD[name](**size), builtin_spec(name, **size)
    assert (new.name, new.plant, new.measurement, new.steps, new.graph) == (old.name, old.plant, old.measurement,
                                                                            old.steps, old.graph)
    assert new.plant_params == old.plant_params and new.noise_std == old.noise_std
    for key in ("sensors", "x0", "p0", "adjacency", "linear_matrix"):
        a, b = getattr(new, key), getattr(old, key)
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b)), key
    cfg = load_scenario_config(name)
    ts = cfg.ts
    assert ts == 0.1 and cfg.seed == 0 and cfg.filter_kind == "teskf" and cfg.fusion == "ci" and cfg.theta is None
    assert_same_data(simulate(new, runs=3, seed=7, ts=ts), simulate(old, runs=3, seed=7))


def test_an_explicit_layout_refuses_another_node_count_in_one_line():
    with pytest.raises(ValueError, match="explicit sensors fix N = 10"):
        builtin_spec("exp2-irregular", nodes=6)


# ------------------------------------------------------------------ the listing


def test_zentrack_scenarios_lists_every_file_with_a_one_line_description(capsys):
    assert FILES == catalogue.names() and len(FILES) >= 14 and "exp2-irregular" in FILES
    assert main(["scenarios"]) == 0
    lines = capsys.readouterr().out.splitlines()
    listed = {line.split()[0]: line.split(None, 1)[1] for line in lines[:-1]}
    assert sorted(listed) == FILES
    for name, text in listed.items():
        assert len(text) > 20 and text == catalogue.description(name), name
        assert load_scenario_config(name, multitarget=True).spec.name == name  # the file's own name is its catalogue name
    assert main(["scenarios", "--json"]) == 0
    assert sorted(json.loads(capsys.readouterr().out)) == FILES


def test_every_help_that_takes_a_scenario_points_to_the_catalogue_which_lists_every_name(capsys):
    """The catalogue is listed once, by `zentrack scenarios` (issue 50: not in every command's help)."""
    for command in (["sim"], ["run"], ["node"], ["truth"], ["compose"], ["soak"]):
        parser = build_parser(command)
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command[0]]
        text = re.sub(r"-\s+", "-", " ".join(sub.format_help().split()))
        assert "`zentrack scenarios` lists them" in text, (command, text)
    assert main(["scenarios"]) == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in FILES)


# ------------------------------------------------------------------ every command takes every name


@pytest.mark.parametrize("name", SINGLE)
def test_every_catalogue_scenario_runs_batched_and_sets_up_live(name, tmp_path):
    out = tmp_path / "sim.json"
    assert main(["sim", "--scenario", name, "--steps", "3", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    cfg = load_scenario_config(name)
    assert figures["scenario"] == name and list(figures["filters"]) == [f"{cfg.filter_kind}+{cfg.fusion}"]
    # (sensors of their own, [sensor_timing], run in realtime only: refused in lockstep, tests/test_sensor_timing.py)
    timing = "realtime" if cfg.sensor_timing is not None else "lockstep"
    argv = ["run", "--scenario", name, "--steps", "3", "--timing", timing, "--out", str(tmp_path / "run")]
    setup = resolve_setup(build_parser(argv).parse_args(argv))
    assert (setup.filter_kind, setup.fusion, setup.mode, setup.spec.steps) == (cfg.filter_kind, cfg.fusion,
                                                                               timing, 3)
    assert setup.node_config(0).node == 0


def test_a_path_works_where_a_name_does(tmp_path, capsys):
    path = tmp_path / "mine.toml"
    path.write_text(catalogue.text("exp1"))
    assert main(["sim", "--scenario", str(path), "--steps", "5"]) == 0
    assert "scenario exp1: 10 nodes, 5 steps" in capsys.readouterr().out


def test_a_scenario_that_cannot_run_live_says_why_in_one_line(tmp_path, capsys):
    """The centralized filter is one centre with every measurement: sim runs it, a live run refuses it."""
    path = tmp_path / "central.toml"
    path.write_text(catalogue.text("exp2").replace("[timing]", '[fusion]\nrule = "centralized"\n\n[timing]'))
    assert main(["sim", "--scenario", str(path), "--steps", "5"]) == 0
    assert "teskf+centralized" in capsys.readouterr().out
    for command in (["run", "--out", str(tmp_path / "o")], ["truth"], ["node", "--id", "0"]):
        assert main([*command, "--scenario", str(path), "--steps", "5"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "centralized" in err and "zentrack sim" in err, err
    assert main(["run", "--scenario", "exp2", "--fusion", "centralized", "--out", str(tmp_path / "o")]) == 2
    assert "runs only in the batched simulator" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_an_unknown_name_lists_the_catalogue_in_one_line(capsys):
    for command in (["sim"], ["run", "--out", "x"], ["compose"], ["soak", "--out", "x"]):
        with pytest.raises(SystemExit) as done:
            main([*command, "--scenario", "exp9"])
        assert done.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "exp2-irregular" in err and "zentrack scenarios" in err, err
