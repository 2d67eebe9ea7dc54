"""What a run prints and judges at the end: the summary table, the failures, the closing line (``zentrack run``,
``zentrack record`` and the benches that start a cluster print the same)."""
from __future__ import annotations

import shutil
from pathlib import Path

from zentrack.common.atomic import EXIT_WRITE_FAILED
from zentrack.common.outages import partition_notes, steps_in
from zentrack.common.progress import outputs_line
from zentrack.common.report import fmt_num, table

#: a tracker that ran this many steps without any detection from its sensors failed (a shorter run may end
#: before its slowest sensor's first detection arrives)
MIN_STEPS_WITHOUT_DETECTION = 20


def trackers_stopped(codes: dict[str, int | None], out: Path, logs: Path) -> str:
    """What went wrong with the trackers (``codes``: name -> exit status, None while running): those that ran
    but could not write their reports (exit :data:`EXIT_WRITE_FAILED`: a full disk, say) named apart from those
    that failed; "every tracker process failed" only when each one did."""
    unwritten = sorted(name for name, code in codes.items() if code == EXIT_WRITE_FAILED)
    failed = ", ".join(f"{name} {code}" for name, code in sorted(codes.items()) if code not in (0, None, EXIT_WRITE_FAILED))
    if not unwritten:
        return f"every tracker process failed while the truth was running ({failed}); see {logs}"
    try:
        free = f"; {shutil.disk_usage(out).free} bytes free there"
    except OSError:
        free = ""
    who = "the trackers" if len(unwritten) == len(codes) else "trackers " + ", ".join(unwritten)
    files = ", ".join(f"{name}.json" for name in unwritten)
    return (f"{who} ran but could not write their reports ({files} in {out}{free})"
            + (f"; other trackers failed ({failed})" if failed else "") + f"; see {logs}")


def run_failures(summary: dict, max_missing_frac: float) -> list[str]:
    """One line per node that did not do its job: it published no estimate for more than ``max_missing_frac``
    of the steps (dead, frozen, stuck). Steps whose estimate the node published but the recorder never received
    (``estimates_lost``: transport drops, a router down) are the network's failing, reported by
    :func:`transport_warnings`, not the node's. Nor are the stretches a node came back from (``outages``: cut
    off by a partition, its router down), which the closing line names (:func:`ok_line`)."""
    steps = summary["network"]["steps"]
    out = detectionless_failures(summary)
    if summary.get("kind") == "multitarget":
        return out + multitarget_failures(summary, max_missing_frac)
    for n in summary["nodes"]:
        unpublished = max(0, n["steps_without_estimate"] - n.get("estimates_lost", 0))
        unpublished = min(unpublished, n["steps_without_estimate"] - steps_in(n.get("outages", [])))
        if unpublished > max_missing_frac * steps:
            ranges = ", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in n["gaps"][:6])
            more = " ..." if len(n["gaps"]) > 6 else ""
            out.append(f"node {n['node']} published no estimate for {unpublished} of {steps} steps "
                       f"(steps without one received: {ranges}{more}; limit {max_missing_frac:.0%})")
    return out


def detectionless_failures(summary: dict) -> list[str]:
    """Sensors of their own: one line per tracker that ran yet received no detection at all from the sensors
    it takes (a sensor that never started, could not connect or was not allowed to publish): every estimate it
    published was a prediction, which the other checks take for a tracker doing its job."""
    out = []
    for n in summary["nodes"]:
        det = n.get("detections")
        published = summary["network"]["steps"] - n.get("steps_without_estimate", n.get("steps_without_list", 0))
        if det is not None and int(det.get("det_rx", 0)) == 0 and published >= MIN_STEPS_WITHOUT_DETECTION:
            out.append(f"node {n['node']} received no detection from its sensors in {published} steps: they "
                       "never reached it (a sensor not running, unable to connect, or refused by the router)")
    return out


