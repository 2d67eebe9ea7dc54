"""Scenarios with clutter in the batched simulator: ragged scans drawn beside the truth, and the clutter
filters running distributed on them (a particle cloud moved onto each fused prior)."""
import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.study.simulator import evaluate, run_filter
from zentrack.truth.simulation.clutter import ClutterSpec
from zentrack.truth.simulation.simulate import simulate

WINDOW = {"az_window": np.array([-np.pi, np.pi]), "el_window": np.array([-0.3, 1.2])}


def clutter_scenario(runs=2, steps=60, p_d=0.9, count=3, seed=3):
    spec = builtin_spec("exp2", nodes=3, steps=steps)
    spec.clutter = ClutterSpec(p_d=p_d, mode="fixed", count=count, **WINDOW)
    return simulate(spec, runs=runs, seed=seed)


def test_clutter_scans_sit_beside_an_unchanged_truth():
    scn = clutter_scenario()
    scn.validate()
    plain = simulate(builtin_spec("exp2", nodes=3, steps=60), runs=2, seed=3)
    np.testing.assert_array_equal(scn.truth, plain.truth)  # clutter draws from a stream of its own
    found = scn.scan_target >= 0
    np.testing.assert_array_equal(scn.scan_counts, 3 + found)
    np.testing.assert_array_equal(scn.present, found)
    for r, k, i in zip(*np.nonzero(found)):
        np.testing.assert_array_equal(scn.scan(r, k, i)[scn.scan_target[r, k, i]], scn.measurements[r, k, i])
    assert 0.8 < found.mean() < 1.0
    # run r is the same whatever the number of runs
    one = clutter_scenario(runs=1)
    np.testing.assert_array_equal(one.scan_returns[0, ..., : one.scan_returns.shape[3], :],
                                  scn.scan_returns[0, ..., : one.scan_returns.shape[3], :])
    np.testing.assert_array_equal(scn.run(1).scan_counts[0], scn.scan_counts[1])


def test_a_malformed_scan_array_is_refused_by_name():
    scn = clutter_scenario(runs=1, steps=5)
    scn.scan_counts = scn.scan_counts + 100
    with pytest.raises(ValueError, match="scan_counts"):
        scn.validate()


@pytest.mark.parametrize("name", ["dpda-fpf", "dpda-pf", "dpdaf-ekf", "dnn-ekf"])
def test_clutter_filters_track_distributed_on_ragged_scans(name):
    scn = clutter_scenario()
    res = run_filter(scn, name)
    out = evaluate(scn, res)
    assert out["diverged_runs"] == 0
    assert np.all(np.isfinite(res.mean)) and np.all(np.isfinite(res.cov))
    assert max(out["rmse"]["p"]) < 30.0, out["rmse"]


def test_clutter_filters_do_not_run_centralized():
    with pytest.raises(ValueError, match="distributed"):
        run_filter(clutter_scenario(runs=1, steps=5), "cpda-fpf")


def test_the_clutter_scenario_file_parses_and_replays_its_scans(tmp_path):
    from zentrack.config.scenario_config import load_scenario_config
    from zentrack.config.scenario_file import load_scenario, save_scenario

    cfg = load_scenario_config("fpf-clutter")
    assert cfg.spec.plant == "cv3d-cd" and cfg.spec.clutter is not None and cfg.filter_kind == "pda-fpf"
    cfg.spec.steps = 10
    scn = cfg.scenario_data()
    back = load_scenario(save_scenario(tmp_path / "s.npz", scn))
    for key in ("scan_returns", "scan_counts", "scan_target", "truth"):
        np.testing.assert_array_equal(getattr(back, key), getattr(scn, key))


@pytest.mark.parametrize("edit, problem", [
    (("count = 10", "count = 5000"), "clutter.count"),
    (('mode = "fixed"', 'mode = "burst"'), "clutter.mode"),
    (("az_window = [[-0.03, 0.184],", "az_window = [[0.184, -0.03],"), "clutter.az_window"),
    (("el_window = [[-0.003, 0.155], [0.006, 0.202], [-0.005, 0.143]]", "el_window = [0.1, 2.0]"), "clutter.el_window"),
    (('kind = "bearing"', 'kind = "point"'), "clutter"),
    (("em_steps = 10", "em_steps = 0"), "plant.em_steps"),
])
def test_a_bad_clutter_table_is_refused_naming_the_key(tmp_path, edit, problem):
    from importlib import resources

    from zentrack.config.scenario_config import ScenarioConfigError, load_scenario_config

    text = (resources.files("zentrack.scenarios") / "fpf-clutter.toml").read_text()
    assert edit[0] in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(ScenarioConfigError, match=problem.replace(".", r"\.")):
        load_scenario_config(str(path))


def test_a_one_return_filter_is_refused_on_a_cluttered_scenario():
    from zentrack.config.run_setup import RunSetup

    scn = clutter_scenario(runs=1, steps=5)
    with pytest.raises(ValueError, match="one return per scan.*pda-fpf"):
        RunSetup.from_data(scn, "teskf").run_parameters()
    RunSetup.from_data(scn, "pda-fpf").run_parameters()
