"""Recovery on a loaded host (issue 30, item 4): a short soak beside a CPU hog that keeps both cores busy
(``zentrack soak --cpu-hog 2``) passes every criterion, and each restarted tracker publishes again within 20
steps; the hog's value is checked at parse time and its processes are gone when the soak ends.

Link cuts need the namespace harness (root, and one harness per host at a time): the loaded soak here runs on
loopback with kills and a freeze; ``test_soak.py::test_short_soak`` covers cuts on an unloaded harness."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from zentrack.cli import main
from zentrack.cluster import lean_start
from zentrack.cluster.cpu_hog import CpuHog

RESTART_TO_PUBLISH_LIMIT = 20


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except OSError:
        return False


def cpu_ticks(pid: int) -> int:
    """User plus system clock ticks of a running process (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().split(") ")[1].split()
    except OSError:
        return 0
    return int(fields[11]) + int(fields[12])


def test_cpu_hog_keeps_cores_busy_and_leaves_nothing():
    hog = CpuHog(2)
    hog.start()
    pids = [p.pid for p in hog.procs]
    end = time.time() + 30
    while not all(cpu_ticks(pid) >= 20 for pid in pids) and time.time() < end:  # each has run 0.2 s
        time.sleep(0.1)
    assert all(cpu_ticks(pid) >= 20 for pid in pids), "every hog runs"
    report = hog.stop()
    assert report["processes"] == 2 and report["pids"] == pids
    assert report["cpu_s"] >= 0.4, report
    assert not any(alive(pid) for pid in pids), "every hog is stopped and reaped"


@pytest.mark.parametrize("value", ["-1", "65", "2.5", "nan", "lots"])
def test_cpu_hog_value_is_checked_before_anything_starts(tmp_path, capsys, value):
    out = tmp_path / "soak"
    with pytest.raises(SystemExit) as stop:
        main(["soak", "--cpu-hog", value, "--cut-every", "0", "--out", str(out)])
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--cpu-hog" in lines[0], lines
    assert not out.exists(), "nothing started, nothing written"


def test_lean_start_sets_one_blas_thread_unless_the_user_chose(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "")
    assert lean_start.prepare()["thread_variables"] == {"OPENBLAS_NUM_THREADS": "3"}
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    assert lean_start.prepare()["thread_variables"] == {"OPENBLAS_NUM_THREADS": "1"}
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"


@pytest.mark.slow
def test_soak_beside_a_cpu_hog_recovers_every_restart_within_20_steps(tmp_path):
    out = tmp_path / "soak"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--duration", "40", "--nodes", "6",
                           "--kill-every", "8", "--freeze-every", "20", "--cut-every", "0", "--cpu-hog", "2",
                           "--out", str(out)], capture_output=True, text=True, timeout=400)
    report = json.loads((out / "report.json").read_text())
    crit = report["criteria"]
    restarts = crit["restart_recovery"]["restarts"]
    figures = {"restart_to_publish": [r["steps_to_publish"] for r in restarts], "hog": report["cpu_hog"],
               "failed": {name: c for name, c in crit.items() if not c["pass"]}}
    assert report["cpu_hog"]["processes"] == 2 and report["cpu_hog"]["cores_busy"] > 1.0, figures
    assert len(restarts) == 4 and sum(f["action"] == "freeze" for f in report["faults"]) == 1, figures
    assert all(r["steps_to_publish"] is not None and r["steps_to_publish"] <= RESTART_TO_PUBLISH_LIMIT
               for r in restarts), figures
    assert crit["fault_recovery"]["worst_steps"] <= RESTART_TO_PUBLISH_LIMIT, figures
    assert report["pass"] and not figures["failed"], figures
    assert proc.returncode == 0 and "soak passed" in proc.stdout, proc.stdout + proc.stderr[-2000:]
    assert not any(alive(pid) for pid in report["cpu_hog"]["pids"]), "the hog is gone with the soak"
