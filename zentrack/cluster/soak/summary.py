"""A finished soak's figures by fault kind and by process type (issue 36, item 4): what an hour-long soak reports.

:func:`faults_by_kind` counts the faults of each kind and how many steps every live tracker took to publish again
after each one's undo (``publishing_after_fault``'s events); :func:`usage_lines` gives each process type's RSS
per process at the first and the last minute and its CPU (cores) over the run, for both runs (``report.json``'s
``usage``, :mod:`zentrack.cluster.soak.usage`); :func:`loss_lines` the deadline misses and the estimates lost on
the way; :func:`write_usage_plot` draws ``usage.png``: RSS and CPU per process type over time, the faulty run
solid and the reference dashed; :func:`write_ratio_plot` draws ``ratios.png``: every fault window's ratios grouped
by fault kind. The soak prints the fault lines at its end and draws both figures; ``zentrack soak --rejudge``
prints every line and draws them again.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from zentrack.cluster.soak.accuracy import fault_kind
from zentrack.cluster.soak.fault_kinds import sensor_of, undo_actions
from zentrack.common.plots import COLORS, legend_outside, new_figure, save_png_svg, style_axes


def undo_kind(after: str) -> str:
    """The kind of fault (:func:`zentrack.cluster.soak.accuracy.fault_kind`) whose undo an event of
    ``publishing_after_fault`` names: ``"restart node-3"`` -> ``kill``, ``"resume truth"`` -> ``truth-stall``,
    ``"restart router"`` -> ``router-kill``, ``"restart sensor-2"`` -> ``sensor-kill``."""
    action, _, name = after.partition(" ")
    kind = undo_actions().get(action)
    if kind is None or not name:
        raise ValueError(f"unknown fault end {after!r}")
    target: int | str = (int(name[5:]) if name.startswith("node-") and name[5:].isdigit()
                         else name if sensor_of(name) is not None else name.split("-")[0])
    return fault_kind(kind, target)


def faults_by_kind(report: dict) -> dict[str, dict]:
    """Per fault kind: ``count`` (faults ended in the run) and ``recovery_steps`` (per fault end, the steps until
    every live tracker published again; None: not all did) with their ``median`` and ``max``."""
    out: dict[str, dict] = {}
    for event in report["criteria"].get("publishing_after_fault", {}).get("events", []):
        entry = out.setdefault(undo_kind(event["after"]), {"count": 0, "recovery_steps": []})
        entry["count"] += 1
        entry["recovery_steps"].append(event["steps_to_all_estimating"])
    for entry in out.values():
        done = [s for s in entry["recovery_steps"] if s is not None]
        entry["median"] = float(np.median(done)) if done else None
        entry["max"] = max(done) if done else None
        entry["never"] = len(entry["recovery_steps"]) - len(done)
    return dict(sorted(out.items()))


def fault_lines(report: dict) -> list[str]:
    """One line per fault kind: how many, and the steps to publishing again (median, worst)."""
    lines = []
    for kind, e in faults_by_kind(report).items():
        steps = ("no tracker published again" if e["median"] is None else
                 f"every live tracker publishing again after {e['median']:g} steps (median), {e['max']} at worst")
        never = f", {e['never']} never" if e["never"] else ""
        lines.append(f"{kind}: {e['count']} ended, {steps}{never}")
    return lines


def _first_last(values: list) -> tuple[float | None, float | None]:
    done = [v for v in values if v is not None]
    return (done[0], done[-1]) if done else (None, None)


def usage_lines(usage: dict[str, dict]) -> list[str]:
    """Per run and process type: RSS per process in the first and the last minute, CPU cores median and peak."""
    lines = []
    for run, types in usage.items():
        for kind, u in types.items():
            first, last = _first_last(u["rss_mib"])
            cpu = [c for c in u["cpu_cores"] if c is not None]
            rss = "RSS -" if first is None or last is None else f"RSS {first:.1f} -> {last:.1f} MiB per process"
            load = f"CPU {np.median(cpu):.3f} cores median, {max(cpu):.3f} peak" if cpu else "CPU -"
            lines.append(f"{run} {kind}: {rss} (first -> last minute), {load}")
    return lines


def loss_lines(misses: dict[str, dict]) -> list[str]:
    """Per run: deadline misses, how many the trackers noted, estimates lost on the way, unexplained steps."""
    lines = []
    for run, m in misses.items():
        lost = sum(g.get("estimates_lost", 0) for g in m.get("gaps", []))
        down = sum(b - a + 1 for g in m.get("gaps", []) for a, b in g["steps"])
        lines.append(f"{run}: {m['deadline_misses']} deadline misses, {len(m.get('notes', []))} noted by the "
                     f"trackers, {down} tracker-steps without an estimate, {lost} estimates lost on the way, "
                     f"{m.get('unexplained', 0)} unexplained")
    return lines


def write_usage_plot(usage: dict[str, dict], path: str | os.PathLike, title: str) -> list[Path]:
    """``usage.png`` / ``.svg``: RSS per process (top) and CPU cores (bottom) of each process type over time,
    the faulty run solid and the reference dashed; their paths."""
    fig, (rss_ax, cpu_ax) = new_figure(2, 1, width=10.0, height=6.5, sharex=True)
    kinds = sorted({k for types in usage.values() for k in types})
    for run, types in usage.items():
        style = "-" if run == "faulty" else "--"
        for kind, u in types.items():
            colour = COLORS[kinds.index(kind) % len(COLORS)]
            t = np.asarray(u["t_s"], dtype=float) / 60.0
            rss = np.array([np.nan if v is None else v for v in u["rss_mib"]], dtype=float)
            rss_ax.plot(t, rss, style, color=colour, marker=".", label=f"{kind}, {run}")
            cpu_ax.plot(t, np.asarray(u["cpu_cores"], dtype=float), style, color=colour, marker=".",
                        label=f"{kind}, {run}")
    style_axes(rss_ax, f"{title}: resident memory per process", "", "RSS (MiB, mean per process)")
    style_axes(cpu_ax, "CPU of each process type (all its processes)", "time since the run started (min)",
               "cores (CPU s per s)")
    cpu_ax.set_xlim(left=0.0)
    legend_outside(rss_ax)
    legend_outside(cpu_ax)
    return save_png_svg(fig, path)


def write_ratio_plot(accuracy: list[dict], path: str | os.PathLike, title: str) -> list[Path]:
    """``ratios.png`` / ``.svg``: every ``accuracy_per_fault`` window's RMSE ratio to the reference, grouped by
    fault kind (left: the trackers hit, right: the network), each beside its limit (a grey dash); green passed,
    red failed, grey judged by a truth or router fault's window. An hour's 200 windows read here at a glance,
    where the time panel of ``error.png`` packs them side by side; their paths."""
    fig, axes = new_figure(1, 2, width=10.0, height=4.2)
    kinds = sorted({w["kind"] for w in accuracy})
    rng = np.random.default_rng(0)  # the same jitter in every drawing of the same windows
    for ax, (key, part) in zip(axes, (("ratio_affected", 0), ("ratio_network", 1))):
        for w in accuracy:
            x = kinds.index(w["kind"]) + float(rng.uniform(-0.25, 0.25))
            colour = "#7f7f7f" if not w.get("judged", True) else "#2ca02c" if w["pass"] else "#d62728"
            ax.plot([x - 0.06, x + 0.06], [w["limits"][part]] * 2, color="#7f7f7f", linewidth=1.0)
            if np.isfinite(w[key]):
                ax.plot([x], [w[key]], "o", color=colour, markersize=4, alpha=0.8)
        ax.axhline(1.0, color="black", linewidth=0.6)
        ax.set_xticks(range(len(kinds)), kinds, rotation=20)
        ax.set_xlim(-0.5, max(len(kinds), 1) - 0.5)
        ax.set_ylim(bottom=0.0)
        style_axes(ax, f"{title}: trackers hit" if part == 0 else "network median", "fault kind",
                   "window RMSE / reference's")
    return save_png_svg(fig, path)


def write_summary_figures(report: dict, windows: list[dict], out: Path, title: str) -> dict[str, list[Path]]:
    """Both figures of a finished soak into ``out``: ``ratios.png`` of ``windows`` (``accuracy_per_fault``'s) and,
    when the report has usage samples, ``usage.png``; ``{"ratio_plot": paths, "usage_plot": paths}``."""
    figures = {"ratio_plot": write_ratio_plot(windows, out / "ratios.png", title)}
    if report.get("usage"):
        figures["usage_plot"] = write_usage_plot(report["usage"], out / "usage.png", title)
    return figures
