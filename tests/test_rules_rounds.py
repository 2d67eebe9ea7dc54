"""Fusion rules with rounds in the batched simulator, the ci3 plug-in, and relay nodes."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.covariance_intersection import ci_fuse, independent_fuse
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information
from zentrack.fusion.rules import RULE_REGISTRY, FusionRule, make_rule
from zentrack.study.simulator import FUSION_RULES, build_filter, evaluate, run_distributed, run_filter
from zentrack.truth.simulation.scenario_spec import ScenarioSpec
from zentrack.truth.simulation.simulate import simulate


@pytest.fixture(scope="module")
def scn():
    return simulate(builtin_spec("exp2", nodes=6, steps=120), runs=2, seed=3)


def old_ci_path(scn, kind="teskf"):
    """The simulator's CI step as it was before rules had rounds (all measurements present)."""
    filt = build_filter(scn, kind)
    r, m, nx, nk = scn.runs, scn.nodes, filt.state_dim, filt.kinematic_dim
    state = filt.initial_state(np.repeat(scn.x0_estimate, m, axis=0), scn.p0, scn.lumped_var)
    sensors = np.tile(scn.sensors[:, None, :], (r, 1, 1))
    noise = np.tile(scn.noise_cov, (r, 1, 1))
    means = np.empty((r, scn.steps, m, nk))
    for k in range(scn.steps):
        post = filt.update(state, scn.measurements[:, k].reshape(r * m, -1), sensors, noise)
        means[:, k] = post.mean[:, :nk].reshape(r, m, nk)
        pair = to_information(filt.predict(post))
        fused = ci_fuse(scn.weights, InformationPair(pair.matrix.reshape(r, m, nx, nx), pair.vector.reshape(r, m, nx)))
        state = GaussianState(fused.mean.reshape(r * m, nx), fused.cov.reshape(r * m, nx, nx))
    return means


def test_ci_with_one_round_is_the_old_ci_path_bit_for_bit(scn):
    old = old_ci_path(scn)
    assert np.array_equal(run_filter(scn, "dteskf").mean, old)
    one_round = run_distributed(scn, build_filter(scn, "teskf"), RULE_REGISTRY.create("ci", {"rounds": 1}))
    assert np.array_equal(one_round.mean, old)


def test_ci3_plugin_runs_three_rounds_and_stays_consistent(scn):
    assert "ci3" in FUSION_RULES and make_rule("ci3").rounds(0) == 3
    ci = run_filter(scn, "dteskf", fusion="ci")
    ci3 = run_filter(scn, "dteskf", fusion="ci3")
    assert np.all(np.isfinite(ci3.mean)) and (ci3.diverged_at < 0).all()
    assert not np.allclose(ci3.mean, ci.mean)
    ci_rounds3 = run_filter(scn, "dteskf", fusion=RULE_REGISTRY.create("ci", {"rounds": 3}))
    assert np.array_equal(ci3.mean, ci_rounds3.mean) and np.array_equal(ci3.cov, ci_rounds3.cov)
    m1, m3 = evaluate(scn, ci), evaluate(scn, ci3)
    lo, hi = m3["anees_band"]
    assert 0.2 * lo < m3["anees"] <= hi  # conservative (CI) but not absurdly so
    # more rounds spread more information: the mean covariance shrinks
    assert np.trace(ci3.cov[:, 30:], axis1=-2, axis2=-1).mean() < np.trace(ci.cov[:, 30:], axis1=-2, axis2=-1).mean()
    assert max(m3["rmse"]["p"]) < 30.0 and m1["anees"] <= m1["anees_band"][1]


