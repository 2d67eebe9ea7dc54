"""Paper 4's network algorithms (study/eot_network.py), scenarios (truth/simulation/eot_scenario.py) and bench."""
from __future__ import annotations

import json

import numpy as np
import pytest

from zentrack.cli import main as cli_main
from zentrack.config.scenario_config import ScenarioConfigError, load_scenario_config, parse
from zentrack.study.eot_network import (
    ExtentInformation,
    _combine_info,
    align_orientation,
    run_eot_network,
    run_eot_scenario,
)
from zentrack.truth.simulation.simulate import simulate


def _run(data, algorithm, rounds=1, weights=None):
    if weights is None:
        return run_eot_scenario(algorithm, data, rounds)
    return run_eot_network(algorithm, data.scan_returns, data.scan_counts, data.roles == "sensor", weights,
                           data.motion_model(), data.noise_cov[0], data.measurement_model().spread,
                           data.x0_estimate[:, :4], data.p0[:4, :4], data.x0_estimate[:, 4:], data.p0[4:, 4:],
                           rounds=rounds, adjacency=data.adjacency)


def _scenario(name="eot-s2", steps=12, runs=3, seed=7, rate=5.0):
    cfg = load_scenario_config(name)
    cfg.spec.steps, cfg.spec.extent.rate = steps, rate
    return simulate(cfg.spec, runs, seed, cfg.ts)


@pytest.fixture(scope="module")
def s2():
    return _scenario()


def test_scenario_has_the_paper_network_and_scans(s2):
    sensing = s2.roles == "sensor"
    assert s2.scan_returns.shape[:3] == (3, 12, 20) and sensing.sum() == 6
    assert np.all(s2.scan_counts[:, :, ~sensing] == 0)  # relays never measure
    assert 3 < s2.scan_counts[:, :, sensing].mean() < 7  # Poisson(5)
    np.testing.assert_allclose(s2.weights.sum(axis=1), 1.0)
    truth = s2.truth[0]
    np.testing.assert_allclose(np.arctan2(truth[:, 3], truth[:, 2]), truth[:, 4], atol=1e-12)  # aligned
    np.testing.assert_allclose(truth[:, 5:], [[170.0, 40.0]] * 12)
    again = _scenario(runs=1)
    np.testing.assert_array_equal(again.scan_returns[0], s2.scan_returns[0])  # run r does not depend on R
    s2.validate()


def test_the_rectangle_scenario_has_its_own_noise_and_spread():
    s3 = _scenario("eot-s3", steps=3, runs=1)
    np.testing.assert_allclose(s3.noise_cov[0], np.eye(2))
    np.testing.assert_allclose(s3.measurement_model().spread, np.eye(2) / 3)
    np.testing.assert_allclose(s3.truth[0, 0, 5:], [10.0, 5.0])


def test_extent_settings_are_checked():
    from importlib import resources

    text = (resources.files("zentrack.scenarios") / "eot-s2.toml").read_text()
    for old, new, key in [("rate = 5.0 ", "rate = -1.0 ", "extent.rate"),
                          ("sensors = 6", "sensors = 60", "extent"),
                          ("semi_axes = [170.0, 40.0]", "semi_axes = [170.0]", "extent.semi_axes"),
                          ('layout = "placed"', 'layout = "ring"', "sensors.layout"),
                          ('kind = "placed"', 'kind = "ring"', "graph.kind")]:
        assert old in text
        with pytest.raises(ScenarioConfigError, match=key.replace(".", r"\.")):
            parse("eot", text.replace(old, new))


@pytest.mark.slow
@pytest.mark.cpu_only
def test_cm_with_many_rounds_is_the_centralized_filter(s2):
    ceot = _run(s2, "ceot")
    cm = _run(s2, "cm", rounds=300)
    for node in range(20):
        np.testing.assert_allclose(cm.x[:, :, node], ceot.x[:, :, 0], rtol=0, atol=1e-6)
        np.testing.assert_allclose(cm.p[:, :, node], ceot.p[:, :, 0], rtol=0, atol=1e-6)
        np.testing.assert_allclose(cm.cx[:, :, node], ceot.cx[:, :, 0], rtol=1e-6, atol=1e-9)


def test_cm_with_few_rounds_differs_from_the_centralized_filter(s2):
    ceot, cm = _run(s2, "cm", rounds=1), _run(s2, "ceot")
    assert np.abs(cm.x[:, -1] - ceot.x[:, -1]).max() > 1e-3


