"""``zentrack bench async`` (issue 52): the methods a tracker has for late detections, the network that runs them, the
bound with every measurement at its own time, and the bench's JSON.

Each method is held to what it must equal: zero latency on the run's grid is the synchronous batched simulator;
the fixed lag with every detection in time is zero latency; re-processing reordered detections is zero latency;
the OOSM update Al1 is re-processing on a linear-Gaussian filter when one update came after the late detection;
drop late drops exactly the detections that arrive after a later one."""
from __future__ import annotations

import json

import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.estimates import GaussianEstimate
from zentrack.fusion.filters import FilterContext, make_node_filter
from zentrack.fusion.filters.interval import IntervalPredictor
from zentrack.fusion.measurement import PointModel
from zentrack.fusion.models import make_plant
from zentrack.fusion.motion_cd import ContinuousCV3D
from zentrack.fusion.rules import make_rule
from zentrack.fusion.scan import Scan
from zentrack.study.async_methods import METHODS, NodeModel, make_method
from zentrack.study.async_network import (
    AsyncSettings,
    RingFusion,
    run_detections,
    run_method,
    simulate_run,
    stream_specs,
    timed_bound,
)
from zentrack.study.pcrlb import scenario_bound
from zentrack.study.simulator import run_filter
from zentrack.truth.simulation.sensor_stream import SensorStreamSpec, SimulatedDetection
from zentrack.truth.simulation.simulate import simulate


def exp2(nodes: int = 4, steps: int = 30, runs: int = 1):
    scn = simulate(builtin_spec("exp2", nodes=nodes, steps=steps), runs=runs, seed=3)
    node = NodeModel.of(scn, "teskf", {"qbar": 1e-6, "theta": None})
    return scn, node, RingFusion(scn, node, make_rule("ci"))


def on_the_grid(scn):
    """Every node's measurement of every step as a detection at the step's time, arriving at once (offset 0)."""
    specs = [SensorStreamSpec(i, 1.0 / scn.ts) for i in range(scn.nodes)]
    dets = [[SimulatedDetection(k, k * scn.ts, k * scn.ts, k * scn.ts, scn.measurements[0, k, i][None])
             for k in range(scn.steps)] for i in range(scn.nodes)]
    return specs, dets


