"""Scenario validation (issue: accuracy against the limit): a graph that cannot diffuse, bearings that are not
radians, and runs that lost the target are caught and reported, not scored as healthy."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.config.scenario_file import save_scenario
from zentrack.fusion.graphs import unreachable
from zentrack.study.metrics import divergence_steps
from zentrack.study.simulator import evaluate, run_filter, scene_extent
from zentrack.truth.simulation.simulate import simulate


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    folder = tmp_path_factory.mktemp("validation")
    scn = simulate(builtin_spec("exp2", nodes=4, steps=30), runs=1, seed=0)
    path = save_scenario(folder / "ok.npz", scn)
    return folder, dict(np.load(path, allow_pickle=False))


def _sim(path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zentrack", "sim", "--scenario-file", str(path), "--filter", "teskf",
                           "--fusion", "ci"],
                          capture_output=True, text=True, timeout=120)


def _directed_ring(m: int) -> np.ndarray:
    w = 0.5 * np.eye(m)
    for i in range(m):
        w[i, (i + 1) % m] = 0.5  # i hears i+1 only: strongly connected, one way round
    return w


@pytest.mark.parametrize("case, key, rule", [
    ("identity", "weights", "not strongly connected"),
    ("one-way", "weights", "not strongly connected"),
    ("no-self-weight", "weights", "w_ii > 0"),
    ("azimuth-degrees", "measurements", "azimuth(s) outside (-pi, pi] radians"),
    ("elevation-degrees", "measurements", "elevation(s) outside [-pi/2, pi/2] radians"),
])
def test_a_scenario_file_that_breaks_a_rule_exits_2_with_one_line_naming_file_key_and_rule(saved, case, key, rule):
    folder, data = saved
    bad = dict(data)
    if case == "identity":
        bad["weights"] = np.eye(4)
    elif case == "one-way":  # node 0 hears node 1, nobody hears node 0: no path from 0's information to anyone
        bad["weights"] = np.array([[0.5, 0.5, 0, 0], [0, 0.5, 0.5, 0], [0, 0.5, 0.5, 0], [0, 0, 0.5, 0.5]])
        bad["adjacency"] = np.ones((4, 4), dtype=bool) & ~np.eye(4, dtype=bool)
    elif case == "no-self-weight":
        bad["weights"] = np.array([[0, 0.5, 0, 0.5], [0.5, 0, 0.5, 0], [0, 0.5, 0, 0.5], [0.5, 0, 0.5, 0]])
    elif case == "azimuth-degrees":
        bad["measurements"] = np.degrees(data["measurements"])
    else:
        z = data["measurements"].copy()
        z[..., 1] = np.degrees(z[..., 1]) + 100.0  # every elevation far outside the pole
        bad["measurements"] = z
    path = folder / f"{case}.npz"
    np.savez(path, **bad)
    done = _sim(path)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert str(path) in lines[0] and f": {key}:" in lines[0] and rule in lines[0], lines[0]


def test_a_valid_file_and_a_strongly_connected_one_way_ring_are_accepted(saved):
    folder, data = saved
    assert _sim(folder / "ok.npz").returncode == 0
    assert unreachable(_directed_ring(5) > 0) == []
    assert unreachable(np.eye(3) > 0) == [1, 2]


def test_divergence_is_the_error_beyond_the_scene_whatever_the_scale():
    err = np.zeros((4, 30, 2, 6))
    err[1, 4:, :, 0] = 50.0  # run 1: 50 units off from step 4 on
    err[2, 7:, 0, 1] = np.nan  # run 2: non-finite from step 7 on
    err[3, 5, :, 2] = 1e6  # run 3: one wild step, then back: a spike, not a loss
    extent = np.full(4, 40.0)
    assert divergence_steps(err, extent, [0, 1, 2]).tolist() == [-1, 4, 7, -1]
    assert divergence_steps(err * 1e-3, extent * 1e-3, [0, 1, 2]).tolist() == [-1, 4, 7, -1]  # km, not m
    assert divergence_steps(err, extent + 20.0, [0, 1, 2]).tolist() == [-1, -1, 7, -1]
    assert divergence_steps(err[:, :3], extent, [0, 1, 2]).tolist() == [-1, -1, -1, -1]  # 3 steps: none all beyond


def test_a_disconnected_network_run_is_reported_diverged_per_run_with_its_rmse(tmp_path):
    """Disconnected (identity weights) bearing-only DTESKF loses the target: each run says so, from the step the
    error left the scene, and keeps the RMSE that shows how far off it went (the simulator itself accepts the
    weights; files are refused, above)."""
    scn = simulate(builtin_spec("exp2", nodes=10, steps=300), runs=3, seed=0)
    healthy = evaluate(scn, run_filter(scn, "dteskf"))
    assert healthy["diverged_runs"] == 0 and healthy["diverged_at"] == [-1, -1, -1]
    scn.weights = np.eye(scn.nodes)
    broken = evaluate(scn, run_filter(scn, "dteskf"))
    assert broken["diverged_runs"] == 3 and all(k > 0 for k in broken["diverged_at"])
    extent = scene_extent(scn)
    assert np.all(np.isfinite(broken["rmse"]["p"])) and np.all(np.array(broken["rmse"]["p"]) > 0.5 * extent)
    # the sim command's JSON carries the per-run steps
    out = tmp_path / "sim.json"
    done = subprocess.run([sys.executable, "-m", "zentrack", "sim", "--filter", "teskf", "--steps", "50",
                           "--json", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(out.read_text())["filters"]["teskf+ci"]["diverged_at"] == [-1]
