"""Batched simulator: equals per-node stepping, per-run execution and the centralized form where it must."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.consistency import anees_band, consistency_ratio, nees
from zentrack.fusion.covariance_intersection import ci_fuse
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information
from zentrack.study.metrics import running_rmse
from zentrack.study.simulator import build_filter, evaluate, parse_filter_name, run_filter
from zentrack.truth.simulation.simulate import simulate


def step_nodes_one_by_one(scn, kind):
    """Paper 0 Algorithm 2 written per node with batches of one: what each tracker process does."""
    filt = build_filter(scn, kind)
    m = scn.nodes
    priors = [filt.initial_state(scn.x0_estimate[0:1], scn.p0, scn.lumped_var) for _ in range(m)]
    means = np.empty((scn.steps, m, filt.kinematic_dim))
    for k in range(scn.steps):
        pairs = []
        for i in range(m):
            post = filt.update(priors[i], scn.measurements[0, k, i:i + 1], scn.sensors[i:i + 1, None], scn.noise_cov[i:i + 1])
            means[k, i] = post.mean[0, :filt.kinematic_dim]
            pairs.append(to_information(filt.predict(post)))
        for i in range(m):
            nbrs = np.flatnonzero(scn.weights[i] > 0)
            pair = InformationPair(np.stack([pairs[j].matrix[0] for j in nbrs])[None], np.stack([pairs[j].vector[0] for j in nbrs])[None])
            fused = ci_fuse(scn.weights[i:i + 1, nbrs], pair)
            priors[i] = GaussianState(fused.mean[0], fused.cov[0])
    return means


@pytest.mark.parametrize("kind", ["teskf", "ukf"])
def test_batched_network_equals_nodes_stepping_alone(exp2_small, kind):
    scn = exp2_small.run(0)
    batched = run_filter(scn, "d" + kind)
    alone = step_nodes_one_by_one(scn, kind)
    np.testing.assert_allclose(batched.mean[0], alone, rtol=1e-9, atol=1e-9)


def test_batched_runs_equal_separate_runs(exp2_small):
    together = run_filter(exp2_small, "dteskf")
    for r in range(exp2_small.runs):
        alone = run_filter(exp2_small.run(r), "dteskf")
        np.testing.assert_allclose(together.mean[r], alone.mean[0], rtol=1e-10, atol=1e-10)


def test_single_node_distributed_equals_centralized():
    scn = simulate(builtin_spec("exp2", nodes=1, steps=100), runs=2, seed=3)
    d = run_filter(scn, "dteskf")
    c = run_filter(scn, "cteskf")
    np.testing.assert_allclose(d.mean, c.mean, rtol=1e-9, atol=1e-9)


def test_node_without_measurement_coasts(exp2_small):
    scn = exp2_small.run(0)
    scn.present = scn.present.copy()
    scn.present[0, 40:60, 2] = False
    scn.measurements = scn.measurements.copy()
    scn.measurements[0, 40:60, 2] = np.nan  # never read when absent
    res = run_filter(scn, "dteskf")
    full = run_filter(exp2_small.run(0), "dteskf")
    assert np.all(np.isfinite(res.mean))
    np.testing.assert_array_equal(res.mean[0, :40], full.mean[0, :40])
    assert not np.allclose(res.mean[0, 40:60, 2], full.mean[0, 40:60, 2])
    # a coasting node's covariance does not shrink by a measurement: its trace exceeds the fully-fed run's
    assert np.trace(res.cov[0, 59, 2]) > np.trace(full.cov[0, 59, 2])
    c = run_filter(scn, "cteskf")
    assert np.all(np.isfinite(c.mean))


def test_distributed_filters_converge_and_ci_beats_naive_consistency(exp2_small):
    ci = evaluate(exp2_small, run_filter(exp2_small, "dteskf"))
    naive = evaluate(exp2_small, run_filter(exp2_small, "dteskf", fusion="independent"))
    assert max(ci["rmse"]["p"]) < 30.0  # 120 steps inside a 400 m ring with 1-degree sensors
    assert ci["anees"] <= ci["anees_band"][1]  # CI diffusion is conservative
    assert naive["anees"] > ci["anees"]  # double counting makes the naive rule more optimistic


def test_metrics_on_known_errors():
    err = np.zeros((1, 4, 2, 2))
    err[0, :, 0, 0] = 2.0  # node 0 off by 2 in x1; node 1 exact
    np.testing.assert_allclose(running_rmse(err)[0], np.sqrt(2.0))
    cov = np.broadcast_to(np.eye(2), (1, 4, 2, 2, 2))
    np.testing.assert_allclose(nees(err, cov)[0, :, 0], 4.0)
    assert consistency_ratio(err, cov) == pytest.approx(1.0)  # mean over nodes of 4/2 and 0/2
    lo, hi = anees_band(6, 1000)
    assert lo < 6 < hi and hi - lo < 1.0


def test_filter_names():
    assert parse_filter_name("dteskf") == ("teskf", "distributed")
    assert parse_filter_name("cckf") == ("ckf", "centralized")
    with pytest.raises(ValueError, match="unknown filter"):
        parse_filter_name("dpf")


def test_divergence_is_per_run():
    """A run whose state explodes is flagged at that step, scores RMSE = inf, and leaves the other runs'
    estimates exactly as if they had run alone."""
    scn = simulate(builtin_spec("exp1", nodes=3, steps=200), runs=3, seed=2)
    clean = run_filter(scn, "dekf")
    assert (clean.diverged_at == -1).all()
    blow_up = 50
    scn.measurements = scn.measurements.copy()
    scn.measurements[1, blow_up:] = 1e15  # run 1's sensors report absurd values from step 50: its state explodes
    res = run_filter(scn, "dekf")
    np.testing.assert_array_equal(res.diverged_at, [-1, blow_up, -1])
    assert np.isnan(res.mean[1, blow_up:]).all() and np.isnan(res.cov[1, blow_up:]).all()
    np.testing.assert_array_equal(res.mean[1, :blow_up], clean.mean[1, :blow_up])  # same run up to the blow-up
    for r in (0, 2):
        np.testing.assert_array_equal(res.mean[r], clean.mean[r])  # the other runs are untouched
    m = evaluate(scn, res)
    assert m["diverged_runs"] == 1
    for key in m["rmse"]:
        assert np.isinf(m["rmse"][key][1]), key
        assert np.isfinite(m["rmse"][key][0]) and np.isfinite(m["rmse"][key][2]), key
    ref = evaluate(scn, clean)
    for key in m["rmse"]:
        assert [m["rmse"][key][r] for r in (0, 2)] == [ref["rmse"][key][r] for r in (0, 2)]
    assert len(m["anees_per_run"]) == 2  # the diverged run is left out of ANEES
    assert m["anees_per_run"] == [ref["anees_per_run"][r] for r in (0, 2)]
