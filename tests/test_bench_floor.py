"""``zentrack bench floor``: null trackers (messaging only) as separate processes through a router; every
estimate arrives, the CPU and memory figures are each process's own, bad flags are refused in one line."""
from __future__ import annotations

import json
import math

import pytest

from zentrack.bench.floor import estimates


@pytest.mark.parametrize("argv", [["--sizes", "0"], ["--duration", "-1"], ["--sizes", "x"],
                                  ["--variant", "timer"], ["--tracker-runtime", "tiny"]])
def test_bench_floor_refuses_a_bad_flag_in_one_line_with_exit_2(argv, capsys, monkeypatch):
    from zentrack.bench import floor
    from zentrack.cli import main

    monkeypatch.setattr(floor, "measure", lambda *a: pytest.fail("processes started"))
    try:
        code = main(["bench", "floor", *argv])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and argv[0] in err, err


def test_estimates_count_the_steps_measured_in_the_window_once_each_and_the_late_ones():
    """Steps 0..9 at 0.1 s from t = 100; the window [100.25, 100.75) holds steps 3..7 (5 steps, 2 trackers)."""
    rows = [(k, i, 100 + 0.1 * k, 100 + 0.1 * k + (0.15 if (k, i) == (4, 1) else 0.05), 2)
            for k in range(10) for i in range(2) if (k, i) != (5, 0)]
    rows.append((6, 1, 100.6, 100.66, 2))  # a duplicate counts once
    e = estimates(rows, 2, 100.0, 100.25, 100.75)
    assert (e["steps"], e["expected"], e["received"], e["late_gt_100ms"]) == (5, 10, 9, 1)
    assert e["latency_ms_p50"] == pytest.approx(50.0, abs=1.0) and e["latency_ms_p99"] > 100
    assert estimates([], 2, 100.0, 100.25, 100.75)["expected"] == 10  # none received: still 10 expected


@pytest.mark.slow
def test_bench_floor_receives_every_estimate_and_measures_each_process(tmp_path):
    """Four null trackers, 12 s: every estimate of the steady state reaches the recorder; each process type's
    CPU per step is finite and positive, the trackers' resident memory too; the JSON has the keys
    docs/performance.md names."""
    from zentrack.cli import main

    out = tmp_path / "floor.json"
    assert main(["bench", "floor", "--sizes", "4", "--duration", "12", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["failed"] == [] and [r["n"] for r in data["results"]] == [4]
    r = data["results"][0]
    e = r["estimates"]
    assert e["steps"] >= 50 and e["expected"] == 4 * e["steps"]
    assert e["received"] == e["expected"], f"estimates lost: {e}"
    assert e["latency_ms_p50"] >= 50.0  # a null tracker publishes at its 50 ms deadline
    cpu = r["cpu_ms_per_step"]
    assert cpu["tracker"]["processes"] == 4 and {"router", "truth", "recorder"} <= set(cpu)
    for kind in ("tracker", "router", "truth", "recorder"):
        assert math.isfinite(cpu[kind]["mean_ms"]) and cpu[kind]["mean_ms"] > 0, kind
    assert cpu["tracker"]["mean_ms"] <= cpu["tracker"]["max_ms"] < 100
    assert r["memory_mb"]["tracker"]["rss_mean_mb"] > 0 and r["memory_mb"]["tracker"]["processes"] == 4
    for key in ("bench_cores_busy", "foreign_cores_busy", "machine_cores_busy", "load_avg_1min", "window_s"):
        assert math.isfinite(r[key]), key
    assert 0 < r["bench_cores_busy"] <= r["machine_cores_busy"] + 0.05
    assert {"latency_ms_p99", "late_gt_100ms"} <= set(e)
    assert data["variant"] == "queue" and data["tracker_runtime"] == "default"
