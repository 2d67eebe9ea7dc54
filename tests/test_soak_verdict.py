"""What a soak prints per criterion (``zentrack.cluster.soak.criteria.verdict_lines``): a failure names the node,
its figures and the limit; the two recovery criteria say what each measures. And the soak's error plot: every
fault a span from its start to its undo (``zentrack.cluster.soak.plot``), written as PNG and SVG."""
from __future__ import annotations

import numpy as np
from matplotlib.patches import Rectangle

from zentrack.cluster.soak.criteria import publishing_after_fault, restarted_error_near_median, verdict_lines
from zentrack.cluster.soak.faults import fault_windows
from zentrack.cluster.soak.plot import error_figure, write_error_plot

STEPS, NODES = 300, 4
FAULTS = [{"t": 4.0, "action": "kill", "node": 3, "step": 40},
          {"t": 6.0, "action": "restart", "node": 3, "step": 60},
          {"t": 10.0, "action": "freeze", "node": 1, "step": 100},
          {"t": 15.0, "action": "thaw", "node": 1, "step": 150},
          {"t": 20.0, "action": "stall", "node": "truth", "step": 200},
          {"t": 21.5, "action": "resume", "node": "truth", "step": 215},
          {"t": 27.0, "action": "cut", "node": 0, "step": 270}]  # never healed: the run ended


def late_restart() -> tuple[np.ndarray, np.ndarray]:
    have = np.ones((STEPS, NODES), dtype=bool)
    have[40:118, 3] = False  # node 3 killed at step 40, restarted at 60, publishing again at 118: 58 steps
    err = np.full((STEPS, NODES), 1.0)
    err[~have] = np.nan
    return have, err


def test_a_late_restart_fails_publishing_after_fault_naming_node_steps_and_limit():
    have, err = late_restart()
    crit = {"publishing_after_fault": publishing_after_fault(FAULTS[:4], have, STEPS),
            "restarted_error_near_median": restarted_error_near_median(FAULTS[:4], have, err, STEPS)}
    lines = verdict_lines(crit)
    assert lines[0] == ("FAIL  publishing_after_fault: after restart node-3 at 6.0 s (step 60): node 3 published "
                        "again after 58 steps (limit 20)")
    # once back, node 3 is at the median at once: this one passes, and says it judges accuracy, not time
    assert lines[1] == ("PASS  restarted_error_near_median: 1 restarts, each within 2x the network median error "
                        "at its first estimate (limit 20 steps)")


def test_a_restart_that_stays_far_from_the_median_fails_with_its_figures():
    have, err = late_restart()
    have[118:, 3], err[118:, 3] = True, 50.0  # back, but 50x the others' error from then on
    crit = {"restarted_error_near_median": restarted_error_near_median(FAULTS[:2], have, err, STEPS)}
    assert verdict_lines(crit) == [
        "FAIL  restarted_error_near_median: node 3 restarted at 6.0 s: published after 58 steps, but its error "
        "stayed above 2x the network median for the 20 steps after (limit 20)"]
    have[60:, 3] = False
    crit = {"restarted_error_near_median": restarted_error_near_median(FAULTS[:2], have, err, STEPS)}
    assert verdict_lines(crit) == ["FAIL  restarted_error_near_median: node 3 restarted at 6.0 s: never published again"]


def test_other_failures_name_their_offenders():
    crit = {"rmse_vs_reference": {"pass": False, "ratio_per_node": [1.0, 1.41, 1.1, 1.3], "limit": 1.25},
            "no_crash_no_nan": {"pass": False, "crashed": {"node-2": 1}, "nan_free": True, "exit_codes": {}},
            "rss_growth": {"pass": False, "growth_per_process": {"truth": 0.02, "viewer": 0.142}, "from_s": 120.0,
                           "limit": 0.10},
            "nothing_left_running": {"pass": True, "processes": []}}
    assert verdict_lines(crit) == [
        "FAIL  rmse_vs_reference:",
        "        node 1: position RMSE 1.41x its fault-free RMSE (limit 1.25x)",
        "        node 3: position RMSE 1.30x its fault-free RMSE (limit 1.25x)",
        "FAIL  no_crash_no_nan: node-2 exited with status 1",
        "FAIL  rss_growth: viewer grew 14.2 % from 120 s to the end (limit 10 %)",
        "PASS  nothing_left_running: nothing left"]


