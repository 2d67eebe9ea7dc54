"""Paper 3 (SecKF, video satellites) end to end: the scenario files, the benchmark, and a satellite
constellation as tracker processes (lockstep) with its recording."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from zentrack.cli import main as cli_main  # the `zentrack` command
from zentrack.cluster.run.cluster import Cluster
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import ScenarioConfigError, load_scenario_config, parse
from zentrack.study.simulator import run_filter
from zentrack.truth.simulation.orbit import elevation_angle
from zentrack.truth.simulation.simulate import simulate


def test_the_paper_scenario_keeps_the_satellite_in_view_and_moves_the_ship_as_the_model_says():
    cfg = load_scenario_config("seckf-power")
    scn = simulate(cfg.spec, runs=3, seed=2, ts=cfg.ts)
    assert scn.nodes == 1 and scn.steps == 20 and scn.sensor_track.shape == (20, 1, 3)
    elevation = np.degrees(elevation_angle(scn.sensor_track[:, 0]))
    assert np.all(elevation > 60), elevation
    assert np.all(np.linalg.norm(scn.sensor_track[:, 0], axis=-1) < 1000e3)
    # the truth follows the constant-power model plus its process noise
    motion = scn.motion_model()
    step = scn.truth[:, 1:] - motion.f(scn.truth[:, :-1].reshape(-1, 5)).reshape(3, 19, 5)
    assert np.all(np.abs(step[..., 3]) < 1.0) and np.all(np.abs(step[..., 4]) < 1e-3)  # Q: 0.01 and 1e-10
    assert scn.truth[0, -1, 3] > 20.0  # the ship accelerates from 10 m/s towards its terminal speed
    np.testing.assert_allclose(scn.noise_cov[0], 1e-8 * np.eye(2))


def test_the_constellation_sees_the_ship_from_three_directions():
    cfg = load_scenario_config("seckf-constellation")
    scn = cfg.scenario_data()
    assert scn.nodes == 3 and scn.sensor_track.shape == (60, 3, 3)
    los = scn.sensor_track / np.linalg.norm(scn.sensor_track, axis=-1, keepdims=True)
    for a, b in ((0, 1), (0, 2), (1, 2)):
        angle = np.degrees(np.arccos(np.clip(np.sum(los[:, a] * los[:, b], axis=-1), -1, 1)))
        assert angle.min() > 30, (a, b, angle.min())
    centralized = run_filter(scn, "cseckf")
    alone = run_filter(scn, "dseckf")
    err_c = np.linalg.norm(centralized.mean[0, 30:, 0, :3] - scn.truth[0, 30:, :3], axis=-1).mean()
    err_d = np.linalg.norm(alone.mean[0, 30:, :, :3] - scn.truth[0, 30:, None, :3], axis=-1).mean()
    assert np.isfinite(err_d) and err_c < err_d < 3 * err_c


def test_orbit_settings_are_checked():
    from importlib import resources

    text = (resources.files("zentrack.scenarios") / "seckf-power.toml").read_text()
    with pytest.raises(ScenarioConfigError, match="sensors.orbits"):
        parse("bad.toml", text.replace("[[7071.004, 1e-6,", "[[6000.0, 1e-6,", 1))
    with pytest.raises(ScenarioConfigError, match="site_under"):
        parse("bad.toml", text.replace("site_under = 0", "site_under = 3", 1))


def test_bench_paper3_reports_errors_per_observation_and_time_ratios(tmp_path, capsys):
    out = tmp_path / "p3.json"
    # in this process (which holds other tests' threads) the filters run serially: forking it is not safe
    assert cli_main(["bench", "paper3", "--runs", "400", "--single-steps", "5", "--jobs", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "12.5 %" in text and "SecKF/EKF" in text
    data = json.loads(out.read_text())
    sc = data["scenarios"]["seckf-power"]
    assert set(sc["filters"]) == {"lin", "ekf", "ukf", "seckf"}
    for row in sc["filters"].values():
        assert len(row["error_per_observation"]) == 20 and row["diverged_runs"] == 0 and row["all_spd"]
    assert sc["filters"]["lin"]["error_at_20"] > 2 * sc["filters"]["ekf"]["error_at_20"]
    assert sc["best"] in ("ekf", "ukf", "seckf") and sc["ratios"]["seckf/ekf"] > 0
    lo, hi = sc["anees_band_95"]
    for name in ("ekf", "ukf", "seckf"):  # consistent filters: ANEES of 400 runs near the state dimension
        assert 0.8 * lo < sc["filters"][name]["anees_at_20"] < 1.2 * hi
    for name in ("ekf", "ukf", "seckf"):  # centralized, one satellite: at the PCRLB of the ship's dynamics
        assert 0.85 < sc["filters"][name]["rmse_over_sqrt_bound"]["at_last"] < 1.15, sc["filters"][name]
    assert sc["filters"]["lin"]["rmse_over_sqrt_bound"]["all_observations"] > 3.0
    assert "RMSE/sqrt(B)" in text
    deviation = sc["filters"]["seckf"]["secant_vs_jacobian_max_relative"]
    assert 0 < deviation["measurement"] < 1 and 0 <= deviation["state"] < 1
    assert set(data["scenarios"]) == {"seckf-power", "seckf-turn"}  # both of the paper's scenarios by default
    assert (tmp_path / "p3.png").stat().st_size > 5_000


def test_bench_paper3_in_parallel_workers_gives_the_serial_figures(tmp_path):
    """The command as users run it (a fresh process): the filters in two forked workers, the same numbers."""
    outs = {}
    for jobs in ("1", "2"):
        out = tmp_path / f"p3-{jobs}.json"
        proc = subprocess.run([sys.executable, "-m", "zentrack", "bench", "paper3", "--runs", "300",
                               "--scenarios", "seckf-power", "--single-steps", "3", "--jobs", jobs, "--json", str(out)],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        outs[jobs] = json.loads(out.read_text())["scenarios"]["seckf-power"]["filters"]
    for name in ("lin", "ekf", "ukf", "seckf"):
        assert outs["1"][name]["error_per_observation"] == outs["2"][name]["error_per_observation"]


@pytest.mark.slow
def test_a_satellite_constellation_runs_as_tracker_processes_and_is_recorded(tmp_path):
    """Three SecKF trackers, one per satellite, CI diffusion over Zenoh (lockstep: the batched simulator's
    numbers); the recording shows the three satellites moving, their lines of sight and the fused estimate."""
    from test_viewer import column, read_rrd

    cfg = load_scenario_config("seckf-constellation")
    cfg.spec.steps = 12
    scn = cfg.scenario_data()
    setup = RunSetup.from_data(scn, "seckf", mode="lockstep", fusion="ci")
    with Cluster(setup, tmp_path / "run", viewer=[]) as cluster:
        cluster.start()
        assert cluster.wait(timeout=200) == 0
        cluster.write_results()
    est = np.load(tmp_path / "run" / "estimates.npz")
    ref = run_filter(scn, "dseckf")
    np.testing.assert_allclose(est["mean"], ref.mean[0], rtol=0, atol=1e-6)
    rec = read_rrd(tmp_path / "run" / "recording.rrd")
    for i in range(3):
        pos = column(rec[f"/world/platforms/{i}/position"], "Points3D:positions")
        assert len(pos) == 12 and np.linalg.norm(np.ravel(pos[-1])) > 500e3  # hundreds of km up
        radii = column(rec[f"/world/platforms/{i}/position"], "Points3D:radii")
        assert all(np.ravel(r)[0] < 0 for r in radii), "satellites drawn at a fixed screen size"
        assert len(column(rec[f"/world/nodes/{i}/ray"], "step")) == 12
    assert len(column(rec["/world/fused/estimate"], "step")) == 12
