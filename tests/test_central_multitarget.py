"""The centralized many-target tracker and Stone Soup's comparator on bearing-only and mixed networks (issue 34,
item 3): fusion/multitarget/central.py, study/stonesoup_bearing.py.

On ``mt-bearing`` (8 cameras on a ring, 6 targets, P_D 0.85, clutter) one zentrack tracker of every scan
triangulates every target once and holds it; on a mixed network (``mt-bearing`` with two cameras made radars,
tests/test_mixed_network.py) it updates each scan with its own sensor's model; both beat the lone nodes.
Stone Soup's tracker, its held tracks started from zentrack's triangulation of the leftover bearings, holds every
target of a clean bearing scenario and of the mixed one. Both delete a track K steps after its last return (Stone
Soup's deleter counts timestamps, i.e. steps: the comparator once gave it K x M).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_mixed_network import KINDS, mixed, mixed_text

from zentrack.bench.multitarget import PARTS, score, truth_sets
from zentrack.cli import main
from zentrack.config.scenario_config import load_scenario_config, parse, resize, resolve
from zentrack.fusion.multitarget.central import make_central_tracker
from zentrack.study.multitarget_runs import MethodRun, node_settings, run_alone, run_centralized, run_distributed
from zentrack.study.stonesoup_multitarget import run_stonesoup

NEAR = 25.0  # m: a track "on" a target (mt-bearing's 0.005 rad at 2 km is 10 m)


def scenario(name: str, replace: dict[str, str]):
    text = resolve(name)[1]
    for old, new in replace.items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return parse(f"{name}.toml", text)


def held(run: MethodRun, data, k: int) -> tuple[np.ndarray, int]:
    """At step k: each present target's distance to the nearest track of the (one) view, and the tracks."""
    _, positions = run.views[0][k]
    truth = data.truth[k, data.alive[k], :3]
    if not len(positions):
        return np.full(len(truth), np.inf), 0
    return np.linalg.norm(truth[:, None] - positions[None], axis=-1).min(axis=1), len(positions)


def gospa_of(run: MethodRun, data) -> float:
    return float(np.mean(score(run, truth_sets(data), data.gospa_cutoff)["gospa"]))


@pytest.fixture(scope="module")
def bearing():
    cfg = load_scenario_config("mt-bearing", multitarget=True)
    resize(cfg, steps=20)
    return cfg, cfg.multitarget_data(seed=0), node_settings(cfg)


def test_the_centre_triangulates_every_bearing_target_once_and_beats_the_lone_nodes(bearing):
    """Three cameras' rays must meet before a track starts (M of N confirms it two steps later): from step 4 on
    every target has a confirmed track on it and there is no other (a target six cameras see makes two triangles
    of fresh rays in one step: started once)."""
    cfg, data, settings = bearing
    central = run_centralized(data, settings)
    for k in range(4, data.steps):
        distance, tracks = held(central, data, k)
        assert distance.max() < NEAR and tracks == len(distance), (k, distance, tracks)
    alone = run_alone(data, settings)
    assert gospa_of(central, data) < 0.5 * gospa_of(alone, data)  # a lone camera starts nothing


def test_the_mixed_centre_takes_each_scan_with_its_sensors_model():
    cfg = mixed(steps=15)
    data, settings = cfg.multitarget_data(seed=0), node_settings(cfg)
    tracker = make_central_tracker(settings)
    for i, kind in enumerate(KINDS):
        assert tracker.model_of(data.scan(0, i)).measurement.dim == (2 if kind == "bearing" else 3), i
    central = run_centralized(data, settings)
    for k in range(4, data.steps):
        distance, _ = held(central, data, k)
        assert distance.max() < NEAR, (k, distance)
    network, alone = run_distributed(data, settings, cfg), run_alone(data, settings)
    assert gospa_of(central, data) < min(gospa_of(network, data), gospa_of(alone, data))


def test_stonesoup_holds_every_target_of_a_clean_bearing_scenario():
    """P_D 1, no clutter: Stone Soup's held tracks start at the first triangle (the third camera's scan of step 0)
    and are released after M + 1 updates, within the same step; it then holds the six targets and nothing else."""
    cfg = scenario("mt-bearing", {"steps = 150 ": "steps = 6 ", "detection_prob = 0.85": "detection_prob = 1.0",
                                     "clutter_rate = 3.0": "clutter_rate = 0.0"})
    data = cfg.multitarget_data(seed=0)
    run = run_stonesoup(data, node_settings(cfg))
    for k in range(1, data.steps):
        distance, tracks = held(run, data, k)
        assert distance.max() < NEAR and tracks == 6, (k, distance, tracks)


def test_stonesoup_on_a_mixed_network_holds_every_target():
    cfg = mixed(steps=8)
    data = cfg.multitarget_data(seed=0)
    run = run_stonesoup(data, node_settings(cfg))
    for k in range(2, data.steps):
        distance, _ = held(run, data, k)
        assert distance.max() < NEAR, (k, distance)


@pytest.mark.parametrize("runner", [run_centralized, run_stonesoup])
def test_a_track_is_deleted_k_steps_after_its_last_return(runner):
    """mt-crossing, P_D 1, no clutter, every return cut from step 6 on: zentrack's and Stone Soup's tracks coast
    K = 5 steps and are gone at the fifth (Stone Soup's deleter counts distinct timestamps, one per step)."""
    cfg = scenario("mt-crossing", {"steps = 120 ": "steps = 16 ", "detection_prob = 0.9": "detection_prob = 1.0",
                                       "clutter_rate = 5.0": "clutter_rate = 0.0"})
    data = cfg.multitarget_data(seed=0)
    data.counts[6:] = 0
    run = runner(data, node_settings(cfg))
    counts = [len(ids) for ids, _ in run.views[0]]
    assert counts[5] == 4 and counts[9] == 4 and counts[10:] == [0] * 6, counts


def test_the_bench_takes_a_mixed_network_with_every_method(tmp_path):
    path, out = tmp_path / "mixed.toml", tmp_path / "mixed.json"
    path.write_text(mixed_text({"steps = 150 ": "steps = 6 "}))
    assert main(["bench", "multitarget", "--scenario", str(path), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    # (the PMBM row takes point sensors only: left out of a mixed network, in one line)
    assert list(result["methods"]) == ["alone", "distributed", "centralized", "stonesoup", "stonesoup-jpda"]
    assert set(result["settings"]) == {"bearing", "point"}
    for method, row in result["methods"].items():
        assert sum(row[p] for p in PARTS) == pytest.approx(row["mean_squared_gospa"]), method
        assert len(row["per_node_gospa"]) == (8 if method in ("alone", "distributed") else 1)
    assert result["aims"]["distributed_over_centralized"] is not None
