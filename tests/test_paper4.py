"""Paper 4 live: extended-object trackers over Zenoh (lockstep = batched), the recording's shapes, the
scan wire format for many points, the consensus rules' orientation handling and the scaled period."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from zentrack.cli import main as cli_main
from zentrack.cluster.run.cluster import Cluster
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import load_scenario_config
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information
from zentrack.fusion.rules import make_rule
from zentrack.study.simulator import run_filter
from zentrack.transport import wire
from zentrack.transport.messages import Measurement
from zentrack.truth.simulation.simulate import simulate


def _scenario(steps: int, name: str = "eot-s2"):
    cfg = load_scenario_config(name)
    cfg.spec.steps = steps
    return simulate(cfg.spec, 1, cfg.seed, cfg.ts)


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["eot-ci", "eot-cm"])
def test_twenty_tracker_processes_equal_the_batched_simulator(tmp_path, rule):
    """20 processes (6 sensing, 14 relaying), 3 consensus rounds per scan, lockstep over Zenoh: every node's
    estimate equals the batched simulator's within 1e-9; the recording shows the shapes."""
    from test_viewer import column, read_rrd

    scn = _scenario(5)
    setup = RunSetup.from_data(scn, "mem-if", mode="lockstep", fusion=rule, fusion_params={"rounds": 3})
    with Cluster(setup, tmp_path / "run", viewer=[]) as cluster:
        cluster.start()
        assert cluster.wait(timeout=240) == 0
        cluster.write_results()
    est = np.load(tmp_path / "run" / "estimates.npz")
    ref = run_filter(scn, "dmem-if", make_rule(rule, {"rounds": 3}))
    assert est["mean"].shape == (5, 20, 7)
    np.testing.assert_allclose(est["mean"], ref.mean[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(est["cov"], ref.cov[0], rtol=1e-9, atol=1e-9)
    rec = read_rrd(tmp_path / "run" / "recording.rrd")
    assert len(column(rec["/world/truth/shape"], "step")) == 5
    relays = np.flatnonzero(scn.roles == "relay")
    sensors = np.flatnonzero(scn.roles == "sensor")
    for i in (sensors[0], relays[0]):
        outlines = column(rec[f"/world/nodes/{i}/shape"], "LineStrips3D:strips")
        assert len(outlines) == 5
        assert len(column(rec[f"/metrics/gw/{i}"], "step")) == 5
    assert len(column(rec[f"/world/nodes/{sensors[0]}/points"], "step")) >= 4  # Poisson(5): rarely empty
    assert f"/world/nodes/{relays[0]}/points" not in rec  # relays never measure
    assert "/world/sensors" in rec and "/world/relays" in rec and "/world/graph" in rec


def test_an_estimated_outline_follows_the_estimate(tmp_path):
    from zentrack.viewer.extent_view import ExtentView

    scn = _scenario(2)
    rows = []

    class Buf:
        def add(self, *row):
            rows.append(row)

    view = ExtentView(scn, Buf(), [[255, 0, 0]] * scn.nodes)
    x = np.array([100.0, -50.0, 1.0, 1.0, np.pi / 2, 170.0, 40.0])
    view.estimate(3, 7, x)
    entity, kind, step, strip, color, radius = rows[-1]
    assert (entity, kind, step) == ("world/nodes/3/shape", "segment", 7)
    strip = np.asarray(strip)
    np.testing.assert_allclose(strip[:, 2], 0.0)
    rel = strip[:, :2] - x[:2]
    # rotated by pi/2: the 170 m semi-axis lies along y, the 40 m one along x
    assert abs(np.abs(rel[:, 1]).max() - 170.0) < 1.0 and abs(np.abs(rel[:, 0]).max() - 40.0) < 1.0
    view.score(3, 7, x, x)
    assert rows[-1][0] == "metrics/gw/3" and abs(rows[-1][3]) < 1e-9


def test_a_hundred_point_scan_round_trips_and_an_oversized_one_is_refused():
    pts = np.random.default_rng(4).normal(0, 200, (100, 2))
    msg = Measurement.decode(Measurement(3, 30.0, 2, pts, np.zeros(3), 1.0).encode(), 2, 2)
    np.testing.assert_array_equal(msg.returns, pts)
    big = Measurement(3, 30.0, 2, np.zeros((wire.MAX_RETURNS + 1, 2)), None, 1.0).encode()
    with pytest.raises(wire.WireError) as err:
        Measurement.decode(big, 2, 2)
    assert err.value.reason in ("shape", "size") and str(wire.MAX_RETURNS) in str(err.value) or "bytes" in str(err.value)


def _pair(mean, var):
    mean = np.asarray(mean, dtype=float)[None]
    st = to_information(GaussianState(mean, np.diag(var)[None]))
    return st


def test_consensus_on_information_keeps_each_nodes_orientation_continuous():
    rule = make_rule("eot-ci", {"rounds": 1})
    var = [1.0, 1.0, 1.0, 1.0, 0.01, 1.0, 1.0]
    a = _pair([0, 0, 0, 0, np.pi - 0.05, 100, 20], var)
    b = _pair([0, 0, 0, 0, -np.pi + 0.05, 100, 20], var)
    stacked = InformationPair(np.stack([a.matrix[0], b.matrix[0]])[None], np.stack([a.vector[0], b.vector[0]])[None])
    fused = rule.combine(1, np.array([[0.5, 0.5], [0.5, 0.5]]), {"state": stacked})["state"]
    # node 0 (near +pi) and node 1 (near -pi) each get the mean at pi on their own side, not 0
    assert abs(fused.mean[0, 0, 4] - np.pi) < 1e-9 and abs(fused.mean[0, 1, 4] + np.pi) < 1e-9


def test_consensus_on_measurements_adds_omega_times_the_average_increment():
    rule = make_rule("eot-cm", {"rounds": 1, "omega": 2.0})
    prior = _pair([0, 0, 0, 0, 0.1, 100, 20], [4.0] * 7)
    inc = [InformationPair(np.eye(7)[None] * 0.5, np.full((1, 7), 1.0)), InformationPair(np.zeros((1, 7, 7)), np.zeros((1, 7)))]
    msgs = [rule.share(1, {"state": InformationPair(prior.matrix + d.matrix, prior.vector + d.vector), "increment": d}).blocks
            for d in inc]
    stacked = {k: InformationPair(np.stack([m[k].matrix[0] for m in msgs])[None], np.stack([m[k].vector[0] for m in msgs])[None])
               for k in ("prior", "increment")}
    fused = rule.combine(1, np.array([[0.5, 0.5]]), stacked)["state"]
    # own prior information + 2 x (0.5 x increment + 0.5 x 0)
    expect_y = prior.matrix[0] + np.eye(7) * 0.5
    np.testing.assert_allclose(np.linalg.inv(fused.cov[0, 0]), expect_y, rtol=1e-9)
    with pytest.raises(ValueError, match="increment"):
        rule.share(1, {"state": prior})


@pytest.mark.slow
def test_a_realtime_run_takes_the_scaled_period(tmp_path, capsys):
    """``--period`` sets the wall-clock step (the models keep T = 10 s): 6 scans at 1 s take seconds, not a
    minute, and the summary says so."""
    t0 = time.monotonic()
    code = cli_main(["run", "--scenario", "eot-s2", "--steps", "6", "--period", "1", "--out", str(tmp_path / "rt")])
    wall = time.monotonic() - t0
    assert code == 0, capsys.readouterr().out[-2000:]
    summary = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert summary["run"]["period_s"] == 1.0 and summary["run"]["ts"] == 10.0
    assert wall < 6 * 10.0  # a 10 s period would take a minute
