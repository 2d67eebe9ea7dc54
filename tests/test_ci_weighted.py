"""CI with weights chosen per step (fusion/rules/ci_weighted.py): consistent whatever the correlation, and the
minimum-trace weights are the minimum."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.covariance_intersection import inverse_covariance_trace_weights, min_trace_weights
from zentrack.fusion.linalg import InformationPair
from zentrack.fusion.rules import make_rule


def _spd(rng, n, scale):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T / n + 0.1 * np.eye(n))


def _correlated(rng, count, n):
    """A joint error covariance of ``count`` estimates with arbitrary cross-correlation; the estimates'
    reported covariances are its diagonal blocks (each estimate consistent on its own)."""
    root = rng.normal(size=(count * n, count * n)) * rng.uniform(0.2, 3.0, size=count * n)
    joint = root @ root.T / (count * n) + 1e-3 * np.eye(count * n)
    blocks = np.array([joint[i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(count)])
    return joint, blocks


@pytest.mark.parametrize("rule", ["ci-fast", "ci-trace"])
def test_the_fused_covariance_bounds_the_true_error_covariance_of_correlated_estimates(rule):
    rng = np.random.default_rng(11)
    fusion = make_rule(rule)
    for _ in range(60):
        count, n = int(rng.integers(2, 6)), int(rng.integers(1, 5))
        joint, covs = _correlated(rng, count, n)
        infos = np.linalg.inv(covs)
        pair = InformationPair(infos[None], np.zeros((1, count, n)))
        weights = np.ones((1, count)) / count  # one receiver that hears every sender
        fused = fusion.combine(1, weights, {"state": pair})["state"]
        p_fused = fused.cov[0, 0]
        # the fused error is P_f sum_j omega_j Y_j e_j; recover the gains from the fused information
        choose = inverse_covariance_trace_weights if rule == "ci-fast" else min_trace_weights
        omega = choose(infos[None], np.ones((1, 1, count), bool))[0, 0]
        gains = np.concatenate([p_fused @ (omega[j] * infos[j]) for j in range(count)], axis=1)
        true_cov = gains @ joint @ gains.T
        assert np.linalg.eigvalsh(p_fused - true_cov).min() >= -1e-9 * np.abs(p_fused).max()
        assert np.isclose(omega.sum(), 1.0) and np.all(omega >= 0)


def test_min_trace_weights_reach_the_minimum_and_fast_weights_favour_the_better_estimate():
    rng = np.random.default_rng(3)
    for _ in range(20):
        covs = np.array([_spd(rng, 3, 1.0), _spd(rng, 3, 5.0)])
        infos = np.linalg.inv(covs)
        omega = min_trace_weights(infos[None], np.ones((1, 1, 2), bool))[0, 0]
        grid = np.linspace(0.0005, 0.9995, 2000)
        traces = [np.trace(np.linalg.inv(w * infos[0] + (1 - w) * infos[1])) for w in grid]
        best = np.trace(np.linalg.inv(omega[0] * infos[0] + omega[1] * infos[1]))
        assert best <= min(traces) * 1.01, (best, min(traces))  # 20 fixed-point iterations: within 1 %
        fast = inverse_covariance_trace_weights(infos[None], np.ones((1, 1, 2), bool))[0, 0]
        assert fast[0] > fast[1]  # the smaller covariance weighs more
    # a sender outside the support gets no weight
    support = np.array([[[True, False, True]]])
    infos = np.linalg.inv(np.array([np.eye(2), 0.1 * np.eye(2), 4 * np.eye(2)]))[None]
    for choose in (inverse_covariance_trace_weights, min_trace_weights):
        assert choose(infos, support)[0, 0, 1] == 0.0


@pytest.mark.slow
def test_measurement_sharing_with_fast_ci_lockstep_equals_the_batched_simulator(tmp_path):
    """deploy/scenarios/exp2-sharing.toml (scans forwarded to the ring neighbours, fast-CI weights) as tracker
    processes in lockstep gives the batched simulator's estimates."""
    import argparse

    from zentrack.cluster.run.cluster import Cluster
    from zentrack.config.run_setup import resolve_setup
    from zentrack.config.scenario_flags import add_scenario_arguments
    from zentrack.study.simulator import run_filter

    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    setup = resolve_setup(p.parse_args(["--scenario", "exp2-sharing", "--timing", "lockstep", "--nodes", "4",
                                        "--steps", "40"]))
    assert (setup.fusion, setup.fusion_params["share_scans"]) == ("ci-fast", True)
    with Cluster(setup, tmp_path / "run") as cluster:
        cluster.start()
        assert cluster.wait(timeout=300) == 0
        summary = cluster.write_results()
    est = np.load(tmp_path / "run" / "estimates.npz")
    ref = run_filter(setup.scenario, "d" + setup.filter_kind, fusion=make_rule(setup.fusion, setup.fusion_params),
                     qbar=setup.qbar, theta=setup.theta)
    np.testing.assert_allclose(est["mean"], ref.mean[0], rtol=0, atol=1e-9)
    assert all(n["steps_estimated"] == 40 for n in summary["nodes"])
