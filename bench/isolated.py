"""``zentrack bench isolated``: a bearing-only tracker cut off from both neighbours, per update rule (issue 54).

Node 4 of the ring (its neighbours are 3 and 5) loses every link, both ways, for ``--cuts`` seconds from step
200 of each run, on exp2 and ``patrol`` (TESKF and CI as the scenarios configure them), in ``--runs`` Monte Carlo
runs of the batched simulator (fixed seeds): :func:`zentrack.study.isolated_node.run_cut`. Every rule of what the
lone node does with its own bearing runs on the same runs: its own update (before issue 54), no update
(prediction alone: the reference), the unobservable subspace held (what trackers do now,
:mod:`zentrack.fusion.isolation`) and the alternatives measured against it. Per rule: the node's position RMS
error over the cut and its mean at the cut's end, both beside prediction's, the largest and the mean over the cut
of the NEES of its kinematic state (averaged over the runs, per step) against the 95 % band of that average, and
the error one second after the node rejoined.

A figure (PNG and SVG) draws, per scenario and cut, the error and the NEES of every rule over the cut.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from zentrack.common.argtypes import name_list, positive_float, positive_int
from zentrack.common.plots import COLORS, legend_outside, new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, outputs_line
from zentrack.common.report import figure_path, table, write_json
from zentrack.study.isolated_node import AFTER_CUT, RULES, run_cut

SCENARIOS = ("exp2", "patrol")
#: the reference every rule is held to
REFERENCE = "prediction"
#: each rule's colour and line style in the figure
STYLE = {rule: (COLORS[i], "--" if rule == REFERENCE else "-") for i, rule in enumerate(RULES)}


def seconds_list(text: str) -> list[float]:
    """An argparse type: comma-separated positive durations in seconds."""
    return [positive_float(t.strip()) for t in text.split(",") if t.strip()] or [positive_float(text)]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=20, help="Monte Carlo runs per cut (default 20)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--scenarios", type=name_list(SCENARIOS, "scenario"), default=list(SCENARIOS),
                   help=f"comma-separated (default {','.join(SCENARIOS)})")
    p.add_argument("--cuts", type=seconds_list, default=[5.0, 30.0], metavar="S,S",
                   help="the cuts' lengths in seconds, comma-separated (default 5,30)")
    p.add_argument("--rules", type=name_list(tuple(RULES), "rule"), default=list(RULES),
                   help=f"comma-separated (default {','.join(RULES)}; {REFERENCE} is always run)")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="error and NEES over each cut (default: beside --json)")


def significant(values: np.ndarray, digits: int = 4) -> list[float]:
    """``values`` rounded to ``digits`` significant digits (the per-step curves of the JSON)."""
    return [float(f"{v:.{digits}g}") for v in values]


def figures(cut: dict) -> dict:
    """The JSON of one cut: its settings, the per-rule summary with the ratios to prediction, and per rule the
    per-step error and NEES from one second before the cut to the end of the run."""
    ref = cut["summary"][REFERENCE]
    first = cut["start"] - int(round(1.0 / cut["ts"]))
    rows = {}
    for rule, s in cut["summary"].items():
        r = cut["results"][rule]
        rows[rule] = {**s, "rms_vs_prediction": s["rms_error_m"] / ref["rms_error_m"],
                      "end_vs_prediction": s["end_error_m"] / ref["end_error_m"],
                      "per_run_rms_error_m": np.sqrt(np.mean(r.run_error[:, cut["start"]:cut["start"] + cut["steps"]]
                                                             ** 2, axis=1)).tolist(),
                      "error_m": significant(r.error[first:]), "nees": significant(r.nees[first:])}
    keys = ("scenario", "seconds", "steps", "start", "node", "runs", "seed", "ts", "filter", "fusion", "nees_dof",
            "nees_band")
    return {**{k: cut[k] for k in keys}, "first_step": first, "rules": rows}


def print_table(cuts: list[dict]) -> None:
    heads = ["cut", "rule", "RMS err. m", "/pred.", "end err. m", "/pred.", "NEES max/mean", "1 s after m"]
    rows = []
    for c in cuts:
        for rule, r in c["rules"].items():
            rows.append([f"{c['scenario']} {c['seconds']:g} s", rule, f"{r['rms_error_m']:.1f}",
                         f"{r['rms_vs_prediction']:.2f}", f"{r['end_error_m']:.1f}", f"{r['end_vs_prediction']:.2f}",
                         f"{r['max_nees']:.3g}/{r['mean_nees']:.3g}", f"{r['after_error_m']:.1f}"])
    print(table(heads, rows))
    lo, hi = cuts[0]["nees_band"]
    print(f"node {cuts[0]['node']} cut off both ways; errors: position, mean over the runs ({cuts[0]['runs']}); NEES: "
          f"{cuts[0]['nees_dof']}-D kinematic state, mean over the runs per step; its 95 % band {lo:.2f}-{hi:.2f}")


#: the NEES axes stop here (a rule whose NEES leaves it is named with its largest value)
NEES_TOP = 100.0


def _log_axis(ax) -> None:
    """A log y axis labelled in plain numbers at its decades only (the curves span up to five)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())


