"""Many-target scenarios (issue 33, item 1): the catalogue's mt-* files and their simulated runs.

Births and deaths come at the stated times, detection and clutter have the configured statistics (P_D within a
binomial bound, clutter counts Poisson in mean and variance), every return lies in its sensor's field of view,
crossing targets really cross, a seed fixes the run, each bad key is refused in one line naming it, and every
single-target command refuses these scenarios in one line (exit 2). Geometry and expected values are
recomputed here from the definitions, not taken from the simulation module.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from zentrack.cli import main
from zentrack.config import catalogue
from zentrack.config.scenario_config import ScenarioConfigError, load_scenario_config, parse, resolve
from zentrack.truth.simulation.multitarget import CLUTTER, PADDING

MT = ("mt-crossing", "mt-birth-death", "mt-bearing", "mt-50")


def config(name: str, replace: dict[str, str] | None = None):
    """A catalogue many-target file, with text replaced (each old text must occur once)."""
    text = resolve(name)[1]
    for old, new in (replace or {}).items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return parse(f"{name}.toml", text)


def geometry(points: np.ndarray, sensor: np.ndarray, centre: np.ndarray):
    """Range, azimuth off the boresight (the direction to centre) and elevation of points (P, 3) from sensor."""
    d = points - sensor
    boresight = math.atan2(centre[1] - sensor[1], centre[0] - sensor[0])
    az = np.arctan2(d[:, 1], d[:, 0]) - boresight
    az = (az + np.pi) % (2 * np.pi) - np.pi
    return np.linalg.norm(d, axis=1), az, np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))


# ------------------------------------------------------------------ births, deaths, survival


def test_targets_appear_and_leave_at_the_stated_times():
    cfg = load_scenario_config("mt-birth-death", multitarget=True)
    data = cfg.multitarget_data()
    assert cfg.ts == 1.0
    births, deaths = [0, 0, 0, 30, 60, 90], [80, None, 150, None, 140, None]  # the file's seconds, ts = 1 s
    for i, (b, d) in enumerate(zip(births, deaths)):
        steps = np.flatnonzero(data.alive[:, i])
        assert steps[0] == b and steps[-1] == (data.steps - 1 if d is None else d - 1), i
        assert np.array_equal(steps, np.arange(steps[0], steps[-1] + 1)), i  # present without gaps
        assert np.all(np.isnan(data.truth[~data.alive[:, i], i])) and np.all(np.isfinite(data.truth[steps, i]))
    ids, states = data.truth_at(100)
    assert set(ids.tolist()) & set(range(6)) == {1, 2, 3, 4, 5} and states.shape == (ids.size, 6)


def test_poisson_births_and_geometric_survival_have_their_rates():
    rate, survival, lag = 0.1, 0.98, 20  # births per second (ts = 1 s), survival per step
    text = {"birth_rate = 0.02": f"birth_rate = {rate}", "survival_prob = 1.0": f"survival_prob = {survival}",
            "death_times = [80.0, 1e9, 150.0, 1e9, 140.0, 1e9]": ""}
    born, outlived, observable = [], 0, 0
    for seed in range(30):
        data = config("mt-birth-death", {**text, "seed = 0": f"seed = {seed}"}).multitarget_data()
        first = data.alive.argmax(axis=0)
        born.append(int(np.sum(first[6:] > 0)))
        seen = first + lag < data.steps  # whether "still present lag steps after birth" can be observed
        observable += int(seen.sum())
        outlived += int(data.alive[first[seen] + lag, np.flatnonzero(seen)].sum())
    expected = rate * (data.steps - 1)  # Poisson(rate ts) births at each step after the first
    assert abs(np.mean(born) - expected) < 4 * math.sqrt(expected / len(born)), (np.mean(born), expected)
    p = survival**lag  # P(lifetime > lag) of a geometric lifetime
    assert abs(outlived / observable - p) < 4 * math.sqrt(p * (1 - p) / observable), (outlived / observable, p)


# ------------------------------------------------------------------ detection and clutter statistics


@pytest.mark.parametrize("name", ["mt-crossing", "mt-bearing"])
def test_detections_follow_pd_and_clutter_is_poisson(name):
    cfg = load_scenario_config(name, multitarget=True)
    pd, rate = cfg.multitarget.sensing.detection_prob, cfg.multitarget.sensing.clutter_rate
    data = cfg.multitarget_data()
    detected = np.zeros(data.in_view.shape, dtype=bool)
    k, i, j = np.nonzero(data.origin >= 0)
    detected[k, i, data.origin[k, i, j]] = True
    assert not np.any(detected & ~data.in_view)  # only targets in view are detected
    n = int(data.in_view.sum())
    p_hat = detected.sum() / n
    assert n > 2000 and abs(p_hat - pd) < 4 * math.sqrt(pd * (1 - pd) / n), (p_hat, pd, n)
    clutter = (data.origin == CLUTTER).sum(axis=2).ravel()
    scans = clutter.size
    assert abs(clutter.mean() - rate) < 4 * math.sqrt(rate / scans), clutter.mean()
    # Poisson: variance = mean; the sample variance's spread is sqrt((lambda + 2 lambda^2) / N)
    assert abs(clutter.var(ddof=1) - rate) < 4 * math.sqrt((rate + 2 * rate**2) / scans), clutter.var(ddof=1)
    assert np.array_equal(data.counts, (data.origin != PADDING).sum(axis=2))


def test_a_target_in_no_sensor_view_is_never_detected_and_pd_one_detects_every_one_in_view():
    data = config("mt-birth-death", {"detection_prob = 0.9": "detection_prob = 1.0"}).multitarget_data()
    detected = np.zeros(data.in_view.shape, dtype=bool)
    k, i, j = np.nonzero(data.origin >= 0)
    detected[k, i, data.origin[k, i, j]] = True
    assert np.array_equal(detected, data.in_view) and not data.in_view.all() and data.in_view.any()


# ------------------------------------------------------------------ field of view and range


@pytest.mark.parametrize("name", ["mt-birth-death", "mt-bearing"])
def test_every_return_lies_in_its_sensors_field_of_view(name):
    cfg = load_scenario_config(name, multitarget=True)
    sensing, centre = cfg.multitarget.sensing, cfg.multitarget.targets.centre
    data = cfg.multitarget_data()
    sigma = float(cfg.spec.noise_std)
    lo, hi = sensing.fov_elevation
    half = sensing.fov_azimuth / 2
    for sensor in range(data.sensors.shape[0]):
        pose = data.sensors[sensor]
        for step in range(data.steps):
            z, origin = data.scan(step, sensor).validate().returns, data.origins(step, sensor)
            ids, states = data.truth_at(step)
            truth = dict(zip(ids.tolist(), states))
            if origin.size == 0:
                continue
            from_targets = np.array([truth[t][:3] for t in origin[origin >= 0]]).reshape(-1, 3)
            rng, az, el = geometry(from_targets, pose, centre)  # a detected target is in range and view
            assert np.all((rng <= sensing.max_range) & (np.abs(az) <= half) & (el >= lo) & (el <= hi))
            if data.measurement == "point":
                rng, az, el = geometry(z[origin == CLUTTER], pose, centre)
                assert np.all(rng <= sensing.max_range * (1 + 1e-12))
                assert np.all(np.linalg.norm(z[origin >= 0] - from_targets, axis=1) < 6 * sigma * math.sqrt(3))
            else:
                boresight = math.atan2(centre[1] - pose[1], centre[0] - pose[0])
                az = (z[origin == CLUTTER, 0] - boresight + np.pi) % (2 * np.pi) - np.pi
                el = z[origin == CLUTTER, 1]
                t_az = np.arctan2(from_targets[:, 1] - pose[1], from_targets[:, 0] - pose[0])
                err = (z[origin >= 0, 0] - t_az + np.pi) % (2 * np.pi) - np.pi
                assert np.all(np.abs(err) < 6 * sigma)  # each labelled return is its target's bearing
            assert np.all((np.abs(az) <= half + 1e-12) & (el >= lo - 1e-12) & (el <= hi + 1e-12)), (step, sensor)
    assert data.in_view.sum() < data.alive.sum() * data.sensors.shape[0]  # the limits do exclude targets


def test_returns_are_shuffled_and_a_scan_carries_no_labels():
    data = load_scenario_config("mt-crossing", multitarget=True).multitarget_data()
    first = data.origin[:, :, 0]
    assert np.mean(first == CLUTTER) > 0.2 and len(set(first[first >= 0].tolist())) == 4  # any slot holds anything
    scan = data.scan(10, 3)
    assert scan.returns.shape == (int(data.counts[10, 3]), 3) and np.array_equal(scan.pose, data.sensors[3])
    assert not hasattr(scan, "origin")


# ------------------------------------------------------------------ crossing, determinism


def test_crossing_targets_really_cross():
    cfg = load_scenario_config("mt-crossing", multitarget=True)
    data, sigma = cfg.multitarget_data(), cfg.spec.noise_std
    pos = data.truth[:, :, :3]
    dist = np.linalg.norm(pos[:, :, None] - pos[:, None, :], axis=-1)  # (K, T, T)
    pairs = np.triu_indices(pos.shape[1], 1)
    closest = dist.min(axis=0)[pairs]
    # far apart at the start; every pair within 10 noise sigmas at its closest, some within 2 (unresolvable)
    assert np.all(dist[0][pairs] > 400.0) and np.all(closest < 10 * sigma) and closest.min() < 2 * sigma, closest
    when = dist.argmin(axis=0)[pairs]
    assert np.all(np.abs(when - 60) <= 5), when  # all of them at the centre at spread / speed = 60 s


def test_a_seed_fixes_the_run_and_clutter_never_moves_the_targets():
    a, b = (load_scenario_config("mt-bearing", multitarget=True).multitarget_data() for _ in range(2))
    for key in ("truth", "alive", "returns", "counts", "origin"):
        assert np.array_equal(getattr(a, key), getattr(b, key), equal_nan=True), key
    c = load_scenario_config("mt-bearing", multitarget=True).multitarget_data(seed=1)
    assert not np.array_equal(a.truth, c.truth, equal_nan=True)
    d = config("mt-bearing", {"clutter_rate = 3.0": "clutter_rate = 9.0"}).multitarget_data()
    assert np.array_equal(a.truth, d.truth, equal_nan=True) and d.counts.sum() > a.counts.sum()


def test_fifty_targets_are_all_present_and_seen_by_at_least_two_sensors():
    cfg = load_scenario_config("mt-50", multitarget=True)
    data = cfg.multitarget_data()
    assert cfg.spec.nodes == 8 and data.alive.all() and data.alive.shape[1] == 50
    assert (data.in_view.sum(axis=1) >= 2).all()


# ------------------------------------------------------------------ parse errors


@pytest.mark.parametrize("old, new, key", [
    ("count = 4", "count = -1", "targets.count"),
    ('layout = "crossing"', 'layout = "swarm"', "targets.layout"),
    ("speed = 10.0", 'speed = "fast"', "targets.speed"),
    ("spread = 600.0", "", "targets.spread"),
    ("centre = [0.0, 0.0, 200.0]", "centre = [0.0, 0.0]", "targets.centre"),
    ("count = 4", "count = 4\nwings = 2", "targets.wings"),
    ("count = 4", "count = 4\nbirth_times = [0.0, 1.0]", "targets.birth_times"),
    ("count = 4", "count = 4\nbirth_times = [0.0, 1.0, 2.0, 500.0]", "targets.birth_times"),
    ("count = 4", "count = 4\nbirth_times = [0, 0, 9, 0]\ndeath_times = [5, 5, 5, 5]", "targets.death_times"),
    ("count = 4", "count = 4\nsurvival_prob = 1.5", "targets.survival_prob"),
    ("count = 4", "count = 4\nbirth_rate = 0.1", "targets.region"),
    ("detection_prob = 0.9", "detection_prob = 0.0", "sensing.detection_prob"),
    ("detection_prob = 0.9", "detection_prob = 1.2", "sensing.detection_prob"),
    ("max_range = 2500.0 ", "#", "sensing.max_range"),
    ("fov_elevation = [-0.5, 1.5]", "fov_elevation = [1.0, 0.5]", "sensing.fov_elevation"),
    ("fov_azimuth = 6.283185307179586", "fov_azimuth = 7.0", "sensing.fov_azimuth"),
    ("clutter_rate = 5.0", "clutter_rate = 5000.0", "sensing.clutter_rate"),
    ("clutter_rate = 5.0", "clutter_rate = 5.0\nbeams = 3", "sensing.beams"),
    ("p0_diag = [", "x0 = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]\np0_diag = [", "initial.x0"),
    ('layout = "ring"', 'layout = "explicit"\npositions = [[0.0, 0.0, 0.0]]', "sensors.positions"),
    ("height = 20.0", "height = 20.0\nrelays = [1]", "sensors.relays"),
    ("[graph]", "[clutter]\nmode = \"fixed\"\n\n[graph]", "clutter"),
])
def test_every_bad_many_target_key_is_refused_in_one_line_naming_it(old, new, key):
    with pytest.raises(ScenarioConfigError) as err:
        config("mt-crossing", {old: new})
    text = str(err.value)
    assert f": {key}: " in text and "\n" not in text, text


def test_a_plant_without_position_and_velocity_is_refused_naming_the_plant():
    with pytest.raises(ScenarioConfigError, match=r": scenario.plant: a many-target scenario moves its targets by "):
        config("mt-crossing", {'plant = "cv3d-cd"': 'plant = "ca9"', "em_steps = 10\n": "",
                               "q = 0.001 ": "sigma_w = 0.1 #"})


def test_either_many_target_section_asks_for_the_other():
    text = resolve("mt-crossing")[1]
    sensing = text[text.index("[sensing]"):text.index("[graph]")]
    with pytest.raises(ScenarioConfigError, match=r": sensing: missing section \[sensing\]"):
        parse("x.toml", text.replace(sensing, ""))


# ------------------------------------------------------------------ the catalogue and the commands


def test_the_catalogue_lists_the_many_target_scenarios_with_a_description(capsys):
    assert set(MT) <= set(catalogue.names())
    assert main(["scenarios"]) == 0
    listed = {line.split()[0]: line.split(None, 1)[1] for line in capsys.readouterr().out.splitlines()[:-1]}
    for name in MT:
        assert listed[name].startswith("Many targets:") and len(listed[name]) > 30, name
        cfg = load_scenario_config(name, multitarget=True)
        assert cfg.spec.name == name and cfg.spec.nodes == 8 and cfg.multitarget is not None
    assert main(["scenarios", "--json"]) == 0
    assert set(MT) <= set(json.loads(capsys.readouterr().out))


@pytest.mark.parametrize("command", [["bench", "paper1", "--scenario"], ["bench", "paper2", "--scenarios"]])
def test_single_target_commands_refuse_a_many_target_scenario_in_one_line(command, capsys):
    """(``run``, ``truth``, ``node`` and ``soak`` run many-target scenarios: tests/test_multitarget_live.py; ``sim``
    runs their trackers in process, below.)"""
    argv = [*command, "mt-crossing"] if command[-1].startswith("--scenario") else [*command, "--scenario", "mt-crossing"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "many-target scenario" in err and "mt-crossing" in err, err
    with pytest.raises(ScenarioConfigError, match="many-target"):
        load_scenario_config("mt-crossing").scenario_data()
    with pytest.raises(ScenarioConfigError, match="many-target"):
        load_scenario_config("mt-crossing", multitarget=True).scenario_data()


@pytest.mark.parametrize(("name", "methods"), [("mt-crossing", ["alone", "distributed", "centralized"]),
                                               ("mt-bearing", ["alone", "distributed", "centralized"])])
def test_sim_runs_a_many_target_scenarios_trackers_and_writes_gospa_with_its_parts(name, methods, tmp_path, capsys):
    out = tmp_path / "sim.json"
    steps = 12
    assert main(["sim", "--scenario", name, "--steps", str(steps), "--runs", "2", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["command"] == "sim" and doc["runs"] == 2 and doc["steps"] == steps and list(doc["methods"]) == methods
    for m, row in doc["methods"].items():
        assert m in printed
        assert row["mean_squared_gospa"] == pytest.approx(row["localisation"] + row["missed"] + row["false"], rel=1e-9)
        assert len(row["per_node_gospa"]) == (1 if m == "centralized" else 8) and len(row["gospa_over_time"]) == steps
    alone, network = doc["methods"]["alone"], doc["methods"]["distributed"]
    if name == "mt-bearing":  # a lone bearing sensor starts nothing: every target missed at every step
        assert alone["localisation"] == 0 and alone["false"] == 0 and alone["gospa"] == pytest.approx(
            np.sqrt(6 * 50.0 ** 2 / 2), rel=1e-9)
    assert network["gospa"] < alone["gospa"], (network["gospa"], alone["gospa"])  # steps 0-11: tracks start
    assert doc["methods"]["centralized"]["gospa"] < alone["gospa"]  # bearing: every sensor's rays triangulated


@pytest.mark.parametrize("flags", [["--fusion", "ci"], ["--nodes", "4"], ["--filter", "ukf"], ["--qbar", "1e-6"]])
def test_sim_refuses_single_target_flags_for_many_targets_in_one_line(flags, capsys):
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(main(["sim", "--scenario", "mt-crossing", *flags]))
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flags[0] in err[0] and "many-target" in err[0], err
