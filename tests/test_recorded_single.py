"""Real motion as a single-target truth (issue 34 item 3): a scenario's ``[trajectory]`` makes one recorded path the
truth of every run (the same path, fresh measurement noise and initial estimate per run), refuses a selection of
zero or two targets and a target absent at some step in one line naming it, and `zentrack sim` runs the
catalogue's ``ais-vessel`` end to end.

The expected path is read straight from the recording (:func:`recorded_targets` with a spec built here, not the
parser's), and the expected absent step from where that path leaves a region, so a parser or simulation that
drops a key, shifts the start or redraws the truth fails.
"""
from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

if importlib.util.find_spec("tracktable_data") is None:  # CI installs it (zentrack[real])
    pytest.skip("the AIS recording's package tracktable-data is not installed", allow_module_level=True)

from zentrack.cli import main  # noqa: E402
from zentrack.config.scenario_config import ScenarioConfigError, parse, resolve  # noqa: E402
from zentrack.fusion.measurement import BearingModel, wrap_angle  # noqa: E402
from zentrack.truth.simulation.recorded.recording import RecordingSpec, recorded_targets  # noqa: E402
from zentrack.truth.simulation.simulate import simulate  # noqa: E402

STEPS = 30
FERRY = "JOHN F KENNEDY"
#: the file's recording, written out independently of the parser
FILE_REGION = np.array([[-4000.0, 4000.0], [-7000.0, 6000.0], [-30.0, 30.0]])


def recording(region: np.ndarray = FILE_REGION, start: float = 1980.0) -> RecordingSpec:
    return RecordingSpec("ais-nyharbor", (40.66, -74.05, 0.0), region, start=start, max_speed=30.0, max_gap=300.0,
                         min_extent=100.0, select=(FERRY,))


def vessel(replace: dict[str, str] | None = None, steps: int = STEPS):
    """The catalogue's ais-vessel with ``steps`` steps and text replaced (each old text must occur once)."""
    text = resolve("ais-vessel")[1].replace("steps = 450 ", f"steps = {steps} ", 1)
    for old, new in (replace or {}).items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return parse("ais-vessel.toml", text)


def test_the_recorded_path_is_the_truth_of_every_run_with_fresh_noise_per_run():
    cfg = vessel()
    scn = simulate(cfg.spec, runs=3, seed=5, ts=cfg.ts)
    path = recorded_targets(recording(), STEPS, 2.0).truth[:, 0]
    assert cfg.ts == 2.0 and path.shape == (STEPS, 6) and np.all(np.isfinite(path))
    assert np.linalg.norm(path[-1, :2] - path[0, :2]) > 100.0  # it moves (about 7 m/s)
    for r in range(scn.runs):
        np.testing.assert_array_equal(scn.truth[r], path)
    # the initial estimates: drawn around the recorded state at step 0, one per run
    assert len({tuple(x) for x in scn.x0_estimate}) == scn.runs and not np.any(scn.x0_estimate == path[0])
    # the measurements: the path seen from the sensors plus each run's own noise of the file's 0.002 rad
    clean = BearingModel().h(path, np.broadcast_to(scn.sensors, (STEPS,) + scn.sensors.shape)).reshape(STEPS, -1, 2)
    noise = wrap_angle(scn.measurements - clean[None])
    assert np.all(scn.present)
    for r in range(scn.runs):
        assert 0.8 < float(np.std(noise[r])) / 0.002 < 1.2, r
    assert not np.allclose(noise[0], noise[1]) and not np.allclose(noise[1], noise[2])


def test_a_target_absent_at_some_step_fails_in_one_line_naming_the_step(tmp_path, capsys):
    wide = recorded_targets(recording(np.array([[-1e7, 1e7]] * 3)), 400, 2.0).truth[:, 0]
    first = int(np.flatnonzero(wide[:, 1] < 0.0)[0])  # where the ferry crosses y = 0 southbound
    assert 50 < first < 400
    region = '[[-4000.0, 4000.0], [0.0, 6000.0], [-30.0, 30.0]]'
    change = {"region = [[-4000.0, 4000.0], [-7000.0, 6000.0], [-30.0, 30.0]]": f"region = {region}"}
    cfg = vessel(change, steps=400)
    with pytest.raises(ValueError) as exc:
        simulate(cfg.spec, runs=1, seed=0, ts=cfg.ts)
    message = str(exc.value)
    assert "\n" not in message and message.startswith("ais-vessel: ")
    assert f"'{FERRY}'" in message and f"absent at step {first} of 400" in message
    path = tmp_path / "absent.toml"
    path.write_text(resolve("ais-vessel")[1].replace("steps = 450 ", "steps = 400 ", 1).replace(
        *next(iter(change.items()))))
    assert main(["sim", "--scenario", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"absent at step {first} of 400" in err


def test_a_target_never_in_the_recording_is_absent_from_step_0():
    cfg = vessel({f'select = ["{FERRY}"]': 'select = ["NO SUCH VESSEL"]'})
    with pytest.raises(ValueError, match=r"^ais-vessel: .*'NO SUCH VESSEL' is absent from step 0 [^\n]*$"):
        simulate(cfg.spec, runs=1, seed=0, ts=cfg.ts)


@pytest.mark.parametrize("select", ["[]", f'["{FERRY}", "ANDREW J BARBERI"]', f'"{FERRY}"'])
def test_selecting_zero_or_two_targets_fails_naming_the_key(select):
    with pytest.raises(ScenarioConfigError, match=r"^ais-vessel.toml: trajectory.select: must name exactly one"):
        vessel({f'select = ["{FERRY}"]': f"select = {select}"})


@pytest.mark.parametrize("change, key", [
    ({'plant = "cv3d-cd"': 'plant = "ca9"', "q = 0.05\nem_steps = 10": "sigma_w = 0.1"}, "scenario.plant"),
    ({"p0_diag = [": "x0 = [0.0, 0.0, 0.0, 1.0, 1.0, 0.0]\np0_diag = ["}, "initial.x0"),
    ({"min_extent = 100.0": "min_extent = 100.0\nmax_targets = 3"}, "trajectory.max_targets"),
    ({"region = [[-4000.0, 4000.0]": "region = [[4000.0, -4000.0]"}, "trajectory.region"),
])
def test_what_a_recorded_trajectory_cannot_take_is_refused_naming_the_key(change, key):
    with pytest.raises(ScenarioConfigError, match=rf"^ais-vessel.toml: {key}: [^\n]*$"):
        vessel(change)


def test_zentrack_sim_on_ais_vessel_gives_finite_figures(tmp_path):
    out = tmp_path / "sim.json"
    assert main(["sim", "--scenario", "ais-vessel", "--steps", "20", "--runs", "3", "--json", str(out)]) == 0
    row = json.loads(out.read_text())["filters"]["teskf+ci"]
    assert all(np.isfinite(row["rmse"][g]["median"]) for g in ("p", "v"))
    assert all(np.isfinite(row["rmse_over_sqrt_bound"][g]["median"]) for g in ("p", "v"))
    assert np.isfinite(row["anees"]) and len(row["anees_band"]) == 2