def multitarget_failures(summary: dict, max_missing_frac: float) -> list[str]:
    """A many-target run's :func:`run_failures`: a node that published no track list for more than
    ``max_missing_frac`` of the steps, or confirmed no track on any target over the run."""
    steps = summary["network"]["steps"]
    out = []
    for n in summary["nodes"]:
        if n["steps_without_list"] > max_missing_frac * steps:
            ranges = ", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in n["gaps"][:6])
            out.append(f"node {n['node']} published no track list for {n['steps_without_list']} of {steps} steps "
                       f"(steps without one: {ranges}{' ...' if len(n['gaps']) > 6 else ''}; limit "
                       f"{max_missing_frac:.0%})")
        elif summary["network"]["targets_mean"] > 0 and n.get("n_missed", float("inf")) >= summary["network"]["targets_mean"]:
            out.append(f"node {n['node']} confirmed no track on any target (GOSPA {fmt_num(n.get('gospa', float('nan')))})")
    return out


def transport_warnings(summary: dict, max_missing_frac: float) -> list[str]:
    """One line per node whose published estimates the recorder lost beyond ``max_missing_frac`` of the steps."""
    if summary.get("kind") == "multitarget":
        return []
    steps = summary["network"]["steps"]
    return [f"node {n['node']}: {n['estimates_lost']} of {n['estimates_published']} published estimates never "
            f"reached the recorder (transport drops or a router outage)"
            for n in summary["nodes"] if n.get("estimates_lost", 0) > max_missing_frac * steps]


def clock_ms(offset_s: float | None) -> str:
    """A node's clock offset for the summary table: signed ms, "-" when the node wrote no report."""
    return "-" if offset_s is None else f"{offset_s * 1e3:+.0f}"


#: what the state groups of the summary's ``rmse_<group>`` figures are, for the table's heading
GROUP_NAMES = {"p": "position", "v": "velocity", "speed": "speed", "x1": "x1", "x2": "x2"}
#: the summary table's columns explained, printed under it
LEGEND = ("RMSE: error against the truth",
          "ANEES [95% band]: mean squared error over the covariance the node claims (inside the band: honest;",
          "  below: cautious; above: overconfident)",
          "missed: steps without an estimate in time; estimated: steps with one",
          "from neighbours: their estimates received for fusion; late: those past the deadline",
          "refused: messages rejected (stale, forged, malformed); clock: offset from the run's schedule")


def anees_cell(node: dict) -> str:
    """``3.10 [5.61, 6.40]``: a node's ANEES beside the 95 % band of an honest covariance over its steps."""
    value = fmt_num(node.get("anees", float("nan")), 2)
    band = node.get("anees_band")
    return f"{value} [{band[0]:.2f}, {band[1]:.2f}]" if band else value


#: the many-target table's columns explained
MT_LEGEND = ("GOSPA (alpha 2, order 2, cut-off c): error of the confirmed tracks against the targets present,",
             "  with its parts (localisation, missed, false: the mean squared terms, m^2)",
             "switches / frag.: identity switches and fragmentations of the targets' tracks",
             "missed: lists past their deadline; no list: steps without one (e.g. dead); refused: messages rejected",
             "back in: steps a restarted node took to hold its tracks again")


def print_multitarget_summary(summary: dict) -> None:
    """A many-target run's per-node table, its legend and the network's line."""
    net = summary["network"]
    rows = []
    for n in summary["nodes"]:
        back = [r["recovery_steps"] for r in n.get("recoveries", [])]
        rows.append([n["node"], fmt_num(n.get("gospa", float("nan")), 2),
                     " / ".join(fmt_num(n.get(p, float("nan")), 0) for p in ("localisation", "missed", "false")),
                     f"{n.get('identity_switches', '-')} / {n.get('fragmentations', '-')}",
                     fmt_num(n.get("confirmed_mean", float("nan")), 1),
                     f"{fmt_num(n['update_ms'].get('p50', float('nan')), 2)} / {fmt_num(n['update_ms'].get('p99', float('nan')), 2)}",
                     n["deadline_misses"], n["steps_without_list"], sum(n["messages"]["rejected"].values()), n["takeovers"],
                     ", ".join("-" if b is None else str(b) for b in back) or "-"])
    print(table(["node", "GOSPA m", "loc / missed / false", "switches / frag.", "confirmed", "update ms p50 / p99",
                 "missed", "no list", "refused", "takeovers", "back in"], rows))
    print("\n".join(MT_LEGEND))
    print(f"network: {net['targets_mean']:.1f} targets on average ({net['targets_total']} over the run), mean GOSPA "
          f"{fmt_num(net['gospa_mean'], 2)} m (c = {net['gospa_cutoff_m']:g} m), steps missed {net['deadline_misses']} "
          f"(all nodes)")