def test_fault_windows_pair_each_fault_with_its_undo():
    assert [(w["kind"], w["node"], w["start"], w["end"], w["undo"]) for w in fault_windows(FAULTS, STEPS - 1)] == [
        ("kill", 3, 40, 60, "restart"), ("freeze", 1, 100, 150, "thaw"), ("stall", "truth", 200, 215, "resume"),
        ("cut", 0, 270, STEPS - 1, None)]


def test_the_error_plot_draws_every_fault_as_a_span_and_writes_png_and_svg(tmp_path):
    _, err = late_restart()
    ts = 0.1
    fig = error_figure(err, FAULTS, ts, "test", reference=np.full((STEPS, NODES), 0.8))
    timeline, ax = fig.axes[:2]
    spans = [p for p in ax.patches if isinstance(p, Rectangle)]
    got = sorted((round(p.get_x(), 6), round(p.get_x() + p.get_width(), 6)) for p in spans)
    assert got == [(4.0, 6.0), (10.0, 15.0), (20.0, 21.5), (27.0, round((STEPS - 1) * ts, 6))]
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"kill \u2192 restart", "freeze \u2192 thaw", "stall \u2192 resume", "cut \u2192 heal"} <= set(legend)
    assert "node 3" in legend and "fault-free run, median" in legend
    assert ax.get_xlabel() == "time since the first estimate (s)" and ax.get_ylabel() == "position error (m)"
    assert [t.get_text() for t in timeline.get_yticklabels()] == ["node-0", "node-1", "node-3", "truth"]
    png, svg = write_error_plot(err, FAULTS, ts, tmp_path / "error.png", "test")
    assert (png, svg) == (tmp_path / "error.png", tmp_path / "error.svg")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert b"<svg" in svg.read_bytes()[:500]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["error.png", "error.svg"], "no temporary file left"


def test_the_error_plot_draws_each_fault_window_at_its_ratios_beside_its_limits():
    """With the per-fault windows a third panel draws each window over its steps at the ratio of the trackers hit
    and of the network, beside their limits; a failed window is red, one judged by a truth fault grey."""
    _, err = late_restart()
    ts = 0.1
    windows = [{"start": 40, "end": 100, "ratio_affected": 1.1, "ratio_network": 1.05, "limits": [2.5, 1.25],
                "judged": True, "pass": True},
               {"start": 100, "end": 190, "ratio_affected": 3.0, "ratio_network": 1.4, "limits": [2.5, 1.25],
                "judged": True, "pass": False},
               {"start": 200, "end": 255, "ratio_affected": 1.8, "ratio_network": 1.7, "limits": [4.0, 4.0],
                "judged": False, "pass": True}]
    fig = error_figure(err, FAULTS, ts, "test", accuracy=windows)
    assert len(fig.axes) == 3 and len(error_figure(err, FAULTS, ts, "test").axes) == 2
    panel = fig.axes[2]
    drawn = {(round(x[0], 6), round(x[1], 6), round(y[0], 6), line.get_color(), line.get_linestyle())
             for line in panel.get_lines() for x, y in [(line.get_xdata(), line.get_ydata())] if len(x) == 2 and x[0] != x[1]}
    for w, colour in zip(windows, ("#2ca02c", "#d62728", "#7f7f7f")):
        span = (round(w["start"] * ts, 6), round(w["end"] * ts, 6))
        for ratio, limit in zip((w["ratio_affected"], w["ratio_network"]), w["limits"]):
            assert (*span, ratio, colour, "-") in drawn, (w, ratio)
            assert (*span, limit, colour, "--") in drawn, (w, limit)
    assert panel.get_ylim()[1] >= 4.0 and panel.get_ylabel() == "RMSE ratio"