def plot(cuts: list[dict], path) -> list:
    """Per cut (a row): the position error (left) and the NEES (right) of every rule, log scale, from one second
    before the cut to the end of the run; the cut shaded, the NEES band dotted (the NEES axis stops at
    ``NEES_TOP``)."""
    fig, axes = new_figure(len(cuts), 2, width=12.0, height=3.2 * len(cuts))
    for row, c in enumerate(cuts):
        err_ax, nees_ax = axes[2 * row], axes[2 * row + 1]
        t0 = (c["first_step"] - c["start"]) * c["ts"]
        off_axis = []
        for rule, r in c["rules"].items():
            t = t0 + np.arange(len(r["error_m"])) * c["ts"]
            colour, style = STYLE[rule]
            err_ax.plot(t, r["error_m"], color=colour, linestyle=style, linewidth=1.2, label=RULES[rule][0])
            nees_ax.plot(t, r["nees"], color=colour, linestyle=style, linewidth=1.0, label=RULES[rule][0])
            if max(r["nees"]) > NEES_TOP:
                off_axis.append(f"{rule}: up to {max(r['nees']):.2g}")
        for ax in (err_ax, nees_ax):
            ax.axvspan(0.0, c["seconds"], color="#eeeeee", zorder=0)
            _log_axis(ax)
        for level in c["nees_band"]:
            nees_ax.axhline(level, color="black", linestyle=":", linewidth=0.9)
        nees_ax.set_ylim(top=NEES_TOP)
        if off_axis:
            nees_ax.annotate("off the axis: " + "; ".join(off_axis), (0.01, 0.97), xycoords="axes fraction",
                             va="top", fontsize=7)
        where = f"{c['scenario']}, node {c['node']} cut off for {c['seconds']:g} s"
        style_axes(err_ax, where, "time from the cut (s)", "position error, mean of runs (m)")
        style_axes(nees_ax, f"{where}: NEES (95 % band dotted)", "time from the cut (s)",
                   f"NEES ({c['nees_dof']}-D), mean of {c['runs']} runs")
    legend_outside(axes[1])
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    rules = [REFERENCE] + [r for r in args.rules if r != REFERENCE]
    t0 = time.perf_counter()
    cuts = []
    with Progress(len(args.scenarios) * len(args.cuts), "cuts", label="bench isolated") as bar:
        for scenario in args.scenarios:
            for seconds in args.cuts:
                cuts.append(figures(run_cut(scenario, seconds, args.runs, args.seed, rules)))
                bar.advance(1)
    print_table(cuts)
    print(f"\nwall {time.perf_counter() - t0:.0f} s")
    plot_path = figure_path(args.plot, args.json)
    drawn = plot(cuts, plot_path) if plot_path is not None else None
    if args.json:
        write_json(args.json, {"command": "bench isolated", "seed": args.seed, "runs": args.runs,
                               "after_cut_steps": AFTER_CUT, "reference": REFERENCE, "cuts": cuts})
    print(outputs_line("bench isolated done", json=args.json, plot=drawn))
    return 0
