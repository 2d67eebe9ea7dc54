"""The short soak of CI: 2 minutes, 6 trackers in network namespaces, kill/freeze/cut faults, judged
against a fault-free run of the same seed."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from zentrack.soak import schedule

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="link cuts use network namespaces, which need root (CI runs as root)")


def test_fault_schedule_is_seeded_and_paired():
    import argparse

    args = argparse.Namespace(duration=600.0, nodes=10, kill_every=30.0, freeze_every=60.0, cut_every=90.0,
                              fault_s=5.0, restart_after=2.0, seed=3)
    events = schedule(args)
    assert events == schedule(args)
    kinds = [e[1] for e in events]
    assert kinds.count("kill") == kinds.count("restart") == 19
    assert kinds.count("freeze") == kinds.count("thaw") == 9 and kinds.count("cut") == kinds.count("heal") == 6
    assert all(0 < t < 600 for t, _, _ in events)


def test_short_soak(tmp_path):
    out = tmp_path / "soak"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--duration", "120", "--nodes", "6",
                           "--kill-every", "30", "--freeze-every", "60", "--cut-every", "90", "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    report = json.loads((out / "report.json").read_text())
    assert proc.returncode == (0 if report["pass"] else 1), proc.stdout + proc.stderr[-2000:]
    crit = report["criteria"]
    assert set(crit) == {"no_crash_no_nan", "rmse_vs_reference", "restart_recovery", "rss_growth",
                         "outputs_complete", "nothing_left_running"}
    actions = [f["action"] for f in report["faults"]]
    assert actions.count("kill") == 3 and actions.count("freeze") == 1 and actions.count("cut") == 1
    for hard in ("no_crash_no_nan", "restart_recovery", "outputs_complete", "nothing_left_running"):
        assert crit[hard]["pass"], (hard, crit[hard])
    assert len(crit["rmse_vs_reference"]["ratio_per_node"]) == 6  # judged and reported (pass/fail in the report)
    assert (out / "error.png").stat().st_size > 5000 and (out / "recording.rrd").stat().st_size > 10_000
    assert (out / "summary.json").exists() and (out / "reference" / "summary.json").exists()
    artifacts = Path(__file__).resolve().parent.parent / "out" / "artifacts"
    artifacts.mkdir(parents=True, exist_ok=True)
    (artifacts / "soak_error.png").write_bytes((out / "error.png").read_bytes())
    (artifacts / "soak_report.json").write_text(json.dumps(report, indent=1))
    assert "ztr-" not in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
