"""Scans, typed single-node estimates and the node-level filter (GaussianNodeFilter) against the batched one."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.estimates import (
    CompositeEstimate,
    GaussianEstimate,
    InformationEstimate,
    ParticleEstimate,
)
from zentrack.fusion.filters import FilterContext, GaussianNodeFilter, NodeFilter, make_node_filter
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information
from zentrack.fusion.rules import RULE_REGISTRY, RoundContribution, next_round_blocks, stack_messages
from zentrack.fusion.scan import Scan
from zentrack.study.simulator import build_filter, run_filter
from zentrack.truth.simulation.simulate import simulate

NOISE = np.diag([1e-4, 2e-4])


def good_scan(**changes):
    fields = dict(step=3, sensor=1, returns=np.array([[0.1, 0.2]]), pose=np.array([1.0, 2.0, 3.0]), noise_cov=NOISE)
    fields.update(changes)
    return Scan(**fields)


def spd(rng, n):
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


# --- scans ---------------------------------------------------------------------------------------------------


def test_scan_constructors_and_counts():
    one = Scan.single(4, 2, [0.5, -0.1], [0.0, 1.0, 2.0], NOISE).validate()
    assert one.count == 1 and one.dim == 2 and one.returns.shape == (1, 2) and one.returns.dtype == float
    none = Scan.empty(4, 2, [0.0, 1.0, 2.0], NOISE).validate()
    assert none.count == 0 and none.returns.shape == (0, 2)
    many = good_scan(returns=np.zeros((5, 2))).validate()
    assert many.count == 5


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"step": -1}, "step"),
        ({"sensor": True}, "sensor"),
        ({"sensor": 1.0}, "sensor"),
        ({"returns": np.array([0.1, 0.2])}, "returns"),
        ({"returns": np.array([[0.1, np.nan]])}, "returns"),
        ({"pose": np.zeros(2)}, "pose"),
        ({"pose": np.array([0.0, np.inf, 0.0])}, "pose"),
        ({"noise_cov": np.eye(3)}, "noise_cov"),
        ({"noise_cov": np.diag([1e-4, -1e-4])}, "noise_cov"),
        ({"noise_cov": np.array([[1.0, 0.5], [0.0, 1.0]])}, "noise_cov"),
    ],
)
def test_scan_validate_names_the_field(changes, field):
    with pytest.raises(ValueError, match=f"^{field}:"):
        good_scan(**changes).validate()


# --- estimates -----------------------------------------------------------------------------------------------


def test_gaussian_and_information_estimates_round_trip(rng):
    cov = spd(rng, 5)
    mean = rng.normal(size=5)
    g = GaussianEstimate(mean, cov, kinematic_dim=3)
    (name, pair), = g.information_blocks().items()
    assert name == "state" and pair.matrix.shape == (5, 5) and pair.vector.shape == (5,)
    np.testing.assert_allclose(pair.matrix @ cov, np.eye(5), atol=1e-12)
    np.testing.assert_allclose(pair.vector, np.linalg.solve(cov, mean), rtol=1e-12)
    info = InformationEstimate(pair.matrix, pair.vector, 3)
    back = info.gaussian()
    np.testing.assert_allclose(back.mean, mean, rtol=1e-10)
    np.testing.assert_allclose(back.cov, cov, rtol=1e-10)
    assert back.kinematic_dim == 3
    np.testing.assert_array_equal(info.information_blocks()["state"].matrix, pair.matrix)
    # batch-of-one conversions are exact
    state = g.to_state()
    assert state.mean.shape == (1, 5) and state.cov.shape == (1, 5, 5)
    again = GaussianEstimate.from_state(state, 3)
    np.testing.assert_array_equal(again.mean, mean)
    np.testing.assert_array_equal(again.cov, cov)
    np.testing.assert_array_equal(InformationEstimate.from_pair(info.to_pair()).matrix, info.matrix)
    # the same numbers as the batched pipeline
    np.testing.assert_array_equal(pair.matrix, to_information(state).matrix[0])
    kin = g.kinematic()
    np.testing.assert_array_equal(kin.mean, mean[:3])
    np.testing.assert_array_equal(kin.cov, cov[:3, :3])
    assert GaussianEstimate(mean, cov).kinematic_dim == 5


def test_estimates_reject_bad_shapes():
    with pytest.raises(ValueError, match="cov"):
        GaussianEstimate(np.zeros(3), np.eye(2))
    with pytest.raises(ValueError, match="kinematic_dim"):
        GaussianEstimate(np.zeros(3), np.eye(3), kinematic_dim=4)
    with pytest.raises(ValueError, match="matrix"):
        InformationEstimate(np.eye(2), np.zeros(3))
    with pytest.raises(ValueError, match="weights"):
        ParticleEstimate(np.zeros((4, 2)), np.zeros(4))
    with pytest.raises(ValueError, match="weights"):
        ParticleEstimate(np.zeros((4, 2)), np.ones(3))
    with pytest.raises(ValueError, match="kinematic"):
        CompositeEstimate({"extent": GaussianEstimate(np.zeros(3), np.eye(3))})


def test_particle_summary_is_the_weighted_mean_and_covariance(rng):
    samples = rng.normal(size=(400, 4)) * [1.0, 2.0, 3.0, 0.5] + [1.0, -2.0, 0.0, 4.0]
    weights = rng.uniform(0.1, 3.0, size=400)  # not normalised
    p = ParticleEstimate(samples, weights, kinematic_dim=2)
    s = p.gaussian()
    np.testing.assert_allclose(s.mean, np.average(samples, axis=0, weights=weights), rtol=1e-12)
    np.testing.assert_allclose(s.cov, np.cov(samples.T, aweights=weights, ddof=0), rtol=1e-10)
    np.testing.assert_allclose(p.kinematic().mean, s.mean[:2], rtol=1e-12)
    np.testing.assert_allclose(p.information_blocks()["state"].matrix, np.linalg.inv(s.cov), rtol=1e-9)
    # a single particle with all the weight is that particle
    w = np.zeros(400)
    w[7] = 2.0
    np.testing.assert_array_equal(ParticleEstimate(samples, w).gaussian().mean, samples[7])


def test_composite_has_one_block_per_part_and_a_kinematic_block(rng):
    kin = GaussianEstimate(rng.normal(size=6), spd(rng, 6))
    extent = InformationEstimate(spd(rng, 3), rng.normal(size=3))
    comp = CompositeEstimate({"kinematic": kin, "extent": extent})
    blocks = comp.information_blocks()
    assert list(blocks) == ["kinematic", "extent"]
    np.testing.assert_array_equal(blocks["extent"].matrix, extent.matrix)
    np.testing.assert_array_equal(comp.kinematic().mean, kin.mean)
    assert comp.kinematic_dim == 6
    nested = CompositeEstimate({"kinematic": kin, "shape": comp})
    assert list(nested.information_blocks()) == ["kinematic", "shape.kinematic", "shape.extent"]


# --- the node-level filter -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scn():
    return simulate(builtin_spec("exp2", nodes=4, steps=30), runs=1, seed=5)


@pytest.mark.parametrize("kind", ["teskf", "ukf", "ekf"])
def test_single_scan_update_is_the_batched_per_node_call_bit_for_bit(scn, kind):
    lf = build_filter(scn, kind)
    node = GaussianNodeFilter(lf, scn.lumped_var, scn.p0)
    est = node.initial(scn.x0_estimate[0])
    state = lf.initial_state(scn.x0_estimate[0:1], scn.p0, scn.lumped_var)
    np.testing.assert_array_equal(est.mean, state.mean[0])
    np.testing.assert_array_equal(est.cov, state.cov[0])
    for k in range(5):
        i = k % scn.nodes
        z = scn.measurements[0, k, i]
        scan = Scan.single(k, i, z, scn.sensors[i], scn.noise_cov[i])
        est = node.update(est, [scan])
        state = lf.update(state, z[None, :], scn.sensors[i : i + 1, None], scn.noise_cov[i : i + 1])
        np.testing.assert_array_equal(est.mean, state.mean[0])
        np.testing.assert_array_equal(est.cov, state.cov[0])
        est, state = node.predict(est), lf.predict(state)
        np.testing.assert_array_equal(est.mean, state.mean[0])
        np.testing.assert_array_equal(est.cov, state.cov[0])
    assert node.kinematic(est).mean.shape == (6,)


def test_empty_and_missing_scans_coast_and_multi_return_scans_are_refused(scn):
    node = make_node_filter("teskf", FilterContext.from_scenario(scn), {"qbar": 1e-6})
    assert isinstance(node, NodeFilter) and node.state_dim == 12 and node.kinematic_dim == 6
    est = node.initial(scn.x0_estimate[0])
    empty = Scan.empty(0, 0, scn.sensors[0], scn.noise_cov[0])
    assert node.update(est, []) is est
    assert node.update(est, [empty]) is est
    z = scn.measurements[0, 0, 0]
    one = Scan.single(0, 0, z, scn.sensors[0], scn.noise_cov[0])
    with_empty = node.update(est, [empty, one])
    alone = node.update(est, [one])
    np.testing.assert_array_equal(with_empty.mean, alone.mean)
    assert not np.array_equal(alone.mean, est.mean)
    two = Scan(0, 0, np.vstack([z, z]), scn.sensors[0], scn.noise_cov[0])
    with pytest.raises(ValueError, match="2 returns"):
        node.update(est, [two])


def test_several_scans_stack_like_the_centralized_filter(scn):
    lf = build_filter(scn, "teskf")
    node = GaussianNodeFilter(lf, scn.lumped_var, scn.p0)
    est = node.initial(scn.x0_estimate[0])
    scans = [Scan.single(0, i, scn.measurements[0, 0, i], scn.sensors[i], scn.noise_cov[i]) for i in (0, 2)]
    got = node.update(est, scans)
    noise = np.zeros((4, 4))
    noise[:2, :2], noise[2:, 2:] = scn.noise_cov[0], scn.noise_cov[2]
    z = scn.measurements[0, 0, [0, 2]].reshape(1, 4)
    want = lf.update(est.to_state(), z, scn.sensors[[0, 2]][None], noise[None])
    np.testing.assert_array_equal(got.mean, want.mean[0])
    np.testing.assert_array_equal(got.cov, want.cov[0])


def test_from_fused_checks_the_blocks(scn):
    node = make_node_filter("ekf", FilterContext.from_scenario(scn))
    est = node.initial(scn.x0_estimate[0])
    back = node.from_fused({"state": est.to_state()}, like=est)
    np.testing.assert_array_equal(back.mean, est.mean)
    with pytest.raises(ValueError, match="state"):
        node.from_fused({"kinematic": est.to_state()}, like=est)
    with pytest.raises(TypeError, match="GaussianEstimate"):
        node.predict(InformationEstimate(np.eye(6), np.zeros(6)))


@pytest.mark.parametrize("rounds", [1, 3])
def test_a_network_of_node_filters_with_the_ci_rule_matches_the_batched_simulator(scn, rounds):
    """Paper 0 Algorithm 2 written per tracker with the node-level API (what a tracker process runs)."""
    ctx = FilterContext.from_scenario(scn)
    nodes = [make_node_filter("teskf", ctx) for _ in range(scn.nodes)]
    rule = RULE_REGISTRY.create("ci", {"rounds": rounds})
    priors = [f.initial(scn.x0_estimate[0]) for f in nodes]
    means = np.empty((scn.steps, scn.nodes, 6))
    for k in range(scn.steps):
        shared = []
        for i, f in enumerate(nodes):
            post = f.update(priors[i], [Scan.single(k, i, scn.measurements[0, k, i], scn.sensors[i], scn.noise_cov[i])])
            means[k, i] = f.kinematic(post).mean
            shared.append(f.predict(post))
        blocks = [f.blocks(est) for f, est in zip(nodes, shared)]
        for rnd in range(1, rule.rounds(k) + 1):
            msgs = [rule.share(rnd, b) for b in blocks]
            assert all(isinstance(m, RoundContribution) and m.scans == [] for m in msgs)
            fused_all = []
            for i in range(scn.nodes):
                senders = [i] + [int(j) for j in np.flatnonzero(scn.adjacency[i])]
                w = scn.weights[i, senders][None]
                fused_all.append(rule.combine(rnd, w, stack_messages([msgs[j] for j in senders]), np.ones_like(w, bool)))
            blocks = [next_round_blocks(fused) for fused in fused_all]
        priors = [f.from_fused(fused, like=shared[i]) for i, (f, fused) in enumerate(zip(nodes, fused_all))]
    batched = run_filter(scn, "dteskf", fusion=rule)
    np.testing.assert_allclose(batched.mean[0], means, rtol=1e-9, atol=1e-9)


def test_stack_messages_checks_blocks():
    a = RoundContribution({"state": InformationPair(np.eye(2), np.zeros(2))})
    b = RoundContribution({"other": InformationPair(np.eye(2), np.zeros(2))})
    stacked = stack_messages([a, a, a])
    assert stacked["state"].matrix.shape == (1, 3, 2, 2) and stacked["state"].vector.shape == (1, 3, 2)
    with pytest.raises(ValueError, match="different blocks"):
        stack_messages([a, b])
    with pytest.raises(ValueError, match="no message"):
        stack_messages([])
    assert isinstance(GaussianState(np.zeros((1, 2)), np.eye(2)[None]), GaussianState)
