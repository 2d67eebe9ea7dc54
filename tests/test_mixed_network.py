"""A mixed many-target network (issue 34): bearing-only cameras and point radars in one network, each node
tracking by its own sensor's kind (zentrack/config/scenario_kinds.py, truth/simulation/mt_sensors.py).

Built on ``mt-bearing`` (8 bearing sensors on a ring) with sensors 2 and 6 made point radars: the truth measures
each sensor by its kind, each node's slice carries its kind and takes scans from its neighbours of that kind only,
and the bearing nodes next to a radar (which cannot triangulate: one bearing neighbour, two rays) hold the targets
through the radars' track lists. The lockstep live run of the real mixed scenario ``ais-nyharbor`` equals the
in-process network in tests/test_multitarget_live.py.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from zentrack.cli import main
from zentrack.config.node_config import RunParameters
from zentrack.config.node_slice import node_config_from_spec
from zentrack.config.scenario_config import ScenarioConfigError, parse, resolve
from zentrack.study.multitarget_runs import node_settings, run_alone, run_distributed
from zentrack.truth.simulation.mt_sensors import boresights, in_field_of_view

KINDS = ["bearing", "bearing", "point", "bearing", "bearing", "bearing", "point", "bearing"]
MIXED = {
    "count = 8\n": "count = 8\nkinds = " + str(KINDS).replace("'", '"') + "\n",
    "noise_std = 0.005       # rad": "noise_stds = [0.005, 0.005, 5.0, 0.005, 0.005, 0.005, 5.0, 0.005]",
    "[graph]": "[sensing.point]\nfov_azimuth = 6.283185307179586\nclutter_rate = 1.0\n\n[graph]",
}


def mixed_text(replace: dict[str, str] | None = None) -> str:
    text = resolve("mt-bearing")[1]
    for old, new in {**MIXED, **(replace or {})}.items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


def mixed(steps: int = 40, replace: dict[str, str] | None = None):
    return parse("mixed.toml", mixed_text({"steps = 150 ": f"steps = {steps} ", **(replace or {})}))


def test_each_sensor_measures_by_its_own_kind_with_its_kinds_sensing():
    cfg = mixed()
    data = cfg.multitarget_data(seed=1)
    assert data.measurement == "mixed" and data.kinds == tuple(KINDS)
    point = cfg.multitarget.sensing_of("point")
    assert point.fov_azimuth == pytest.approx(2 * np.pi) and point.clutter_rate == 1.0
    assert point.max_range == cfg.multitarget.sensing.max_range  # from [sensing]
    for i, kind in enumerate(KINDS):
        scan = data.scan(5, i)
        dim = 2 if kind == "bearing" else 3
        assert scan.returns.shape[1] == dim and scan.noise_cov.shape == (dim, dim), i
        assert np.allclose(np.diag(scan.noise_cov), (0.005 if kind == "bearing" else 5.0) ** 2)
    # the radars see all round, the cameras only their 1.6 rad: what each is scored in view follows its kind
    k, alive = 20, data.alive[20]
    position = data.truth[k, alive, :3]
    for i, kind in enumerate(KINDS):
        sensing = cfg.multitarget.sensing_of(kind)
        expected = in_field_of_view(position[None, None], data.sensors[i:i + 1],
                                    boresights(data.sensors[i:i + 1], cfg.multitarget.targets.centre), sensing)[0, 0]
        assert np.array_equal(data.in_view[k, i, alive], expected), i
    # a radar's detection is the target's position plus 5 m noise; a camera's an angle
    for i in (2, 6):
        origin = data.origins(k, i)
        z = data.scan(k, i).returns[origin >= 0]
        assert np.all(np.linalg.norm(z - data.truth[k, origin[origin >= 0], :3], axis=1) < 5 * 5.0 * 3)


def test_each_nodes_slice_carries_its_kind_and_takes_scans_only_from_its_own_kind():
    cfg = mixed()
    params = {"detection_prob": 0.85, "clutter_density": 1e-3}
    for i, kind in enumerate(KINDS):
        node = node_config_from_spec(cfg.spec, cfg.ts, 0, i, RunParameters(), params, cfg.multitarget.kinds)
        assert node.measurement == kind and node.measurement_dim == (2 if kind == "bearing" else 3)
        assert node.scan_neighbours == [j for j in node.neighbours if KINDS[j] == kind], i
    settings = node_settings(cfg)
    assert [s.measurement for s in settings] == KINDS
    assert settings[2].clutter_density != settings[0].clutter_density  # per m^3 and per rad^2


def test_bearing_nodes_that_cannot_triangulate_hold_the_targets_from_the_radars_lists():
    cfg = mixed(steps=15)
    data = cfg.multitarget_data(seed=0)
    settings = node_settings(cfg)
    alone, network = run_alone(data, settings), run_distributed(data, settings, cfg)
    for node in (1, 3, 5, 7):  # one bearing neighbour and a radar: two rays, no triangulated birth of its own
        assert all(len(ids) == 0 for ids, _ in alone.views[node]), node
        k = data.steps - 1
        ids, positions = network.views[node][k]
        truth = data.truth[k, data.alive[k], :3]
        near = [np.min(np.linalg.norm(truth - x, axis=1)) < 50.0 for x in positions]
        assert len(ids) >= 5 and sum(near) >= 5, (node, len(ids), sum(near))  # of the 6 targets


@pytest.mark.parametrize(("replace", "key"), [
    ({'"point", "bearing", "bearing", "bearing", "point"': '"sonar", "bearing", "bearing", "bearing", "point"'},
     "sensors.kinds"),
    ({"kinds = [": "kinds = [\"bearing\", "}, "sensors.kinds"),
    ({"[0.005, 0.005, 5.0,": "[0.005, 0.005, 5.0, 0.005, 0.005, 5.0, 0.005, 5.0] #"}, "measurement.noise_stds"),
    ({"[sensing.point]": "[sensing.radar]"}, "sensing.radar"),
    ({"clutter_rate = 1.0": "clutter_rate = 1.0\nbeams = 2"}, "sensing.point.beams"),
])
def test_a_bad_mixed_network_is_refused_in_one_line_naming_the_key(replace, key):
    with pytest.raises(ScenarioConfigError) as err:
        mixed(replace=replace)
    text = str(err.value)
    assert f": {key}: " in text and "\n" not in text, text


def exit_status(argv: list[str]) -> int | str | None:
    """``zentrack``'s exit status (a refused argument exits from argparse)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def test_a_network_in_which_no_node_can_start_a_track_exits_2_in_one_line(tmp_path, capsys):
    # two cameras: two rays meet anywhere, so neither starts a track, and there is no radar
    text = resolve("mt-bearing")[1].replace("count = 8\n", "count = 2\n")
    path = tmp_path / "no-births.toml"
    path.write_text(text)
    assert exit_status(["sim", "--scenario", str(path), "--steps", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "graph.kind: no node can start a track" in err[0], err
    path.write_text(mixed_text({"kinds = [": 'kinds = ["sonar", '}))
    assert exit_status(["run", "--scenario", str(path), "--steps", "5", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensors.kinds" in err[0] and "'sonar'" in err[0], err


@pytest.mark.slow
def test_a_run_into_an_earlier_runs_folder_hands_its_nodes_their_own_slices(tmp_path, capsys):
    """A second run in the same --out once reused the first run's node slices (written once, for restarts): the
    cameras' slices made the radars refuse every 3-D scan of the mixed network."""
    out = tmp_path / "run"
    assert main(["run", "--scenario", "mt-bearing", "--steps", "3", "--timing", "lockstep", "--out", str(out)]) == 0
    first = json.loads((out / "config" / "node-2.json").read_text())
    assert first["measurement"] == "bearing"
    path = tmp_path / "mixed.toml"
    path.write_text(mixed_text())
    assert main(["run", "--scenario", str(path), "--steps", "10", "--timing", "lockstep", "--out", str(out)]) == 0
    assert json.loads((out / "config" / "node-2.json").read_text())["measurement"] == "point"
    summary = json.loads((out / "summary.json").read_text())
    assert not summary["network"]["refused"], summary["network"]["refused"]
