"""``zentrack soak --rejudge --out DIR``: judge a finished soak's accuracy per fault again from what it saved.

A soak of an hour is two hours of a machine; when the rule that judges a fault's window changes
(:mod:`zentrack.cluster.soak.accuracy`), the runs need not be repeated: both runs' estimates
(``DIR/estimates.npz``, ``DIR/reference/estimates.npz``) and the applied faults (``DIR/report.json``) hold
everything the criterion reads, with the scenario the report names (its geometry, for the bound ratios). The criterion ``accuracy_per_fault`` is computed again, the report's verdict
updated (every other criterion is kept as the run judged it), the error figure redrawn and the per-fault table
printed. ``report.json`` is rewritten atomically, with ``rejudged`` saying when and that only this criterion was.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from zentrack.cluster.soak.accuracy import accuracy_per_fault, window_lines, window_table
from zentrack.cluster.soak.criteria import failed, passed
from zentrack.cluster.soak.faults import fault_windows
from zentrack.cluster.soak.plot import write_error_plot
from zentrack.cluster.soak.reach import ReachBound
from zentrack.cluster.soak.summary import fault_lines, loss_lines, usage_lines, write_summary_figures
from zentrack.common.progress import outputs_line
from zentrack.common.report import write_json
from zentrack.config.run_setup import scenario_setup
from zentrack.config.scenario_config import load_scenario_config


def saved_errors(path: Path) -> np.ndarray:
    """(steps, nodes) position error of every tracker of a saved single-target run (NaN: no estimate)."""
    with np.load(path) as saved:
        mean, truth = saved["mean"], saved["truth"]
    return np.linalg.norm(mean[:, :, :3] - truth[:, None, :3], axis=-1)


def saved_bound(out: Path, report: dict, scenario: str, steps: int, nodes: int) -> ReachBound | None:
    """The geometry of the saved run for the bound ratios: its scenario and seed as the report names them, its
    ``nodes`` trackers, along the truth it recorded (``estimates.npz``); None when it has no bound."""
    setup = scenario_setup(report.get("scenario", scenario), nodes=nodes, steps=steps,
                           seed=report.get("seed", 0), timing_mode="realtime")
    with np.load(out / "estimates.npz") as saved:
        truth = saved["truth"]
    return ReachBound.of(setup.run_data, truth)


def _load(out: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    report_path, est, ref_est = out / "report.json", out / "estimates.npz", out / "reference" / "estimates.npz"
    for path in (report_path, est, ref_est):
        if not path.is_file():
            raise ValueError(f"--rejudge: {path} is missing (a finished single-target soak's --out holds "
                             "report.json, estimates.npz and reference/estimates.npz)")
    try:
        report = json.loads(report_path.read_text())
        faults = report["faults"]
        if not isinstance(faults, list):
            raise TypeError("faults is not a list")
        err, ref_err = saved_errors(est), saved_errors(ref_est)
    except (ValueError, KeyError, TypeError, OSError) as exc:
        raise ValueError(f"--rejudge: {out} does not hold a readable soak ({type(exc).__name__}: {exc})") from None
    if err.shape != ref_err.shape:
        raise ValueError(f"--rejudge: the runs' estimates differ in shape ({err.shape} vs {ref_err.shape})")
    return report, err, ref_err


def rejudge(out: Path, scenario: str) -> int:
    """Judge ``out`` again (module docstring); exit status 0 when every criterion passes, else 1. ``scenario``:
    the soak's ``--scenario``, for its sample period when the report does not name it."""
    report, err, ref_err = _load(out)
    try:  # before anything is written: a report whose fault ends or usage do not read is refused whole
        summary = [*fault_lines(report), *usage_lines(report.get("usage", {})), *loss_lines(report.get("misses", {}))]
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"--rejudge: {out / 'report.json'} does not hold a readable soak ({exc})") from None
    ts = float(report.get("ts") or load_scenario_config(report.get("scenario", scenario), multitarget=True).ts)
    crit = accuracy_per_fault(fault_windows(report["faults"], err.shape[0] - 1), err, ref_err,
                              bound=saved_bound(out, report, scenario, *err.shape))
    before = report["criteria"].get("accuracy_per_fault", {}).get("pass")
    report["criteria"]["accuracy_per_fault"] = crit
    report["pass"] = passed(report["criteria"])
    report["rejudged"] = {"at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "criteria": ["accuracy_per_fault"],
                          "accuracy_per_fault_before": before}
    title = f"soak of {report.get('scenario', scenario)}, seed {report.get('seed', '?')}"
    figures = write_error_plot(err, report["faults"], ts, out / "error.png", title, reference=ref_err,
                               accuracy=crit["windows"])
    write_json(out / "report.json", report)
    print(f"accuracy_per_fault: {'pass' if crit['pass'] else 'FAIL'} (was {'pass' if before else 'FAIL'})")
    for line in [*window_lines(crit), *window_table(crit)]:
        print(line)
    summary_figures = write_summary_figures(report, crit["windows"], out, title)
    for line in summary:
        print(line)
    print(outputs_line(f"soak {'passed' if report['pass'] else 'FAILED (' + ', '.join(failed(report['criteria'])) + ')'}",
                       report=out / "report.json", error_plot=figures, **summary_figures))
    return 0 if report["pass"] else 1
