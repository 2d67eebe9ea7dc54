"""An isolated bearing-only tracker stays honest (issue 54 item 1): the Schmidt hold of what its own measurements
cannot observe (fusion/isolation.py), who counts as isolated, the same numbers in a tracker and the batched
simulator, and, over 5 s and 30 s cuts on exp2 and patrol, error no faster than prediction alone and NEES at or
below its band (study/isolated_node.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.estimates import GaussianEstimate
from zentrack.fusion.filters import FilterContext, make_node_filter
from zentrack.fusion.isolation import (
    fused_alone,
    held_projector,
    hold_unobserved,
    isolated_update,
    unobserved_projector,
)
from zentrack.fusion.linalg import GaussianState, joseph_update
from zentrack.fusion.measurement import BearingModel, PointModel
from zentrack.fusion.scan import Scan
from zentrack.node.diffusion.tracker import Tracker
from zentrack.study.isolated_node import AFTER_CUT, run_cut
from zentrack.study.links import cut_links
from zentrack.study.simulator import build_filter, run_distributed
from zentrack.truth.simulation.simulate import simulate


def spd(rng, n, scale=1.0):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T + n * np.eye(n))


def test_the_hold_is_the_kalman_update_with_zero_gain_on_the_held_subspace():
    """Schmidt's update (Simon 2006, 7.4) written out: the Joseph form with the gain's held part zeroed,
    ``K_s = (I - Pi) K``, equals the optimal update with the held mean and block set back to the prior."""
    rng = np.random.default_rng(5)
    n, m = 12, 2
    prior = GaussianState(rng.normal(size=(1, n)), spd(rng, n)[None])
    jac, noise, innovation = rng.normal(size=(1, m, n)), spd(rng, m, 0.1)[None], rng.normal(size=(1, m))
    basis = np.linalg.qr(rng.normal(size=(n, 3)))[0]
    projector = (basis @ basis.T)[None]
    held = hold_unobserved(prior, joseph_update(prior, jac, innovation, noise), projector)
    p, c, r = prior.cov[0], jac[0], noise[0]
    gain = (np.eye(n) - projector[0]) @ p @ c.T @ np.linalg.inv(c @ p @ c.T + r)
    i_kc = np.eye(n) - gain @ c
    np.testing.assert_allclose(held.mean[0], prior.mean[0] + gain @ innovation[0], atol=1e-12)
    np.testing.assert_allclose(held.cov[0], i_kc @ p @ i_kc.T + gain @ r @ gain.T, atol=1e-10)
    assert np.linalg.eigvalsh(held.cov[0]).min() > 0


def test_a_bearing_leaves_range_range_rate_and_the_lumped_terms_unobserved_a_point_nothing():
    scn = simulate(builtin_spec("exp2", steps=2), runs=1, seed=0)
    filt = build_filter(scn, "teskf")  # [p, v, F, dF]: 12 states, kinematic 6
    x = np.zeros((1, 6))
    x[0, :3] = [120.0, -40.0, 30.0]
    sensor = np.array([[[400.0, 0.0, 0.0]]])
    u = (x[0, :3] - sensor[0, 0]) / np.linalg.norm(x[0, :3] - sensor[0, 0])
    a = filt.nominal_transition()
    projector = held_projector(BearingModel().jacobian(x, sensor, 12), a, 12)[0]
    expected = np.zeros((12, 12))
    expected[:3, :3] = expected[3:6, 3:6] = np.outer(u, u)
    expected[6:, 6:] = np.eye(6)
    np.testing.assert_allclose(projector, expected, atol=1e-9)
    assert not held_projector(PointModel().jacobian(x, sensor, 12), a, 12).any()
    assert not unobserved_projector(PointModel().jacobian(x, sensor, 6), a).any()


def test_the_range_mean_and_spread_are_kept_and_a_spread_past_the_sensor_is_not_updated():
    scn = simulate(builtin_spec("patrol", steps=2), runs=1, seed=0)
    filt = build_filter(scn, "teskf")
    sensor = scn.sensors[:1, None]  # (1, 1, 3)
    truth = scn.truth[0, 1, :6]
    z = BearingModel().h(truth[None], sensor)
    mean = np.concatenate([truth + np.r_[8.0, -6.0, 3.0, 1.0, -1.0, 0.5], np.zeros(6)])[None]
    u = (mean[0, :3] - sensor[0, 0]) / np.linalg.norm(mean[0, :3] - sensor[0, 0])  # the prior's line of sight
    rng_m = float(np.linalg.norm(mean[0, :3] - sensor[0, 0]))
    for sigma_range, updated in ((rng_m / 10, True), (rng_m / 2, False)):
        cov = np.eye(12)[None] * 4.0
        cov[0, :3, :3] += (sigma_range**2 - 4.0) * np.outer(u, u)
        e = np.cross(u, [0.0, 0.0, 1.0]) / np.linalg.norm(np.cross(u, [0.0, 0.0, 1.0]))  # across the ray
        cov[0, :3, :3] += 0.5 * sigma_range * 2.0 * (np.outer(u, e) + np.outer(e, u))  # correlation 0.5
        prior = GaussianState(mean, cov)
        post = isolated_update(filt, prior, z, sensor, scn.noise_cov[:1])
        if not updated:  # 3 sigma of range reach past the sensor: the prior, untouched
            np.testing.assert_array_equal(post.mean, prior.mean)
            np.testing.assert_array_equal(post.cov, prior.cov)
            continue
        move = post.mean[0, :3] - prior.mean[0, :3]
        assert abs(move @ u) < 1e-9 and np.linalg.norm(move) > 1.0, "moved across the ray, not along it"
        assert post.cov[0, :3, :3] @ u @ u == pytest.approx(sigma_range**2, rel=1e-9), "the range spread is kept"
        np.testing.assert_allclose(post.mean[0, 6:], 0.0, atol=1e-12)  # lumped terms held
        own = filt.update(prior, z, sensor, scn.noise_cov[:1])
        assert abs((own.mean[0, :3] - prior.mean[0, :3]) @ u) > 0.1, "the own update slides along the ray"


def test_isolated_means_it_has_neighbours_and_heard_none():
    ring = np.array([[0, 1, 0, 1], [1, 0, 1, 0], [0, 1, 0, 1], [1, 0, 1, 0]], dtype=bool)
    heard = np.eye(4, dtype=bool)
    assert fused_alone(heard, ring).tolist() == [True] * 4
    heard[0, 3] = True  # node 0 heard node 3
    heard[1, 3] = True  # node 1 "heard" a node that is not its neighbour
    assert fused_alone(heard, ring).tolist() == [False, True, True, True]
    assert not fused_alone(np.ones(3, dtype=bool), np.zeros(3, dtype=bool))  # no neighbours: never isolated


def test_every_link_up_is_bit_for_bit_the_run_without_links(exp2_small):
    filt = build_filter(exp2_small, "teskf")
    plain = run_distributed(exp2_small, filt)
    linked = run_distributed(exp2_small, filt, links=np.ones((exp2_small.steps, 6, 6), dtype=bool))
    np.testing.assert_array_equal(plain.mean, linked.mean)
    np.testing.assert_array_equal(plain.cov, linked.cov)


def test_a_tracker_cut_off_updates_as_the_simulators_isolated_row():
    """Trackers stepped by hand (update, predict, fuse with the messages that got through) on a 4-ring with node 1
    cut off for steps 10-24: the same numbers as the batched simulator with the same links (to rounding: the
    simulator's sums run over the whole network, as tests/test_contracts.py compares them), node 1 is isolated at
    exactly those steps, and its updates there are the isolated ones (its own update would differ)."""
    scn = simulate(builtin_spec("exp2", nodes=4, steps=40), runs=1, seed=2)
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "lockstep", 0.5, "test")
    start, length = 10, 15
    links = cut_links(scn.steps, 4, 1, start, length)
    expected = run_distributed(scn, build_filter(scn, "teskf"), links=links)
    own = run_distributed(scn, build_filter(scn, "teskf"), links=links, alone=lambda f, p, z, s, r: f.update(p, z, s, r))
    trackers = [Tracker(setup.node_config(i)) for i in range(4)]
    for tr in trackers:
        tr.set_initial(scn.x0_estimate[0])
        tr.cold_start(0)
    isolated = []
    for k in range(scn.steps):
        pairs = []
        for i, tr in enumerate(trackers):
            isolated.append((k, i)) if tr.isolated else None
            post = tr.update([tr.scan(k, scn.measurements[0, k, i][None])])
            kin = tr.kinematic(post)
            np.testing.assert_allclose(kin.mean, expected.mean[0, k, i], rtol=1e-9, atol=1e-9, err_msg=f"step {k} node {i}")
            np.testing.assert_allclose(kin.cov, expected.cov[0, k, i], rtol=1e-9, atol=1e-9, err_msg=f"step {k} node {i}")
            pairs.append(tr.predict_pair(post, k + 1))
        for i, tr in enumerate(trackers):
            tr.fuse(k + 1, pairs[i], {j: pairs[j] for j in tr.neighbours if links[k, i, j]})
    assert isolated == [(k, 1) for k in range(start, start + length)]
    cut = slice(start, start + length)
    assert not np.allclose(own.mean[0, cut, 1], expected.mean[0, cut, 1])
    np.testing.assert_array_equal(own.mean[0, :start], expected.mean[0, :start])


def test_a_node_filter_updates_an_isolated_estimate_as_the_batch_does():
    scn = simulate(builtin_spec("patrol", steps=12), runs=1, seed=0)
    filt, node = build_filter(scn, "teskf"), make_node_filter("teskf", FilterContext.from_scenario(scn))
    rng = np.random.default_rng(1)
    mean = np.concatenate([scn.truth[0, 10, :6], np.zeros(6)]) + rng.normal(0, 3, (5, 12))
    cov = np.stack([spd(rng, 12) for _ in range(5)])
    cov[:, :3, :3] *= 40.0
    sensors, noise, z = scn.sensors[:5, None], scn.noise_cov[:5], scn.measurements[0, 10, :5]
    batch = isolated_update(filt, GaussianState(mean, cov), z, sensors, noise)
    for i in range(5):
        one = node.update_isolated(GaussianEstimate(mean[i], cov[i], 6), [Scan.single(10, i, z[i], sensors[i, 0], noise[i])])
        np.testing.assert_array_equal(one.mean, batch.mean[i])
        np.testing.assert_array_equal(one.cov, batch.cov[i])


@pytest.mark.slow
@pytest.mark.cpu_only
def test_the_bench_writes_each_rule_beside_prediction_and_draws_the_cut(tmp_path, capsys):
    from zentrack.cli import main

    out = tmp_path / "isolated.json"
    assert main(["bench", "isolated", "--runs", "1", "--cuts", "0.5", "--scenarios", "patrol", "--rules", "held",
                 "--json", str(out)]) == 0
    assert "prediction" in capsys.readouterr().out
    (cut,) = json.loads(out.read_text())["cuts"]
    assert (cut["scenario"], cut["steps"], cut["runs"], list(cut["rules"])) == ("patrol", 5, 1, ["prediction", "held"])
    assert cut["rules"]["prediction"]["rms_vs_prediction"] == 1.0
    assert len(cut["rules"]["held"]["error_m"]) == 10 + 5 + AFTER_CUT  # from 1 s before the cut to the run's end
    assert (tmp_path / "isolated.png").stat().st_size > 20_000 and (tmp_path / "isolated.svg").exists()


def test_a_cut_of_no_length_is_refused_in_one_line(capsys):
    from zentrack.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["bench", "isolated", "--cuts", "5,0"])
    assert exc.value.code == 2
    assert "--cuts: must be a positive finite number, got 0" in capsys.readouterr().err


#: Monte Carlo runs of each cut (fixed seed 0): over seeds 0-3 the held rule's error ratios to prediction were
#: 0.46-0.69 (5 s) and 0.89-0.94 (30 s), its largest mean NEES 2.4-6.2 against the band's 7.61 (docs/isolated-tracker.md)
RUNS = 20


@pytest.mark.slow
@pytest.mark.cpu_only
@pytest.mark.parametrize("scenario, seconds", [("exp2", 5), ("exp2", 30), ("patrol", 5), ("patrol", 30)])
def test_a_node_cut_off_grows_no_faster_than_prediction_and_stays_inside_its_nees_band(scenario, seconds):
    cut = run_cut(scenario, seconds, RUNS, seed=0, rules=("prediction", "held"))
    held, pred = cut["summary"]["held"], cut["summary"]["prediction"]
    where = f"{scenario}, {seconds} s: held {held}, prediction {pred}"
    assert held["rms_error_m"] <= pred["rms_error_m"], where
    assert held["end_error_m"] <= pred["end_error_m"], where
    assert held["max_nees"] <= cut["nees_band"][1], where
    assert held["after_error_m"] <= 2.0 * pred["after_error_m"], where  # and it rejoins