def test_zero_latency_on_the_run_grid_is_the_synchronous_simulator():
    """Sensors at the fusion rate, phase 0, no latency: after tick k's fusion every tracker updates with its step-k
    measurement, which is the batched simulator's posterior of step k (``zentrack sim``), to rounding."""
    scn, node, fusion = exp2()
    specs, dets = on_the_grid(scn)
    held: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    def observe(k, trackers):  # at tick k each tracker holds its posterior of step k - 1
        held[k] = [(node.filter.kinematic(tr.est).mean, node.filter.kinematic(tr.est).cov) for tr in trackers]

    simulate_run(scn, 0, dets, specs, "zero-latency", node, fusion, observe=observe)
    sync = run_filter(scn, "teskf", fusion="ci")
    for k in range(1, scn.steps):
        for i in range(scn.nodes):
            np.testing.assert_allclose(held[k][i][0], sync.mean[0, k - 1, i], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(held[k][i][1], sync.cov[0, k - 1, i], rtol=1e-9, atol=1e-12)


def test_the_fixed_lag_with_every_detection_in_time_is_zero_latency():
    """Latencies up to 300 ms, nothing reordered, a 350 ms lag: every window is complete when it is processed, so
    every tracker publishes at every tick what it would with no latency at all, fused 350 ms later."""
    scn, node, fusion = exp2(steps=40)
    settings = AsyncSettings(reorder=0.0)
    specs = stream_specs(scn.nodes, settings, seed=1)
    dets = [run_detections(scn, specs, 1, 0)]
    zero, _ = run_method(scn, dets, specs, "zero-latency", node, fusion, settings)
    lagged, records = run_method(scn, dets, specs, "fixed-lag", node, fusion, settings)
    assert records[0].counts.too_old == 0 and records[0].counts.applied == sum(len(d) for d in dets[0])
    np.testing.assert_allclose(lagged.mean, zero.mean, rtol=1e-12, atol=1e-9)
    assert np.all(records[0].age >= settings.lag_s)


def exact_cv_node(q: float = 0.5) -> NodeModel:
    """A Kalman filter (EKF on a linear model) of an exactly discretised constant velocity (its ``Q`` over two
    intervals is that of their sum), seen by a point sensor."""
    def cv(dt: float) -> FilterContext:
        motion = ContinuousCV3D(ts=dt, q=q, em_steps=1)
        motion.Q = motion.exact_q()
        return FilterContext(motion, PointModel(), np.diag([100.0, 100, 100, 10, 10, 10]))

    base = make_node_filter("ekf", cv(0.25))
    return NodeModel(base, IntervalPredictor(base, 0.25, lambda dt: make_node_filter("ekf", cv(dt))))


def one_sensor(late_s: float = 0.2, reorder: float = 0.3, n: int = 120, seed: int = 4):
    """A 4 Hz point sensor's scans (time, arrival, scan): latencies 10 ms to ``late_s``, a share ``reorder`` held
    one period more (as ``sensor_stream`` does)."""
    rng = np.random.default_rng(seed)
    t = 0.1 + np.arange(n) / 4.0
    truth = np.stack([5 * t, 2 * t, np.full(n, 3.0)], axis=1)
    z = truth + rng.normal(0, 2.0, truth.shape)
    arrival = t + rng.uniform(0.01, late_s, n) + np.where(rng.random(n) < reorder, 0.25, 0.0)
    return t, arrival, [Scan(0, 0, z[i][None], np.zeros(3), 4.0 * np.eye(3)) for i in range(n)]


def feed(name: str, node: NodeModel, t, order, scans):
    tracker = make_method(name, node, node.filter.initial(np.zeros(6)))
    for i in order:
        tracker.detection(float(t[i]), scans[i])
    return tracker


def test_reprocessing_is_zero_latency_and_al1_is_reprocessing_on_a_linear_system():
    node = exact_cv_node()
    t, arrival, scans = one_sensor()
    by_arrival = np.argsort(arrival, kind="stable")
    zero = feed("zero-latency", node, t, np.argsort(t), scans)
    again = feed("reprocess", node, t, by_arrival, scans)
    oosm = feed("oosm", node, t, by_arrival, scans)
    assert again.counts.late == oosm.counts.late >= 10 and again.counts.too_old == 0
    assert set(oosm.counts.lag_events) == {1}, "one update after each late detection: Al1's exact case"
    for other in (again, oosm):
        assert isinstance(other.est, GaussianEstimate) and isinstance(zero.est, GaussianEstimate)
        np.testing.assert_allclose(other.est.mean, zero.est.mean, rtol=0, atol=1e-9)
        np.testing.assert_allclose(other.est.cov, zero.est.cov, rtol=0, atol=1e-9)
    # a lag of several updates: re-processing stays exact, Al1's equivalent measurement comes close
    t, arrival, scans = one_sensor(late_s=0.7, seed=5)
    zero = feed("zero-latency", node, t, np.argsort(t), scans)
    again = feed("reprocess", node, t, np.argsort(arrival, kind="stable"), scans)
    oosm = feed("oosm", node, t, np.argsort(arrival, kind="stable"), scans)
    assert max(oosm.counts.lag_events) >= 2
    np.testing.assert_allclose(again.est.mean, zero.est.mean, rtol=0, atol=1e-9)
    assert np.abs(oosm.est.mean[:3] - zero.est.mean[:3]).max() < 0.1 * np.sqrt(zero.est.cov[0, 0])


def test_reprocessing_across_fusions_fuses_again_with_the_stored_messages():
    """Ticks every 0.5 s fuse the tracker's estimate with a neighbour's (CI, half and half); a late detection rolls
    back over them, and each is done again with the neighbour's message of its tick: the result is the tracker that
    had every detection in time order."""
    node, rule = exact_cv_node(), make_rule("ci")
    t, arrival, scans = one_sensor(late_s=0.7, seed=6)

    def neighbour_at(k: int):
        theirs = GaussianEstimate(np.array([5.0, 2.0, 3.0, 5.0, 2.0, 0.0]) * (0.5 * k + 0.1), 50.0 * np.eye(6))
        blocks = {name: (p.matrix, p.vector) for name, p in node.filter.blocks(theirs).items()}

        def refuse(est):
            mine = {name: (p.matrix, p.vector) for name, p in node.filter.blocks(est).items()}
            return node.filter.from_fused(rule.combine_one(1, np.array([0.5, 0.5]), [mine, blocks]), est)
        return refuse

    ticks = [(0.5 * k, 0, k) for k in range(1, int(t[-1] / 0.5))]

    def drive(name: str, when) -> object:
        tracker = make_method(name, node, node.filter.initial(np.zeros(6)))
        events = sorted(ticks + [(float(when[i]), 1, i) for i in range(len(t))])
        for _, kind, j in events:
            if kind == 0:
                refuse = neighbour_at(j)
                tracker.fused(j, 0.5 * j, refuse(tracker.share(j, 0.5 * j)), refuse)
            else:
                tracker.detection(float(t[j]), scans[j])
        return tracker

    zero, again = drive("zero-latency", t), drive("reprocess", arrival)
    assert again.counts.late >= 10 and again.counts.replayed > again.counts.rollbacks, "rolled back over events"
    np.testing.assert_allclose(again.est.mean, zero.est.mean, rtol=0, atol=1e-8)
    np.testing.assert_allclose(again.est.cov, zero.est.cov, rtol=1e-9, atol=1e-10)


def test_drop_late_drops_exactly_the_detections_that_arrive_after_a_later_one():
    node = exact_cv_node()
    t, arrival, scans = one_sensor()
    order = np.argsort(arrival, kind="stable")
    dropped = feed("drop-late", node, t, order, scans)
    overtaken = {int(i) for i in range(len(t)) if np.any((t > t[i]) & (arrival < arrival[i]))}
    assert dropped.counts.dropped == len(overtaken) >= 10 and dropped.counts.applied == len(t) - len(overtaken)
    kept = feed("zero-latency", node, t, [i for i in np.argsort(t) if int(i) not in overtaken], scans)
    np.testing.assert_array_equal(dropped.est.mean, kept.est.mean)


def test_the_timed_bound_on_the_grid_is_the_synchronous_bound_one_period_later():
    """With every measurement at a step's time, the bound at t_k holds those before it: the synchronous bound of
    step k - 1 predicted one period (``pcrlb_timed`` and ``pcrlb_per_run`` are one recursion)."""
    scn, _, _ = exp2(steps=25)
    _, dets = on_the_grid(scn)
    timed = timed_bound(scn, [dets])[0]
    sync = scenario_bound(scn)[0]
    plant = make_plant(scn.plant, scn.ts, scn.plant_params)
    np.testing.assert_allclose(timed[0], scn.p0, rtol=1e-12)
    for k in range(1, scn.steps):
        np.testing.assert_allclose(timed[k], plant.Q + plant.A @ sync[k - 1] @ plant.A.T, rtol=1e-8, atol=1e-10)


def test_the_bench_writes_every_method_and_the_stone_soup_rows(tmp_path, capsys):
    pytest.importorskip("stonesoup", reason="Stone Soup is the benchmark-only extra (pip install '.[bench]')")
    from zentrack.cli import main

    out = tmp_path / "async.json"
    assert main(["bench", "async", "--scenarios", "exp2", "--nodes", "3", "--steps", "30", "--runs", "2",
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "zero latency (reference)" in text and "aims: RMSE within 5% of zero latency" in text
    data = json.loads(out.read_text())
    (res,) = data["scenarios"]
    rows = {r["method"]: r for r in res["rows"]}
    assert list(rows) == [*METHODS, "stonesoup-asd", "stonesoup-buffered"]
    assert rows["zero-latency"]["vs_zero_latency"] is None and rows["stonesoup-asd"]["vs_zero_latency"] is None
    for name, r in rows.items():
        assert len(r["rmse_over_sqrt_bound"]["p"]["runs"]) == 2, name
        assert r["anees_band"] and r["cpu_us_per_detection"] > 0 and r["detections"] > 0, name
        assert {"max", "p99"} <= set(r["age_ms"]) and set(r["aims"]) == {"within_5_percent",
                                                                        "age_within_period_plus_lag"}, name
    assert rows["fixed-lag"]["age_ms"]["max"] >= 350.0 and rows["reprocess"]["age_ms"]["max"] < 50.0
    assert rows["drop-late"]["counts"]["dropped"] > 0 and rows["reprocess"]["counts"]["late"] > 0
    assert res["nodes"] == 3 and rows["stonesoup-asd"]["nodes"] == 1
    assert out.with_suffix(".png").stat().st_size > 5000 and out.with_suffix(".svg").stat().st_size > 5000
