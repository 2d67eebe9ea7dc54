"""``zentrack bench scale``: every size's misses, lost estimates and CPU per step per process type."""
from __future__ import annotations

import json
import os

import pytest

from zentrack.bench.scale import cpu_per_step, cpu_seconds, figures, passes


def test_cpu_seconds_of_this_process_grow_with_work_and_a_dead_pid_has_none():
    before = cpu_seconds(os.getpid())
    sum(i * i for i in range(2_000_000))
    assert cpu_seconds(os.getpid()) > before
    assert cpu_seconds(2**22 + 12345) is None


def test_cpu_per_step_groups_trackers_and_keeps_the_other_types_apart():
    before = {"node-0": 1.0, "node-1": 2.0, "truth": 0.5, "recorder": 3.0}
    after = {"node-0": 1.2, "node-1": 2.4, "truth": 0.6, "recorder": 3.3, "viewer": 9.0}  # viewer: no start
    cpu = cpu_per_step(before, after, steps=100)
    assert cpu["tracker"]["processes"] == 2
    assert cpu["tracker"]["mean_ms"] == pytest.approx(3.0) and cpu["tracker"]["max_ms"] == pytest.approx(4.0)
    assert cpu["truth"]["mean_ms"] == pytest.approx(1.0) and "viewer" not in cpu


def test_a_sizes_figures_are_its_runs_counts_and_a_lost_estimate_fails_it():
    """Two trackers, 10 steps: node 1 published 10 estimates of which the recorder got 8 (2 lost), node 0 missed
    its deadline once (9 published, 9 recorded)."""
    def node(published, recorded, late):
        return {"estimates_published": published, "steps_estimated": recorded, "messages": {"late": late},
                "gaps": [[3, 3]] if recorded < 10 else []}

    summary = {"nodes": [node(9, 9, 1), node(10, 8, 0)],
               "network": {"deadline_misses": 1, "latency_ms": {"p50": 1.0}, "estimates": 17, "estimates_lost": 2}}
    r = figures(summary, 2, 10, router=False, cpu={})
    assert (r["published_estimates"], r["estimates"], r["lost_estimates"], r["expected_estimates"]) == (19, 17, 2, 20)
    assert r["published_estimates"] - r["estimates"] == r["lost_estimates"]  # node 0's miss was never published
    assert (r["deadline_misses"], r["late_priors"], r["gaps"], r["topology"]) == (1, 1, 2, "peers")
    assert not passes(r)
    clean = {"nodes": [node(10, 10, 0)] * 2,
             "network": {"deadline_misses": 0, "latency_ms": {}, "estimates": 20, "estimates_lost": 0}}
    assert passes(figures(clean, 2, 10, router=True, cpu={}))
    lost_one = {**clean, "network": {**clean["network"], "estimates": 19, "estimates_lost": 1}}
    assert not passes(figures(lost_one, 2, 10, router=True, cpu={}))


@pytest.mark.slow
def test_bench_scale_reports_every_size_with_lost_estimates_and_cpu(tmp_path):
    """Every figure of a size is the run's own: checked against the run's summary.json, node by node (lost =
    published and never recorded, so a bench that dropped, double-counted or made up a figure fails)."""
    from zentrack.cli import main

    out, runs = tmp_path / "scale.json", tmp_path / "runs"
    assert main(["bench", "scale", "--sizes", "2,3", "--duration", "18", "--all", "--json", str(out),
                 "--out", str(runs)]) == 0
    data = json.loads(out.read_text())
    assert [r["nodes"] for r in data["results"]] == [2, 3]
    for r in data["results"]:
        summary = json.loads((runs / f"n{r['nodes']}" / "summary.json").read_text())
        nodes = summary["nodes"]
        assert len(nodes) == r["nodes"] and r["expected_estimates"] == r["nodes"] * 180
        published = [n["estimates_published"] for n in nodes]
        recorded = [n["steps_estimated"] for n in nodes]
        assert r["published_estimates"] == sum(published) > 0
        assert r["estimates"] == sum(recorded) == summary["network"]["estimates"] <= r["expected_estimates"]
        assert r["lost_estimates"] == sum(max(0, p - k) for p, k in zip(published, recorded, strict=True))
        assert r["deadline_misses"] == summary["network"]["deadline_misses"]
        assert r["passes"] == (r["deadline_misses"] == 0 and r["lost_estimates"] == 0
                               and r["estimates"] == r["expected_estimates"])
        cpu = r["cpu_ms_per_step"]
        assert cpu["tracker"]["processes"] == r["nodes"] and 0 < cpu["tracker"]["mean_ms"] < 100
        assert {"truth", "recorder"} <= set(cpu)
    assert [r["topology"] for r in data["results"]] == ["peers", "peers"]  # auto: a mesh up to 12 trackers
    passing = [r["nodes"] for r in data["results"] if r["passes"]]
    assert data["largest_passing_n"] == (max(passing) if passing else None)
