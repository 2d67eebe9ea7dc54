"""What a finished run leaves in its output folder: each tracker's final report read back, the run's summary
(the recorder's figures, each tracker's clocks and intake, the run's settings) and its recorded estimates, written
so that a disk error loses nothing complete."""
from __future__ import annotations

import json
import logging
from pathlib import Path

from zentrack.cluster.recording.core import Recorder
from zentrack.common.report import write_json

log = logging.getLogger("zentrack.run")


def read_node_reports(out: Path, nodes: int) -> dict[int, dict]:
    """Each node's final counters (``<out>/node-<i>.json``), where a node wrote one and it is readable."""
    reports = {}
    for i in range(nodes):
        path = out / f"node-{i}.json"
        try:
            reports[i] = json.loads(path.read_text())
        except FileNotFoundError:
            continue
        except (OSError, ValueError) as exc:
            log.warning("%s: unreadable node report (%s); using the counters of its last estimate", path, exc)
    return reports


def write_results(recorder: Recorder, reports: dict[int, dict], run: dict, out: Path, estimates_path: Path,
                  interrupted: bool = False) -> dict:
    """Write ``summary.json`` first (atomically), then the estimates to ``estimates_path`` (atomically). ``run``:
    the run's settings (``summary["run"]``, with the step it was interrupted at added). A disk error is listed
    under ``write_errors`` in the returned summary (``zentrack run`` prints it as one line and exits 1); whatever
    was complete before stays as it was."""
    # (each sensor's and neighbour's clock offset, sensors of their own, is a figure of the report, not a count
    # to sum)
    offsets = {i: report.pop("sensor_offsets_s", None) for i, report in reports.items()}
    neighbours = {i: report.pop("neighbour_offsets_s", None) for i, report in reports.items()}
    summary = recorder.summary(reports, steps_run=recorder.steps_reached() if interrupted else None)
    for entry in summary["nodes"]:  # each tracker's clock against the run's schedule (node/clock_offset.py)
        report = reports.get(entry["node"], {})
        entry["clock_offset_s"] = report.get("clock_offset_s")
        entry["clock_exceeded"] = bool(report.get("clock_exceeded", False))
        if offsets.get(entry["node"]) is not None:  # sensors of their own: the tracker's intake at its exit
            entry["sensor_offsets_s"] = offsets[entry["node"]]
            entry["neighbour_offsets_s"] = neighbours[entry["node"]]
            entry["detections"] = report.get("detections")
    summary["run"] = {**run, "interrupted_at_step": summary["network"]["steps"] if interrupted else None}
    try:
        write_json(out / "summary.json", summary)
    except OSError as exc:
        summary["write_errors"] = [f"{out / 'summary.json'} ({exc.strerror or exc})"]
        return summary
    try:
        recorder.save_estimates(estimates_path)
    except OSError as exc:
        summary["write_errors"] = [f"{estimates_path} ({exc.strerror or exc}; summary.json is complete)"]
    return summary
