"""``zentrack bench scale``: every size's misses, lost estimates and CPU per step per process type."""
from __future__ import annotations

import json
import os

import pytest

from zentrack.bench.scale import cpu_per_step, cpu_seconds


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


@pytest.mark.slow
def test_bench_scale_reports_every_size_with_lost_estimates_and_cpu(tmp_path):
    from zentrack.cli import main

    out = tmp_path / "scale.json"
    assert main(["bench", "scale", "--sizes", "2,3", "--duration", "18", "--all", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert [r["nodes"] for r in data["results"]] == [2, 3]
    for r in data["results"]:
        assert r["expected_estimates"] == r["nodes"] * 180
        assert r["published_estimates"] >= r["estimates"] and r["lost_estimates"] >= 0
        assert r["passes"] == (r["deadline_misses"] == 0 and r["lost_estimates"] == 0
                               and r["estimates"] == r["expected_estimates"])
        cpu = r["cpu_ms_per_step"]
        assert cpu["tracker"]["processes"] == r["nodes"] and 0 < cpu["tracker"]["mean_ms"] < 100
        assert {"truth", "recorder"} <= set(cpu)
    assert [r["topology"] for r in data["results"]] == ["peers", "peers"]  # auto: a mesh up to 12 trackers
    assert data["largest_passing_n"] in (None, 2, 3)
