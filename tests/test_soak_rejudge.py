"""``zentrack soak --rejudge``: a finished soak's accuracy per fault judged again from its saved estimates and
faults, without running anything; a folder that holds no soak is one line and exit status 2, and nothing in it
is touched."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from zentrack.cluster.soak.rejudge import rejudge


def _saved_run(folder, errors: np.ndarray) -> None:
    """A run's estimates.npz whose trackers sit ``errors`` metres east of the truth."""
    steps, nodes = errors.shape
    truth = np.zeros((steps, 6))
    truth[:, 0] = np.arange(steps)
    mean = np.repeat(truth[:, None, :], nodes, axis=1)
    mean[:, :, 0] += errors
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "estimates.npz", mean=mean, truth=truth)


def _soak_dir(tmp_path, others: float):
    steps, nodes = 400, 8
    ref = np.full((steps, nodes), 5.0)
    err = ref.copy()
    err[100:170, [1, 2, 3, 4]] = 10.0  # four trackers hit at once, each 2x its reference (limit 2.5)
    err[100:170, [0, 5, 6, 7]] = others  # the rest of the network
    faults = [{"t": s * 0.1, "action": a, "node": n, "step": s} for s, a, n in
              [(100, "kill", 1), (102, "freeze", 2), (104, "cut", 3), (106, "kill", 4), (110, "restart", 1),
               (112, "thaw", 2), (114, "heal", 3), (116, "restart", 4)]]
    _saved_run(tmp_path, err)
    _saved_run(tmp_path / "reference", ref)
    ends = [{"after": f"{a} node-{n}", "steps_to_all_estimating": s} for a, n, s in
            [("restart", 1, 7), ("thaw", 2, 3), ("heal", 3, 4), ("restart", 4, 9)]]
    usage = {run: {"node": {"t_s": [0.0, 60.0], "rss_mib": [100.0, 101.5], "cpu_cores": [0.4, 0.5]}}
             for run in ("faulty", "reference")}
    report = {"scenario": "patrol", "ts": 0.1, "seed": 0, "faults": faults, "pass": False, "usage": usage,
              "criteria": {"rss_growth": {"pass": True}, "accuracy_per_fault": {"pass": False},
                           "publishing_after_fault": {"pass": True, "events": ends}}}
    (tmp_path / "report.json").write_text(json.dumps(report))
    return tmp_path


def _rejudge(folder):
    return subprocess.run([sys.executable, "-m", "zentrack", "soak", "--rejudge", "--out", str(folder)],
                          capture_output=True, text=True, timeout=120)


def test_rejudge_applies_the_current_rule_to_a_saved_soak_and_keeps_the_other_criteria(tmp_path, capsys):
    folder = _soak_dir(tmp_path / "ok", others=5.0)
    assert rejudge(folder, "patrol") == 0
    printed = capsys.readouterr().out
    report = json.loads((folder / "report.json").read_text())
    crit = report["criteria"]["accuracy_per_fault"]
    assert report["pass"] and crit["pass"] and len(crit["windows"]) == 4
    assert report["rejudged"]["accuracy_per_fault_before"] is False and report["criteria"]["rss_growth"]["pass"]
    assert (folder / "error.png").stat().st_size > 10_000 and "(was FAIL)" in printed
    assert "network without node-2, node-3, node-4" in printed
    # the figures by fault kind and process type, and the usage figure
    assert "kill: 2 ended, every live tracker publishing again after 8 steps (median), 9 at worst" in printed
    assert "freeze: 1 ended" in printed and "cut: 1 ended" in printed
    assert "faulty node: RSS 100.0 -> 101.5 MiB per process (first -> last minute)" in printed
    assert (folder / "usage.png").stat().st_size > 10_000 and (folder / "ratios.png").stat().st_size > 10_000
    # the trackers no fault hit 2.6x their reference: over the network limit of four faults at once (1.25 ** 4)
    worse = _soak_dir(tmp_path / "worse", others=13.0)
    assert rejudge(worse, "patrol") == 1 and "FAILED (accuracy_per_fault)" in capsys.readouterr().out
    assert not json.loads((worse / "report.json").read_text())["pass"]


def test_rejudge_of_a_folder_without_a_soak_is_one_line_and_exit_2(tmp_path):
    folder = _soak_dir(tmp_path / "s", others=5.0)
    (folder / "reference" / "estimates.npz").unlink()
    before = (folder / "report.json").read_text()
    proc = _rejudge(folder)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "reference/estimates.npz is missing" in lines[0], proc.stderr
    assert (folder / "report.json").read_text() == before
    (folder / "report.json").write_text("{not json")
    _saved_run(folder / "reference", np.full((400, 8), 5.0))
    proc = _rejudge(folder)
    assert proc.returncode == 2 and "does not hold a readable soak" in proc.stderr.strip(), proc.stderr
    assert (folder / "report.json").read_text() == "{not json"


def test_rejudge_of_a_report_with_a_forged_fault_end_is_one_line_and_exit_2(tmp_path):
    folder = _soak_dir(tmp_path / "s", others=5.0)
    report = json.loads((folder / "report.json").read_text())
    report["criteria"]["publishing_after_fault"]["events"][0]["after"] = "explode node-1"
    (folder / "report.json").write_text(json.dumps(report))
    before = (folder / "report.json").read_text()
    proc = _rejudge(folder)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "explode node-1" in lines[0], proc.stderr
    assert (folder / "report.json").read_text() == before and not (folder / "error.png").exists()