def test_rounds_follow_the_rule_and_are_validated(scn):
    calls = []

    class Counting(FusionRule):
        name = "counting"

        def rounds(self, step):
            return 1 + step % 2

        def combine(self, round, weights, messages, present=None):
            calls.append(round)
            return {k: ci_fuse(weights, p, present) for k, p in messages.items()}

    short = scn.run(0)
    run_distributed(short, build_filter(short, "ekf"), Counting())
    assert calls == [1, 1, 2] * (short.steps // 2)
    with pytest.raises(ValueError, match="'rounds'"):
        RULE_REGISTRY.create("ci", {"rounds": 0})

    class NoRounds(Counting):
        def rounds(self, step):
            return 0

    with pytest.raises(ValueError, match="at least 1"):
        run_distributed(short, build_filter(short, "ekf"), NoRounds())
    with pytest.raises(ValueError, match="fusion must be one of"):
        run_filter(scn, "dteskf", fusion="nope")


def test_a_scan_exchanging_rule_in_the_batched_simulator_equals_per_node_updates(scn):
    """Measurement sharing (paper 2) batched: node i updates with its own scan and its neighbours' (own first,
    then by index; missing ones left out), exactly what each tracker does with its node filter."""
    from zentrack.fusion.filters import FilterContext, make_node_filter
    from zentrack.fusion.rules import next_round_blocks, stack_messages
    from zentrack.fusion.scan import Scan

    class Forwarding(FusionRule):
        exchanges_scans = True

        def combine(self, round, weights, messages, present=None):
            return {k: ci_fuse(weights, p, present) for k, p in messages.items()}

    one = scn.run(1)
    one.present[0, 30:40, 2] = False  # a node without a scan for a while: its neighbours use fewer
    one.present[0, 50:52, :] = False  # nobody measures: every node coasts
    batched = run_distributed(one, build_filter(one, "ekf"), Forwarding())
    plain = run_distributed(one, build_filter(one, "ekf"), "ci")
    rule = Forwarding()
    nodes = [make_node_filter("ekf", FilterContext.from_scenario(one)) for _ in range(one.nodes)]
    priors = [f.initial(one.x0_estimate[0]) for f in nodes]
    means = np.empty((one.steps, one.nodes, 6))
    for k in range(one.steps):
        own = {i: Scan.single(k, i, one.measurements[0, k, i], one.sensors[i], one.noise_cov[i])
               for i in range(one.nodes) if one.present[0, k, i]}
        shared = []
        for i, f in enumerate(nodes):
            group = [i, *(int(j) for j in np.flatnonzero(one.adjacency[i]))]
            post = f.update(priors[i], [own[j] for j in group if j in own])
            means[k, i] = f.kinematic(post).mean
            shared.append(f.predict(post))
        msgs = [rule.share(1, f.blocks(est)) for f, est in zip(nodes, shared)]
        for i, f in enumerate(nodes):
            group = [i, *(int(j) for j in np.flatnonzero(one.adjacency[i]))]
            w = one.weights[i, group][None]
            fused = rule.combine(1, w, stack_messages([msgs[j] for j in group]), np.ones_like(w, bool))
            priors[i] = f.from_fused(fused, like=shared[i])
            assert next_round_blocks(fused)["state"].matrix.shape == (6, 6)
    np.testing.assert_allclose(batched.mean[0], means, rtol=1e-9, atol=1e-9)
    assert np.abs(plain.mean[0] - means).max() > 1e-3, "the neighbours' scans change the estimates"


def test_independent_rule_equals_independent_fuse(rng):
    adj = np.array([[0, 1, 0, 1], [1, 0, 1, 0], [0, 1, 0, 1], [1, 0, 1, 0]], dtype=bool)
    a = rng.normal(size=(2, 4, 3, 3))
    pair = InformationPair(a @ np.swapaxes(a, -1, -2) + 3 * np.eye(3), rng.normal(size=(2, 4, 3)))
    rule = RULE_REGISTRY.create("independent")
    w = rule.network_weights(np.full((4, 4), 0.25), adj)
    got = rule.combine(1, w, {"state": pair})["state"]
    want = independent_fuse(adj, pair)
    assert np.array_equal(got.mean, want.mean) and np.array_equal(got.cov, want.cov)
    present = np.ones((2, 4, 4), dtype=bool)
    present[1, 0, 1] = False
    got = rule.combine(1, w, {"state": pair}, present)["state"]
    want = independent_fuse(adj, pair, present)
    assert np.array_equal(got.mean, want.mean)


def alternating_relays(runs=2, steps=150, point=False):
    spec = builtin_spec("exp2-point" if point else "exp2", nodes=8, steps=steps)
    spec.roles = ["sensor", "relay"] * 4
    return spec


@pytest.mark.parametrize("point", [False, True])
def test_relays_never_measure_and_track_through_fusion(point):
    spec = alternating_relays(point=point)
    with_relays = simulate(spec, runs=2, seed=3)
    spec.roles = None
    plain = simulate(spec, runs=2, seed=3)
    # the same random draws: only `present` and `roles` differ
    for key in ("truth", "measurements", "x0_estimate"):
        assert np.array_equal(getattr(with_relays, key), getattr(plain, key)), key
    relay = with_relays.roles == "relay"
    assert relay.tolist() == [False, True] * 4 and (plain.roles == "sensor").all()
    assert not with_relays.present[:, :, relay].any() and with_relays.present[:, :, ~relay].all()
    with_relays.validate()
    res = run_filter(with_relays, "dteskf")
    assert np.all(np.isfinite(res.mean)) and (res.diverged_at < 0).all()
    err = np.linalg.norm(res.errors(with_relays)[:, 30:, :, :3], axis=-1)
    rmse = np.sqrt((err**2).mean(axis=(0, 1)))
    assert rmse[relay].max() < 15.0  # relays track through fusion alone
    # a relay holds less information than a sensor: its posterior covariance is larger on average
    # (its RMSE need not be: averaging two neighbours' estimates often beats one's own bearing)
    trace = np.trace(res.cov[:, 30:, :, :3, :3], axis1=-2, axis2=-1).mean(axis=(0, 1))
    assert trace[relay].mean() >= trace[~relay].mean()
    m = evaluate(with_relays, res)
    assert m["anees"] <= m["anees_band"][1]


def test_roles_are_validated():
    spec = alternating_relays(steps=5)
    spec.roles = ["sensor", "relay", "watcher"] + ["sensor"] * 5
    with pytest.raises(ValueError, match="roles.*watcher"):
        simulate(spec)
    spec.roles = ["sensor"] * 7
    with pytest.raises(ValueError, match="roles: expected 8"):
        spec.validate()
    spec.roles = ["sensor", "relay"] * 4
    scn = simulate(spec)
    scn.present = scn.present.copy()
    scn.present[0, 2, 1] = True
    with pytest.raises(ValueError, match="relay"):
        scn.validate()
    scn.present[0, 2, 1] = False
    scn.roles = np.array(["sensor"] * 8)
    scn.validate()
    scn.roles = np.array(["sensor"] * 3)
    with pytest.raises(ValueError, match="roles"):
        scn.validate()
    assert isinstance(spec, ScenarioSpec)
