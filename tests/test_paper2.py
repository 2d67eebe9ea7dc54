"""Paper 2 (DCE-ICI) end to end: the UAV scenarios, the consensus rules in the batched simulator, and the
runtime (a lockstep cluster equals the simulator; a realtime cluster runs L* rounds inside each 0.5 s step)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from zentrack.cluster.run.cluster import Cluster
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import ScenarioConfigError, load_scenario_config, parse
from zentrack.config.scenario_file import load_scenario, save_scenario
from zentrack.fusion.consensus_weights import consensus_rounds, graph_diameter
from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext
from zentrack.fusion.graphs import is_connected, metropolis_weights
from zentrack.fusion.rules import RULE_REGISTRY
from zentrack.study.simulator import run_distributed
from zentrack.truth.simulation.simulate import simulate

DEG = math.pi / 180


@pytest.fixture(scope="module")
def cfg():
    return load_scenario_config("dce-ici")


@pytest.fixture(scope="module")
def short():
    cfg = load_scenario_config("dce-ici")
    cfg.spec.steps = 60
    return simulate(cfg.spec, runs=4, seed=1, ts=cfg.ts)


def srcif(scn):
    return FILTER_REGISTRY.create("srcif", {}, FilterContext.from_scenario(scn))


def test_the_uav_scenario_is_the_papers_setting(cfg):
    assert cfg.spec.plant == "ca9" and cfg.filter_kind == "srcif" and cfg.fusion == "dce-ici"
    full = cfg
    assert full.spec.steps * full.ts == 200.0 and full.ts == 0.5 and full.spec.nodes == 8
    # every UAV's noise is 0.1 or 0.5 degrees
    assert set(np.round(full.spec.noise_levels() / DEG, 9)) <= {0.1, 0.5}
    assert len(set(np.round(full.spec.noise_levels() / DEG, 9))) == 2
    # a random graph of link probability 0.3, connected, diameter 4; L* from its weights, at least the diameter
    scn = full.scenario_data()
    assert is_connected(scn.adjacency) and graph_diameter(scn.adjacency) == 4
    assert np.array_equal(scn.adjacency, scn.adjacency.T)
    assert consensus_rounds(scn.weights, scn.adjacency) >= 4
    assert not np.allclose(scn.weights, metropolis_weights(scn.adjacency)), "centrality weights, not Metropolis"
    # UAVs fly constant-acceleration paths and report them with every scan
    track = scn.sensor_track
    assert track.shape == (400, 8, 3)
    t = 0.5 * np.arange(400)[:, None, None]
    np.testing.assert_allclose(track, full.spec.sensors + full.spec.sensor_velocity * t
                               + 0.5 * full.spec.sensor_accel * t * t, rtol=0, atol=1e-9)
    assert np.linalg.norm(track[-1] - track[0], axis=-1).min() > 20_000  # they cover tens of km in 200 s
    np.testing.assert_array_equal(scn.sensor_pose(123, 5), track[123, 5])


def test_the_manoeuvring_target_follows_its_acceleration_schedule():
    cfg = load_scenario_config("dce-ici-manoeuvre")
    scn = simulate(cfg.spec, runs=2, seed=3, ts=cfg.ts)
    t = cfg.ts * np.arange(scn.steps)
    for start, end, accel in zip([0, 50, 100], [50, 100, 200], cfg.spec.accel_schedule):
        seg = (t >= start) & (t < end)
        np.testing.assert_allclose(scn.truth[:, seg, 6:9], np.broadcast_to(accel[1], (2, seg.sum(), 3)), atol=1e-12)
    plain = simulate(load_scenario_config("dce-ici").spec, runs=1, seed=3, ts=cfg.ts)
    assert np.std(plain.truth[0, :, 6:9], axis=0).max() < 0.5  # scenario 1: acceleration drifts slowly


def test_scenario_files_reject_bad_uav_settings(tmp_path):
    text = (Path_of("dce-ici")).read_text()
    cases = {
        "link_prob = 0.3": ("link_prob = 0.0", "graph.link_prob"),
        "noise_stds = [0.008726646259971648, ": ("noise_stds = [", "noise_stds"),
        "diameter = 4": ("diameter = 9", "diameter"),
        'weights = "centrality"': ('weights = "degree"', "graph.weights"),
    }
    for old, (new, where) in cases.items():
        assert old in text
        with pytest.raises(ScenarioConfigError, match=where):
            parse("bad.toml", text.replace(old, new, 1))
    with pytest.raises(ScenarioConfigError, match="sensors.velocities"):
        parse("bad.toml", text.replace("velocities = [[119.16, 34.95, -0.12], ", "velocities = [", 1))


def Path_of(name: str):
    from importlib import resources

    return resources.files("zentrack.scenarios") / f"{name}.toml"


def test_consensus_rules_in_the_simulator(short):
    """Every paper 2 method tracks the target on the UAV scenario, and fusing beats keeping the local estimate."""
    one = short
    err = {}
    for name, params in (("local", {}), ("diff-fci", {}), ("diff-ici", {}), ("dce-fci", {"rounds": 11}),
                         ("dce-ici", {"rounds": 11})):
        res = run_distributed(one, srcif(one), RULE_REGISTRY.create(name, params))
        assert np.all(res.diverged_at < 0) and np.all(np.isfinite(res.mean))
        err[name] = float(np.sqrt(np.mean(np.sum((res.mean[:, 20:, :, :3] - one.truth[:, 20:, None, :3]) ** 2, -1))))
    assert all(err[name] < err["local"] for name in err if name != "local"), err


def random_estimates(rng, m: int, n: int = 4):
    """``m`` correlated estimates (information pairs stacked as a network of one run)."""
    a = rng.normal(size=(m, n, n))
    cov = a @ np.swapaxes(a, -1, -2) + n * np.eye(n)
    mean = rng.normal(size=(m, n)) * 3
    from zentrack.fusion.linalg import GaussianState, to_information

    return to_information(GaussianState(mean, cov)), mean, cov


def test_consensus_rounds_reach_the_centralized_fusion(short):
    """L -> infinity: every node holds the network average, so DCE-ICI gives every node the centralized ICI of
    all estimates (uniform weights: the consensus weights are doubly stochastic) and DCE-FCI the fast CI."""
    from zentrack.fusion.linalg import InformationPair
    from zentrack.study.simulator import NetworkResult

    rng = np.random.default_rng(7)
    adj, w = short.adjacency, short.weights
    pair, mean, cov = random_estimates(rng, 8)
    stacked = {"state": InformationPair(pair.matrix[None], pair.vector[None])}
    centre = NetworkResult("x", mean[None, None], cov[None, None])
    for name, how in (("dce-ici", "ici"), ("dce-fci", "fci")):
        fused = {}
        for rounds in (1, 300):  # combine and mix do not cap the rounds; the registry's rule caps L at 32
            rule = RULE_REGISTRY.create(name, {"rounds": min(rounds, 32)})
            weights = rule.network_weights(w, adj)
            message = rule.share(1, stacked).blocks
            for rnd in range(1, rounds + 1):
                out = rule.combine(rnd, weights, message)
                if rnd < rounds:
                    message = rule.mix(rnd, weights, message, None, out)
            fused[rounds] = out["state"]
        from zentrack.bench.paper2 import centre_fusion as centre_of

        want = centre_of(centre, how)
        spread = {r: np.abs(f.mean[0] - f.mean[0].mean(axis=0)).max() for r, f in fused.items()}
        assert spread[300] < 1e-9 * spread[1], spread
        np.testing.assert_allclose(fused[300].mean[0], np.broadcast_to(want.mean[0, 0], (8, 4)), rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(fused[300].cov[0], np.broadcast_to(want.cov[0, 0], (8, 4, 4)), rtol=1e-8, atol=1e-8)


def test_rounds_auto_is_resolved_from_the_graph_by_the_run_setup(cfg):
    setup = RunSetup(filter_kind="srcif", qbar=1e-6, theta=None, mode="lockstep", deadline_frac=0.5,
                     source="test", spec=cfg.spec, ts=cfg.ts, fusion="dce-ici", fusion_params={"rounds": "auto"})
    node = setup.node_config(3)
    scn = cfg.scenario_data()
    assert node.fusion_params["rounds"] == consensus_rounds(scn.weights, scn.adjacency)
    assert node.sensor is not None and np.allclose(node.sensor.noise_cov, cfg.spec.noise_levels()[3] ** 2 * np.eye(2))
    with pytest.raises(ValueError, match="auto"):
        RULE_REGISTRY.create("dce-ici", {}).rounds(0)


@pytest.mark.slow
def test_dce_ici_lockstep_cluster_equals_the_batched_simulator(tmp_path):
    """Eight tracker processes forward their scans, run L* consensus rounds per step over Zenoh and fuse by
    ICI: the same numbers as the batched simulator (1e-9)."""
    cfg = load_scenario_config("dce-ici")
    cfg.spec.steps = 40
    scn = load_scenario(save_scenario(tmp_path / "scenario.npz", simulate(cfg.spec, runs=1, seed=5, ts=cfg.ts)))
    scn.present[0, 10:14, 2] = False  # a UAV without a measurement for a while: its neighbours use fewer
    scn = load_scenario(save_scenario(tmp_path / "scenario2.npz", scn))
    setup = RunSetup.from_data(scn, "srcif", mode="lockstep", fusion="dce-ici", fusion_params={"rounds": "auto"})
    rounds = setup.run_parameters().fusion_params["rounds"]
    with Cluster(setup, tmp_path / "run") as cluster:
        cluster.start()
        assert cluster.wait(timeout=400) == 0
        summary = cluster.write_results()
    est = dict(np.load(tmp_path / "run" / "estimates.npz"))
    ref = run_distributed(scn, srcif(scn), RULE_REGISTRY.create("dce-ici", {"rounds": rounds}))
    np.testing.assert_allclose(est["mean"], ref.mean[0], rtol=0, atol=1e-9 * np.abs(ref.mean[0]).max())
    np.testing.assert_allclose(est["cov"], ref.cov[0], rtol=1e-7, atol=1e-9)
    assert all(n["messages"]["priors_received"] >= rounds * 39 for n in summary["nodes"])
    assert summary["network"]["partial_rounds"] == 0
    assert summary["network"]["round_ms"]["count"] >= rounds * 8 * 38


def test_the_bound_along_each_runs_own_trajectory(short):
    """With point (linear) measurements the per-run PCRLB is the Kalman filter's covariance recursion exactly;
    with bearings at long range, averaging the information over runs (the ensemble bound) is far lower than
    the mean of the runs' own bounds (lines of sight in many directions at once), and the centralized filter
    sits near the per-run bound."""
    from zentrack.fusion.measurement import PointModel
    from zentrack.study.pcrlb import bound_rmse, pcrlb, pcrlb_per_run
    from zentrack.study.simulator import run_centralized

    motion = short.motion_model()
    noise = np.tile(25.0 * np.eye(3), (short.nodes, 1, 1))
    per_run = pcrlb_per_run(short.truth[:2], short.sensor_track, motion.A, motion.Q, short.p0, noise, PointModel())
    info_z = short.nodes * np.eye(9)[:3].T @ np.eye(9)[:3] / 25.0
    p = np.linalg.inv(np.linalg.inv(short.p0) + info_z)
    np.testing.assert_allclose(per_run[1, 0], p, rtol=1e-9)
    for _ in range(1, short.steps):
        p = np.linalg.inv(np.linalg.inv(motion.A @ p @ motion.A.T + motion.Q) + info_z)
    np.testing.assert_allclose(per_run[0, -1], p, rtol=1e-6)
    bearing = pcrlb_per_run(short.truth, short.sensor_track, motion.A, motion.Q, short.p0, short.noise_cov)
    ensemble = pcrlb(short.truth, short.sensor_track, motion.A, motion.Q, short.p0, short.noise_cov)
    floor = bound_rmse(bearing.mean(axis=0), [0, 1, 2])
    assert np.all(bound_rmse(ensemble, [0, 1, 2])[-10:] < floor[-10:])
    central = run_centralized(short, srcif(short))
    rmse = np.sqrt(np.mean(np.sum((central.mean[:, :, 0, :3] - short.truth[..., :3]) ** 2, -1), axis=0))
    assert 0.8 < np.mean(rmse[30:] / floor[30:]) < 1.6
