"""``zentrack bench step``: an in-process lockstep network runs every step, and each piece of a step is timed."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

ZENTRACK = str(Path(sys.executable).with_name("zentrack"))


def test_bench_step_runs_the_network_to_the_end_and_times_every_piece(tmp_path):
    out = subprocess.run([ZENTRACK, "bench", "step", "--nodes", "4", "--steps", "30", "--rounds", "1",
                          "--json", str(tmp_path / "step.json")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads((tmp_path / "step.json").read_text())
    assert doc["nodes"] == 4 and doc["steps"] == 30 and doc["mean_degree"] >= 1
    assert 0 < doc["us_per_node_step"] < 1e5
    pieces = doc["pieces_us"]
    assert {"decode prior", "local update", "gate: test"} <= set(pieces)
    assert all(0 < us < 1e5 and math.isfinite(us) for us in pieces.values())
    assert doc["ci_general_over_one"] > 0 and "µs per node-step" in out.stdout


def test_bench_step_idle_times_the_same_steps_with_a_gap_before_every_call(tmp_path):
    out = subprocess.run([ZENTRACK, "bench", "step", "--nodes", "3", "--steps", "20", "--rounds", "1", "--idle-ms", "1",
                          "--json", str(tmp_path / "step.json")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    idle = json.loads((tmp_path / "step.json").read_text())["idle"]
    assert idle["idle_ms"] == 1.0 and idle["steps"] == 20
    assert 0 < idle["us_per_node_step_busy"] < 1e5 and 0 < idle["us_per_node_step_idle"] < 1e5
    assert idle["idle_over_busy"] == idle["us_per_node_step_idle"] / idle["us_per_node_step_busy"]
    assert "idle before every call" in out.stdout
    bad = subprocess.run([ZENTRACK, "bench", "step", "--idle-ms", "-5"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--idle-ms" in bad.stderr
