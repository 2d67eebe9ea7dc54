"""The figure of ``zentrack bench scale --plot``: what a run costs against N and against node degree.

Top row, against N (at the smallest degree swept, or the scenario's own ring): CPU per step per process of
each type, step latency p99, RSS per process of each type (Pss dashed), router bytes per second (all links,
and one tracker's link). Bottom row, the same against degree (at the largest N swept). A row with a single
point on its axis is left out.
"""
from __future__ import annotations

import os
from pathlib import Path

from zentrack.common.plots import COLORS, legend_outside, new_figure, save_png_svg, style_axes

#: the process types drawn, in legend order, each with its colour in every panel
KINDS = ("tracker", "router", "truth", "recorder")
KIND_COLORS = dict(zip(KINDS, COLORS, strict=False))


def _series(rows: list[dict], axis: str) -> dict[str, tuple[list[float], list[float]]]:
    """Per curve name: (x, y) over ``rows`` sorted by ``axis`` ("nodes" or "degree"); NaN-free points only."""
    rows = sorted(rows, key=lambda r: r[axis])
    out: dict[str, tuple[list[float], list[float]]] = {}

    def add(name: str, x: float, y: float | None) -> None:
        if y is not None:
            out.setdefault(name, ([], []))[0].append(x)
            out[name][1].append(y)

    for r in rows:
        x = r[axis]
        for k in KINDS:
            add(f"cpu {k}", x, r["cpu_ms_per_step"].get(k, {}).get("mean_ms"))
            add(f"rss {k}", x, r["memory_mb"].get(k, {}).get("rss_mean_mb"))
            add(f"pss {k}", x, r["memory_mb"].get(k, {}).get("pss_mean_mb"))
        add("p99", x, r["latency_ms"].get("p99"))
        links = r.get("router_links")
        if links:
            add("bytes all links", x, links["total_bytes_per_s"] / 1e3)
            add("bytes tracker link", x, links["per_type"].get("tracker", {}).get("mean_bytes_per_s", 0.0) / 1e3)
    return out


def _row(axes: list, rows: list[dict], axis: str, label: str, where: str) -> None:
    s = _series(rows, axis)
    cpu, lat, mem, net = axes
    for k in KINDS:
        if f"cpu {k}" in s:
            cpu.plot(*s[f"cpu {k}"], "o-", color=KIND_COLORS[k], label=k)
        if f"rss {k}" in s:
            mem.plot(*s[f"rss {k}"], "o-", color=KIND_COLORS[k], label=f"{k} RSS")
            mem.plot(*s[f"pss {k}"], "s--", color=KIND_COLORS[k], alpha=0.7, label=f"{k} Pss")
    if "p99" in s:
        lat.plot(*s["p99"], "o-", color="black")
    for name, style, color in (("bytes all links", "o-", "black"), ("bytes tracker link", "s--", KIND_COLORS["tracker"])):
        if name in s:
            net.plot(*s[name], style, color=color, label=name.replace("bytes ", "") + " (mean)" * name.endswith("link"))
    style_axes(cpu, f"CPU per step, per process ({where})", label, "ms per step")
    style_axes(lat, "step latency p99", label, "ms")
    style_axes(mem, "memory per process", label, "MB")
    style_axes(net, "router links", label, "kB/s (both directions)")
    from matplotlib.ticker import MaxNLocator

    for ax in (cpu, lat, mem, net):
        ax.set_ylim(bottom=0)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # whole trackers, whole neighbours
    legend_outside(cpu)
    legend_outside(mem)
    if net.lines:
        net.legend(fontsize=8, frameon=False)


def plot(results: list[dict], path: str | os.PathLike) -> list[Path]:
    """Draw the figure (module docstring) of bench scale's ``results``; returns the PNG and SVG written."""
    if not results:
        raise ValueError("bench scale --plot: no results to draw")
    def sweep_of(r: dict) -> int:  # the degree asked for (-1: the scenario's own ring, whatever N makes of it)
        asked = r.get("degree_requested", r["degree"])
        return -1 if asked is None else asked

    low = min(sweep_of(r) for r in results)
    high = max(r["nodes"] for r in results)
    by_n = [r for r in results if sweep_of(r) == low]
    by_d = [r for r in results if r["nodes"] == high]
    where = "the scenario's ring" if low < 0 else f"degree {low}"
    rows = [(by_n, "nodes", "trackers N", where)] if len({r["nodes"] for r in by_n}) > 1 else []
    if len({sweep_of(r) for r in by_d}) > 1:
        rows.append((by_d, "degree", "neighbours per node", f"N = {high}"))
    if not rows:  # one run: its points against N
        rows = [(by_n, "nodes", "trackers N", where)]
    fig, axes = new_figure(len(rows), 4, width=17.0, height=3.6 * len(rows))
    for i, (subset, axis, label, where) in enumerate(rows):
        _row(axes[4 * i: 4 * i + 4], subset, axis, label, where)
    return save_png_svg(fig, path)
