"""The soak's error plot (``error.png`` and ``error.svg``): every tracker's position error over time, with
every fault drawn as a span from its start to its undo (kill -> restart, freeze -> thaw, cut -> heal, stall ->
resume) over the error curves, and above them a timeline with one row per process hit, so that which tracker
was under which fault can be read off. The fault-free reference run's median error is drawn for comparison. With
the ``accuracy_per_fault`` windows (``zentrack.cluster.soak.accuracy``), each window is a bar along the top of the
error axes labelled with its affected trackers' RMSE ratio to the reference (red: over its limit; grey: inside a
truth or router fault's window, judged by that one)."""
from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from zentrack.cluster.soak.fault_kinds import UnknownFault, fault_actions, fault_of, service_name
from zentrack.cluster.soak.faults import fault_windows
from zentrack.common.plots import COLORS, legend_outside, new_figure, save_png_svg, style_axes

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: a fault span's colour when no kind in the registry has its event (each kind's own: its entry's ``colour``)
NO_KIND_COLOUR = "#7f7f7f"


def fault_colour(action: str, target: int | str) -> str:
    """The colour of a fault's span: its kind's in the registry (:data:`NO_KIND_COLOUR` for an event no kind has)."""
    try:
        return fault_of(action, target).colour
    except UnknownFault:
        return NO_KIND_COLOUR


def _kind_name(action: str, target: int | str) -> str:
    try:
        return fault_of(action, target).name
    except UnknownFault:
        return action


def _order(target: int | str) -> tuple[int, int | str]:
    return (0, target) if isinstance(target, int) else (1, str(target))


def error_figure(err: np.ndarray, faults: list[dict], ts: float, title: str,
                 reference: np.ndarray | None = None, accuracy: list[dict] | None = None) -> Figure:
    """The figure: ``err`` (steps, nodes) position errors in m (NaN: no estimate), ``faults`` the applied
    fault events (``{"t", "action", "node", "step"}``), ``ts`` the sample period (s); ``reference`` the
    fault-free run's errors (its median over the nodes is drawn). Axes 0: the fault timeline, 1: the errors
    (one span patch per fault)."""
    steps, nodes = err.shape
    windows = fault_windows(faults, steps - 1)
    targets = sorted({w["node"] for w in windows}, key=_order)
    ratios = (max(1.0, 0.25 * len(targets)), 3.0) + ((1.6,) if accuracy else ())
    fig, axes = new_figure(len(ratios), 1, width=11.0, height=6.5 + (1.8 if accuracy else 0.0), sharex=True,
                           height_ratios=ratios)
    timeline, ax = axes[0], axes[1]
    t = np.arange(steps) * ts
    finite = err[np.isfinite(err)]
    top = float(np.percentile(finite, 99)) * 1.3 if finite.size else 1.0
    clipped = bool(finite.size and finite.max() > top)
    for i in range(nodes):
        ax.plot(t, err[:, i], color=COLORS[i % len(COLORS)], linewidth=0.8, label=f"node {i}")
    if reference is not None and np.isfinite(reference).any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a step no tracker published: NaN, not drawn
            median = np.nanmedian(np.where(np.isfinite(reference), reference, np.nan), axis=1)
        ax.plot(np.arange(median.size) * ts, median, color="black", linestyle="--", linewidth=1.2,
                label="fault-free run, median")
    seen: dict[str, str] = {}  # a legend label -> the colour it was given
    undo_of = fault_actions()
    for w in windows:
        kind, colour = w["kind"], fault_colour(w["kind"], w["node"])
        start, end = w["start"] * ts, max(w["end"], w["start"] + 1) * ts  # at least one step wide
        name = f"{kind} \u2192 {undo_of[kind]}"
        if seen.get(name, colour) != colour:  # another kind with the same events (a sensor's kill): named
            name = f"{name} ({_kind_name(kind, w['node'])})"
        label = None if name in seen else name
        seen.setdefault(name, colour)
        ax.axvspan(start, end, color=colour, alpha=0.18, linewidth=0, label=label)
        row = targets.index(w["node"])
        timeline.broken_barh([(start, end - start)], (row - 0.4, 0.8), facecolors=colour)
    ax.set_ylim(0.0, top)
    ax.set_xlim(0.0, max(steps - 1, 1) * ts)
    style_axes(ax, f"position error of each tracker (y clipped at {top:.3g} m)" if clipped
               else "position error of each tracker", "time since the first estimate (s)", "position error (m)")
    legend_outside(ax, columns=2 if nodes > 12 else 1)
    timeline.set_yticks(range(len(targets)), [service_name(x) for x in targets])
    timeline.set_ylim(-0.6, len(targets) - 0.4)
    timeline.invert_yaxis()
    style_axes(timeline, f"{title}: {len(windows)} faults over {steps} steps of {ts:g} s (spans: fault to undo)",
               "", "hit")
    timeline.tick_params(labelbottom=False, labelsize=7 if len(targets) > 12 else 9)
    if accuracy:
        ax.tick_params(labelbottom=False)
        ax.set_xlabel("")
        _window_panel(axes[2], accuracy, ts)
    return fig


def _window_panel(ax: Axes, accuracy: list[dict], ts: float) -> None:
    """Each ``accuracy_per_fault`` window over its steps: its affected trackers' RMSE ratio (thick) and the
    network median's (thin), each with its limit dashed above it, coloured by the window's verdict."""
    top = 1.0
    for w in accuracy:
        colour = "#7f7f7f" if not w.get("judged", True) else "#2ca02c" if w["pass"] else "#d62728"
        span = [w["start"] * ts, max(w["end"], w["start"] + 1) * ts]
        for ratio, limit, width in ((w["ratio_affected"], w["limits"][0], 3.0), (w["ratio_network"], w["limits"][1], 1.2)):
            if np.isfinite(ratio):
                ax.plot(span, [ratio, ratio], color=colour, linewidth=width, solid_capstyle="butt")
                top = max(top, float(ratio))
            ax.plot(span, [limit, limit], color=colour, linewidth=0.8, linestyle="--")
            top = max(top, float(limit))
    ax.axhline(1.0, color="black", linewidth=0.6)
    ax.set_ylim(0.0, top * 1.08)
    style_axes(ax, "each fault's window: RMSE over the reference's (thick: trackers hit, thin: network; "
                   "dashed: limit; red: failed, grey: judged by a truth or router fault)", "time since the first estimate (s)", "RMSE ratio")


def write_error_plot(err: np.ndarray, faults: list[dict], ts: float, path: str | os.PathLike, title: str,
                     reference: np.ndarray | None = None, accuracy: list[dict] | None = None) -> list[Path]:
    """Draw :func:`error_figure` and write it as PNG and SVG (``path``'s suffix replaced); their paths."""
    return save_png_svg(error_figure(err, faults, ts, title, reference, accuracy), path)
