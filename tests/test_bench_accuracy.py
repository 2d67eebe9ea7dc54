"""``zentrack bench accuracy`` and its second scenario, ``exp2-irregular``."""
from __future__ import annotations

import json

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.consensus_weights import graph_diameter
from zentrack.fusion.graphs import check_weights
from zentrack.fusion.motion import ManeuveringCV3D
from zentrack.truth.simulation.simulate import simulate


def test_the_irregular_scenario_has_a_connected_random_graph_and_a_turning_target():
    spec = builtin_spec("exp2-irregular")
    adj = np.asarray(spec.adjacency, bool)
    assert adj.sum() // 2 != spec.nodes, "not a ring"
    assert graph_diameter(adj) >= 2
    scn = simulate(spec, runs=1, seed=0)
    check_weights(scn.weights, scn.adjacency)  # connected, row-stochastic, primitive
    d = np.diff(scn.sensors[:, :2], axis=0)
    assert np.std(np.linalg.norm(d, axis=1)) > 50.0, "irregular spacing"
    heading = np.unwrap(np.arctan2(scn.truth[0, :, 4], scn.truth[0, :, 3]))
    assert abs(heading[-1] - heading[0]) > 2 * np.pi, "the target turns more than once around"


def test_the_turn_rate_enters_the_dynamics_and_its_jacobian():
    plant = ManeuveringCV3D(ts=0.1, turn_rate=0.3)
    x = np.array([[1.0, 2.0, 3.0, 0.7, -0.4, 0.2]])
    eps = 1e-6
    numeric = np.stack([(plant.f(x + eps * e) - plant.f(x - eps * e))[0] / (2 * eps) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(plant.jacobian(x)[0], numeric, atol=1e-6)
    still = ManeuveringCV3D(ts=0.1)
    assert np.abs(plant.f(x) - still.f(x)).max() > 1e-3


def test_bench_accuracy_prints_and_writes_every_configuration(tmp_path, capsys):
    from zentrack.cli import main

    out = tmp_path / "acc.json"
    assert main(["bench", "accuracy", "--runs", "2", "--steps", "60", "--scenarios", "exp2", "--filters", "eskf",
                 "--rules", "ci,ci+share,hcmci,hcmci(omega=N)", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "best single-round distributed configuration" in text
    data = json.loads(out.read_text())
    rows = {(r["filter"], r["rule"]): r for r in data["scenarios"][0]["rows"]}
    assert set(rows) == {("ceskf", None), ("deskf", "ci"), ("deskf", "ci+share"), ("deskf", "hcmci"),
                         ("deskf", "hcmci(omega=N)")}
    assert rows[("ceskf", None)]["bytes_per_node_step"] == 0
    plain, shared = rows[("deskf", "ci")], rows[("deskf", "ci+share")]
    assert shared["bytes_per_node_step"] > plain["bytes_per_node_step"] > 200, "a scan costs bytes"
    for r in rows.values():
        assert len(r["rmse_over_sqrt_bound"]["p"]["runs"]) == 2 and r["us_per_node_step"] > 0
    # the paper's omega = N over-counts the neighbours' scans after one round: less consistent
    assert rows[("deskf", "hcmci(omega=N)")]["anees"] > rows[("deskf", "hcmci")]["anees"]
    assert out.with_suffix(".png").stat().st_size > 5000 and out.with_suffix(".svg").stat().st_size > 5000
    assert f"bench accuracy done: json {out}, plot {out.with_suffix('.png')} {out.with_suffix('.svg')}" in text


def test_bench_accuracy_refuses_an_unknown_rule(capsys):
    from zentrack.cli import main

    with pytest.raises(SystemExit) as refused:
        main(["bench", "accuracy", "--rules", "ci,nope"])
    assert refused.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "argument --rules: unknown rule(s) ['nope']" in err
