"""What every viewer screen shares, single-target (:mod:`.single_target_layout`) or many-target
(:mod:`.multi_target_layout`): the nodes' colours, the dark 3-D background, the white truth, plots without
legends, trails as visible time ranges, the key and event panels and the screen's frame.

Every per-node series is named ``node <i>`` in its node's colour (the colours of the sensor layout), so the
plots carry no legend; the key panel says what each colour and shape is for the run.
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

#: the truth in every view: white, larger than the estimates, labelled
TRUTH_RGB = [255, 255, 255]
#: the 3-D views' background (dark, whatever the UI theme: the white truth and the node colours stand out)
BACKGROUND_RGB = [18, 22, 34]


def node_color(i: int, n: int) -> list[int]:
    """Node i's colour of n: hues spread around the wheel."""
    h = (i / max(n, 1)) % 1.0
    r, g, b = (np.clip(np.abs((h * 6 + off) % 6 - 3) - 1, 0, 1) for off in (0, 4, 2))
    return [int(200 * r + 40), int(200 * g + 40), int(200 * b + 40)]


def log_node_series(rec: rr.RecordingStream, colors: list[list[int]], names: list[str]) -> None:
    """Each node's series ``metrics/<name>/<i>`` named ``node <i>`` in its colour (static), node after node."""
    for i, color in enumerate(colors):
        for name in names:
            rec.log(f"metrics/{name}/{i}", rr.SeriesLines(colors=[color], names=[f"node {i}"]), static=True)


def history(steps: int | None) -> rrb.VisibleTimeRanges:
    """The last ``steps`` steps up to the time cursor (None: the whole run): what a trail or a path keeps."""
    start = rrb.TimeRangeBoundary.infinite() if steps is None else rrb.TimeRangeBoundary.cursor_relative(seq=-steps)
    return rrb.VisibleTimeRanges([rrb.VisibleTimeRange("step", start=start, end=rrb.TimeRangeBoundary.cursor_relative())])


def series(origin: str, name: str, top: float | None = None) -> rrb.TimeSeriesView:
    """A plot without a legend (each series is named ``node <i>``: hovering a line names it), starting with
    the y range 0..``top`` (double-click the plot to fit it to the data)."""
    axis = rrb.ScalarAxis(range=(0.0, top)) if top else None
    return rrb.TimeSeriesView(origin=origin, name=name, plot_legend=rrb.PlotLegend(visible=False), axis_y=axis)


def key_view() -> rrb.TextDocumentView:
    """The key panel: ``key``, what the views show."""
    return rrb.TextDocumentView(origin="key", name="what you see")


def events_view() -> rrb.TextLogView:
    """The event log: ``events``, nodes joining and leaving (and, for one target, rejected messages)."""
    return rrb.TextLogView(origin="events", name="events")


def screen(*columns: rrb.Container | rrb.View, shares: list[int], time_panel: rrb.TimePanel | None = None
           ) -> rrb.Blueprint:
    """The whole screen: ``columns`` side by side in ``shares``, the side panels collapsed."""
    extra = [] if time_panel is None else [time_panel]
    return rrb.Blueprint(rrb.Horizontal(*columns, column_shares=shares), *extra, collapse_panels=True)
