"""The figures of the soak and the benches, drawn by matplotlib with one style: :func:`new_figure` makes a figure
(no pyplot, so no global state and no display: the Agg canvas renders it), :func:`style_axes` labels an Axes the
same way everywhere (title, axis labels with units, a light grid), :func:`label_points` writes point labels
that do not overprint each other, and :func:`save_png_svg` writes the PNG and the SVG side by side (each file
atomically) and returns their paths.

``COLORS`` is the palette every figure draws its series from, ``color_of(name)`` a stable colour for a name
(a filter, a rule) so that the same name has the same colour in every figure.
"""
from __future__ import annotations

import os
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from zentrack.common.atomic import replace_atomically

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: the qualitative palette (matplotlib's tab10, colour-blind friendlier than the old hand-picked RGB triples)
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf")
#: names with a fixed colour in every figure (filters and the reference curves)
NAMED_COLORS = {"teskf": COLORS[1], "eskf": COLORS[0], "ukf": COLORS[2], "ckf": COLORS[3], "ekf": COLORS[4],
                "seckf": COLORS[1], "linearised": COLORS[7], "bound": "black"}
#: pixels per inch of the PNG (the SVG is vector)
DPI = 110
#: font sizes: body text, titles
FONT_SIZE, TITLE_SIZE = 9, 10


def color_of(name: str) -> str:
    """The colour of ``name``: its fixed one (``NAMED_COLORS``, case-insensitive, a leading ``c``/``d`` of a
    centralized/distributed filter ignored), else one of ``COLORS`` chosen by a hash of the name."""
    key = name.lower()
    for candidate in (key, key[1:] if key[:1] in "cd" else key):
        if candidate in NAMED_COLORS:
            return NAMED_COLORS[candidate]
    return COLORS[zlib.crc32(key.encode()) % len(COLORS)]


def new_figure(rows: int = 1, cols: int = 1, *, width: float = 10.0, height: float = 5.0, sharex: bool = False,
               height_ratios: Sequence[float] | None = None) -> tuple[Figure, list[Axes]]:
    """A figure of ``rows`` x ``cols`` Axes (``width`` x ``height`` inches, laid out so labels fit); the Axes
    as a flat list, row by row."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    grid = fig.subplots(rows, cols, sharex=sharex, squeeze=False,
                        gridspec_kw={"height_ratios": list(height_ratios)} if height_ratios else None)
    return fig, [ax for row in grid for ax in row]


def style_axes(ax: Axes, title: str, xlabel: str, ylabel: str) -> None:
    """The one look of every Axes: a title, axis labels (with their units), a light grid under the data."""
    ax.set_title(title, fontsize=TITLE_SIZE, loc="left")
    ax.set_xlabel(xlabel, fontsize=FONT_SIZE)
    ax.set_ylabel(ylabel, fontsize=FONT_SIZE)
    ax.tick_params(labelsize=FONT_SIZE)
    ax.grid(True, color="#dddddd", linewidth=0.6)
    ax.set_axisbelow(True)


def log_scale(ax: Axes, axis: Literal["x", "y"] = "y") -> None:
    """A log scale labelled in plain numbers (``20``, ``50``, not ``2 x 10^1``), minor ticks labelled too."""
    from matplotlib.ticker import FuncFormatter

    plain = FuncFormatter(lambda v, _pos: f"{v:g}")
    target = ax.yaxis if axis == "y" else ax.xaxis
    (ax.set_yscale if axis == "y" else ax.set_xscale)("log")
    target.set_major_formatter(plain)
    target.set_minor_formatter(plain)
    ax.tick_params(axis=axis, which="minor", labelsize=FONT_SIZE - 2)


def legend_outside(ax: Axes, title: str | None = None, columns: int = 1) -> None:
    """A legend to the right of the Axes, so that it never covers the data."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=FONT_SIZE - 1, title=title,
              title_fontsize=FONT_SIZE - 1, ncols=columns, frameon=False, borderaxespad=0.0)


def label_points(ax: Axes, xs: Sequence[float], ys: Sequence[float], labels: Sequence[str],
                 colors: Sequence[str] | None = None, min_gap_pt: float = 11.0) -> None:
    """Write ``labels`` beside the points ``(xs, ys)`` without overprinting: labels of points close together
    are stacked upwards (at least ``min_gap_pt`` points apart in display space) and tied to their point by a
    thin leader line. Call after the Axes' limits are final."""
    fig = ax.get_figure(root=True)
    assert fig is not None
    fig.draw_without_rendering()  # the layout as it will be saved: display positions are final
    to_pt = 72.0 / fig.dpi
    disp = [ax.transData.transform((x, y)) for x, y in zip(xs, ys)]
    order = sorted(range(len(labels)), key=lambda i: (disp[i][1], disp[i][0]))
    placed: list[tuple[float, float]] = []  # (x, y) in points of each label placed
    for i in order:
        x_pt, y_pt = disp[i][0] * to_pt, disp[i][1] * to_pt
        target, moved = y_pt, True
        while moved:  # up past every label already placed near it (the target only rises: this ends)
            moved = False
            for px, py in placed:
                if abs(px - x_pt) < 90.0 and abs(py - target) < min_gap_pt:
                    target, moved = py + min_gap_pt, True
        placed.append((x_pt, target))
        ax.annotate(labels[i], (xs[i], ys[i]), xytext=(8.0, target - y_pt), textcoords="offset points",
                    fontsize=FONT_SIZE - 1, va="center", color=None if colors is None else colors[i],
                    arrowprops={"arrowstyle": "-", "color": "#999999", "linewidth": 0.5, "shrinkA": 0, "shrinkB": 2})


def figure_paths(path: str | os.PathLike) -> tuple[Path, Path]:
    """The PNG and the SVG of a figure named by ``path`` (any suffix, or none): ``x.png``, ``x.svg``."""
    path = Path(path)
    stem = path.with_suffix("") if path.suffix.lower() in (".png", ".svg") else path
    return stem.with_name(stem.name + ".png"), stem.with_name(stem.name + ".svg")


def save_png_svg(fig: Figure, path: str | os.PathLike) -> list[Path]:
    """Write ``fig`` as PNG and SVG beside each other (``path``'s suffix is replaced), each atomically;
    returns ``[png, svg]``."""
    written = []
    for target, fmt in zip(figure_paths(path), ("png", "svg")):

        def render(tmp: Path, fmt: str = fmt) -> None:
            fig.savefig(tmp, format=fmt, dpi=DPI, facecolor="white")

        replace_atomically(target, render, suffix=f".tmp.{fmt}")
        written.append(target)
    return written