def test_ci_on_a_complete_graph_agrees_after_one_round(s2):
    w = np.full((20, 20), 1 / 20)
    ci = _run(s2, "ci", rounds=1, weights=w)
    spread = np.abs(ci.x - ci.x[:, :, :1]).max()
    assert spread < 1e-8  # every node holds the same average after each point's round


def test_ci_on_the_paper_graph_converges_with_rounds(s2):
    few, many = _run(s2, "ci", rounds=1), _run(s2, "ci", rounds=10)
    def disagreement(res):
        return np.abs(res.x - res.x.mean(axis=2, keepdims=True)).mean()
    assert disagreement(many) < 0.5 * disagreement(few)


def test_deot_combines_the_closed_neighbourhood_with_equal_weights(s2, rng):
    from zentrack.study.eot_network import _deot_step

    r, m = 2, 20
    adj = s2.adjacency
    equal = (adj | np.eye(m, dtype=bool)).astype(float)
    equal /= equal.sum(axis=1, keepdims=True)
    x = rng.normal(size=(r, m, 4))
    p = np.concatenate([rng.uniform(-0.5, 0.5, (r, m, 1)), rng.uniform(10, 200, (r, m, 2))], axis=-1)
    cx = np.broadcast_to(np.eye(4), (r, m, 4, 4)) * rng.uniform(1, 2, (r, m, 1, 1))
    cp = np.broadcast_to(np.eye(3), (r, m, 3, 3)) * rng.uniform(1, 2, (r, m, 1, 1))
    no_points = np.zeros((r, m), dtype=int)  # nothing to update: only the combination acts
    xo, cxo, po, cpo = _deot_step(np.zeros((r, m, 1, 2)), no_points, x, cx, p, cp, equal, s2.noise_cov[0],
                                  s2.measurement_model().spread)
    for i in range(m):
        hood = np.flatnonzero(adj[i]).tolist() + [i]
        np.testing.assert_allclose(xo[:, i], x[:, hood].mean(axis=1))
        np.testing.assert_allclose(po[:, i], p[:, hood].mean(axis=1))
        np.testing.assert_allclose(cxo[:, i], cx[:, hood].mean(axis=1))


def test_orientation_is_averaged_as_an_angle():
    w = np.array([[0.5, 0.5], [0.5, 0.5]])
    alpha = np.array([[np.pi - 0.1, -np.pi + 0.1]])
    aligned = align_orientation(alpha, w)
    np.testing.assert_allclose(np.cos(aligned), np.cos(alpha)[:, None, :].repeat(2, axis=1))
    assert np.ptp(aligned[0, 0]) < 0.3  # both within pi of the mean: 0.2 apart, not 2 pi - 0.2
    # the averaged information gives the mean orientation near pi, not near 0
    x = np.zeros((1, 2, 4))
    p = np.stack([alpha[0], [100.0, 100.0], [20.0, 20.0]], axis=-1)[None]
    cx = np.broadcast_to(np.eye(4), (1, 2, 4, 4)).copy()
    cp = np.broadcast_to(np.diag([0.01, 4.0, 4.0]), (1, 2, 3, 3)).copy()
    fused = _combine_info(ExtentInformation.from_moments(x, cx, p, cp), w)
    _, _, p_f, _ = fused.moments()
    assert abs(abs(p_f[0, 0, 0]) - np.pi) < 1e-9


def test_bad_arguments_are_refused(s2):
    with pytest.raises(ValueError, match="algorithm"):
        _run(s2, "nope")
    with pytest.raises(ValueError, match="rounds"):
        _run(s2, "ci", rounds=0)
    with pytest.raises(ValueError, match="extended-object"):
        run_eot_scenario("ci", simulate(load_scenario_config("exp2").spec, 1, 0, 0.1))


def test_bench_paper4_reports_every_method_and_checks_the_findings(tmp_path, capsys):
    out = tmp_path / "p4.json"
    assert cli_main(["bench", "paper4", "--runs", "2", "--steps", "10", "--rates", "5", "--rounds", "1,4",
                     "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "GW distance" in text and "OSPA corners" in text and "CM improves with L" in text
    data = json.loads(out.read_text())
    assert set(data["cases"]) == {"eot-s2 lambda=5", "eot-s3 lambda=5"}
    for case in data["cases"].values():
        assert set(case["methods"]) == {"ceot", "ci L=1", "ci L=4", "cm L=1", "cm L=4", "deot", "ci/scan L=4", "cm/scan L=4"}
        for row in case["methods"].values():
            assert len(row["shape_error_per_scan"]) == 10 and np.isfinite(row["shape_error"])
        assert len(case["findings"]) == 5 and all(isinstance(f["holds"], bool) for f in case["findings"])
    assert (tmp_path / "p4.png").stat().st_size > 5_000
