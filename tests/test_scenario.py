"""Scenarios: determinism, per-run reproducibility, exact file round trip, precise errors on bad files."""
from __future__ import annotations

import json
from dataclasses import fields

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.config.scenario_file import ScenarioFileError, load_scenario, save_scenario
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.scenario_spec import ring_sensor_positions
from zentrack.truth.simulation.simulate import simulate


def test_simulation_is_deterministic_and_runs_do_not_depend_on_r():
    spec = builtin_spec("exp2", nodes=4, steps=50)
    a = simulate(spec, runs=3, seed=7)
    b = simulate(spec, runs=3, seed=7)
    one = simulate(spec, runs=1, seed=7)
    np.testing.assert_array_equal(a.measurements, b.measurements)
    np.testing.assert_array_equal(a.truth[0], one.truth[0])
    np.testing.assert_array_equal(a.measurements[0], one.measurements[0])
    assert not np.array_equal(a.truth[0], a.truth[1])
    assert not np.array_equal(simulate(spec, runs=1, seed=8).truth, one.truth)


def test_exp2_scenario_matches_the_paper():
    scn = simulate(builtin_spec("exp2"), runs=1, seed=0)
    assert (scn.steps, scn.nodes, scn.ts) == (1000, 10, 0.1)
    np.testing.assert_array_equal(scn.truth[0, 0], [0, 0, 0, 2.0, 1.0, 1.5])
    np.testing.assert_allclose(scn.sensors[1], [400 * np.cos(0.2 * np.pi), 400 * np.sin(0.2 * np.pi), 50 * np.sin(0.4 * np.pi)])
    np.testing.assert_allclose(scn.noise_cov[0], (np.pi / 180) ** 2 * np.eye(2))
    np.testing.assert_allclose(scn.weights[0, [0, 1, 9]], [0.5, 0.25, 0.25])
    assert np.all(np.abs(scn.measurements) <= np.pi)
    np.testing.assert_allclose(ring_sensor_positions(4)[:, 2], 0.0, atol=1e-12)


def test_exp1_truth_follows_eq_63():
    scn = simulate(builtin_spec("exp1", steps=5), runs=1, seed=3)
    x = scn.truth[0]
    ts = 0.1
    for k in range(4):
        f = np.sin(x[k, 0] ** 2 + x[k, 1] ** 2) + 0.3 * np.sin(0.1 * k)
        nominal = np.array([x[k, 0] + ts * x[k, 1], -ts * x[k, 0] + x[k, 1] + ts * f])
        noise = x[k + 1] - nominal
        assert np.all(np.abs(noise) < 5 * np.sqrt(0.1))
    np.testing.assert_allclose(scn.lumped[0, :, 0], np.sin((x**2).sum(axis=1)) + 0.3 * np.sin(0.1 * np.arange(5)))


@pytest.mark.parametrize("name", ["exp1", "exp2", "exp2-point"])
def test_scenario_file_round_trips_exactly(tmp_path, name):
    scn = simulate(builtin_spec(name, nodes=3, steps=20), runs=2, seed=4)
    scn.present[0, 3, 1] = False
    path = save_scenario(tmp_path / "s.npz", scn)
    back = load_scenario(path)
    for f in fields(ScenarioData):
        a, b = getattr(scn, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            assert a.dtype.kind == b.dtype.kind and a.shape == b.shape, f.name
            np.testing.assert_array_equal(a, b, err_msg=f.name)
        elif a is None:
            assert b is None
        else:
            assert a == b, f.name


def _corrupt(tmp_path, scn, **changes):
    path = save_scenario(tmp_path / "good.npz", scn)
    with np.load(path) as npz:
        data = {k: npz[k] for k in npz.files}
    for k, v in changes.items():
        if v is None:
            del data[k]
        else:
            data[k] = v
    bad = tmp_path / "bad.npz"
    np.savez(bad, **data)
    return bad


@pytest.mark.parametrize(
    "change, message",
    [
        ({"truth": None}, "missing key 'truth'"),
        ({"weights": np.ones((3, 3))}, "row-stochastic"),
        ({"noise_cov": -np.ones((3, 2, 2))}, "noise_cov"),
        ({"sensors": np.ones((3, 2))}, "sensors|measurements"),
        ({"schema_version": np.int64(9)}, "schema_version 9"),
        ({"plant": np.str_("boat")}, "unknown plant"),
        ({"plant_params": np.str_('{"wings": 2}')}, "no parameter"),
        ({"plant_params": np.str_("{not json")}, "not JSON"),
        ({"measurement": np.str_("sonar")}, "measurement"),
        ({"ts": np.str_("fast")}, "'ts' must be a number"),
        ({"p0": np.full((6, 6), np.nan)}, "NaN"),
        ({"truth": np.array([object()], dtype=object)}, "'truth'"),
    ],
)
def test_bad_scenario_files_get_precise_errors(tmp_path, change, message):
    scn = simulate(builtin_spec("exp2", nodes=3, steps=10), runs=1, seed=1)
    with pytest.raises(ScenarioFileError, match=message) as err:
        load_scenario(_corrupt(tmp_path, scn, **change))
    assert "bad.npz" in str(err.value)


def test_unreadable_and_missing_files(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ScenarioFileError, match="not a readable"):
        load_scenario(junk)
    with pytest.raises(ScenarioFileError, match="no such scenario file"):
        load_scenario(tmp_path / "nope.npz")


def test_plant_params_are_json(tmp_path):
    scn = simulate(builtin_spec("exp2", nodes=2, steps=5), runs=1, seed=1)
    path = save_scenario(tmp_path / "x.npz", scn)
    with np.load(path) as npz:
        assert json.loads(str(npz["plant_params"])) == {"alpha": 1.2, "beta": 2.5, "sigma_w": 1.0}