def print_summary(summary: dict) -> None:
    """The per-node table of a run, its legend and the network's line."""
    if summary.get("kind") == "multitarget":
        print_multitarget_summary(summary)
        return
    net = summary["network"]
    first = next(k for k in summary["nodes"][0] if k.startswith("rmse_"))
    group = GROUP_NAMES.get(first[len("rmse_"):], first[len("rmse_"):])
    rows = []
    for n in summary["nodes"]:
        m = n["messages"]
        lat = n["latency_ms"]
        rows.append([n["node"], fmt_num(n.get(first) or float("nan"), 3), anees_cell(n),
                     f"{fmt_num(lat.get('p50', float('nan')), 2)} / {fmt_num(lat.get('p99', float('nan')), 2)}",
                     n["deadline_misses"], n["steps_estimated"], m["priors_received"], m["late"],
                     sum(m["rejected"].values()) if m["rejected"] else 0, clock_ms(n.get("clock_offset_s"))])
    print(table(["node", f"RMSE {group}", "ANEES [95% band]", "latency ms p50/p99", "missed", "estimated",
                 "from neighbours", "late", "refused", "clock ms"], rows))
    print("\n".join(LEGEND))
    lat = net["latency_ms"]
    print(f"network: median RMSE {group} {fmt_num(net.get('median_' + first) or float('nan'))}, "
          f"latency p50 {fmt_num(lat.get('p50', float('nan')), 2)} ms p99 {fmt_num(lat.get('p99', float('nan')), 2)} ms, "
          f"steps missed {net['deadline_misses']} (all nodes)")


def outputs(out: Path) -> dict[str, str]:
    """Where a run's outputs are, for its closing line (:func:`~zentrack.common.progress.outputs_line`): the
    summary (written before the line is printed), then the estimates, the logs and the recording that exist."""
    named = {"estimates": out / "estimates.npz", "tracks": out / "tracks.npz", "logs": out / "logs", "recording": out / "recording.rrd"}
    return {"summary_written_to": str(out / "summary.json"),
            **{name: f"{path}/" if path.is_dir() else str(path) for name, path in named.items() if path.exists()}}


def interrupted_line(summary: dict, out: Path) -> str:
    """The closing line of a Ctrl-C'd run: the step it stopped at, what the summary covers, where it is."""
    net = summary["network"]
    steps, planned = net["steps"], net.get("steps_planned", net["steps"])
    return outputs_line(f"run interrupted at step {steps} of {planned} (the summary covers those {steps} steps)",
                        **outputs(out))


def ok_line(summary: dict | None, out: Path) -> str:
    """The closing line of a run that did its job; one whose trackers refused forged, conflicting or flooded
    messages says so, with the counts per kind (``network.refused`` of the summary); one whose trackers were cut
    off for a stretch and came back names the stretches (``common/outages.py``)."""
    refused = (summary or {}).get("network", {}).get("refused") or {}
    notes = []
    if refused:
        kinds = ", ".join(f"{count} {name}" for name, count in list(refused.items())[:6])
        notes.append(f"the trackers refused {sum(refused.values())} message(s) ({kinds}"
                     f"{', ...' if len(refused) > 6 else ''}; per node in the summary)")
    notes += partition_notes(summary or {})
    return outputs_line(f"run OK, but {'; '.join(notes)}" if notes else "run OK", **outputs(out))
