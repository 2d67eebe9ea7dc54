"""``zentrack bench paper0``: paper 0 Table 2 (Experiment 1) and Table 3 (Experiment 2) beside ours.

Every filter runs R Monte Carlo runs (fixed seeds, batched) of the paper's scenario; we print the paper's
single-run row and our median [inter-quartile range] over the runs.  Times: the paper's column is one
MATLAB run; ``time/run`` is our batched wall time divided by R, ``1-run`` one unbatched run. A figure (PNG
and SVG, ``--plot``, default beside ``--json``) shows each filter's RMSE beside the paper's and against the
bound.
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import positive_int
from zentrack.common.plots import color_of, log_scale, new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, outputs_line
from zentrack.common.report import figure_path, fmt_num, fmt_stats, stats, table, write_json
from zentrack.config.scenario_config import builtin_spec
from zentrack.study.pcrlb import scenario_bound
from zentrack.study.simulator import evaluate, run_filter
from zentrack.truth.simulation.simulate import simulate

# Paper 0 Table 2: RMSE x1, x2, tot, time (s)
PAPER_TABLE2 = {
    "cteskf": (0.8059, 0.9285, 1.2295, 0.0419),
    "cekf": (1.3093, 1.0922, 1.7051, 0.0322),
    "ceskf": (0.9288, 1.2700, 1.5734, 0.0536),
    "cukf": (1.2764, 1.0891, 1.6779, 0.0426),
    "cckf": (1.2915, 1.0904, 1.6902, 0.0443),
    "dteskf": (1.0601, 0.9948, 1.4538, 0.2256),
    "dekf": (1.3762, 1.1402, 1.7872, 0.2342),
    "deskf": (1.1174, 1.1218, 1.5834, 0.2329),
    "dukf": (1.3681, 1.1410, 1.7814, 0.4323),
    "dckf": (1.3661, 1.1396, 1.7790, 0.4087),
}
# Paper 0 Table 3: RMSE p, v, tot, time (s); cteskf is ours only (the paper has no row for it)
PAPER_TABLE3 = {
    "dteskf": (6.7649, 8.5797, 10.9259, 0.3103),
    "dukf": (7.0591, 7.0758, 9.9949, 0.5848),
    "dckf": (7.5545, 7.2560, 10.4747, 0.5671),
    "deskf": (7.3625, 9.4077, 11.9461, 0.3733),
    "dekf": (69.3945, 22.0093, 72.8011, 0.3196),
    "cteskf": None,
}
#: the paper's algorithm names in the zentrack vocabulary, printed under each table
PAPER_NAMES = ("algorithm: the paper's name; D<filter> is `--filter <filter> --fusion ci`, C<filter> is `--filter "
               "<filter> --fusion centralized`\n(DTESKF: --filter teskf --fusion ci)")
EXPERIMENTS: dict[str, tuple[str, Mapping[str, tuple[float, ...] | None], tuple[str, ...]]] = {
    "1": ("exp1", PAPER_TABLE2, ("x1", "x2", "tot")),
    "2": ("exp2", PAPER_TABLE3, ("p", "v", "tot")),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=20, help="Monte Carlo runs per filter (default 20)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--experiments", default="1,2", help="which experiments: 1, 2 or 1,2 (default)")
    p.add_argument("--steps", type=positive_int, help="override the paper's length (quick looks only)")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="RMSE per filter beside the paper's, and against the bound "
                                                       "(PNG and SVG; default: beside --json)")


def run_experiment(key: str, runs: int, seed: int, steps: int | None, bar: Progress | None = None) -> dict:
    """Every filter of the experiment's table on R runs; ``bar`` advances by one per filter (lines above it)."""
    bar = bar or Progress(None, enabled=False)
    progress = bar.write_above
    scenario, paper, cols = EXPERIMENTS[key]
    t0 = time.perf_counter()
    scn = simulate(builtin_spec(scenario, steps=steps), runs=runs, seed=seed)
    progress(f"[exp {key}] simulated {runs} runs of {scn.steps} steps in {time.perf_counter() - t0:.1f} s")
    bound = scenario_bound(scn)  # each run's own PCRLB, every node's measurements (study/pcrlb.py)
    out = {}
    for i, name in enumerate(paper, 1):
        t0 = time.perf_counter()
        res = run_filter(scn, name)
        batched = time.perf_counter() - t0
        t1 = time.perf_counter()
        run_filter(scn.run(0), name)
        single = time.perf_counter() - t1
        m = evaluate(scn, res, bound)
        row = paper[name]
        out[name] = {
            "paper": None if row is None else dict(zip(cols + ("time_s",), row)),
            "rmse": {c: stats(m["rmse"][c]) | {"runs": m["rmse"][c]} for c in cols},
            "anees": m["anees"], "anees_band": m["anees_band"], "eta": m["eta"],
            "diverged_runs": m["diverged_runs"], "diverged_at": m["diverged_at"],
            "rmse_over_sqrt_bound": {g: stats(v) | {"runs": v} for g, v in m["bound_ratio"].items()},
            "time_per_run_s": batched / runs, "single_run_s": single,
        }
        bar.advance(1)
        progress(f"[exp {key} {i}/{len(paper)}] {name}: RMSE tot {fmt_stats(out[name]['rmse']['tot'])}, "
                 f"{batched:.1f} s for {runs} runs")
    return {"scenario": scenario, "steps": scn.steps, "nodes": scn.nodes, "runs": runs, "filters": out, "cols": cols}


def print_table(key: str, exp: dict) -> None:
    cols = exp["cols"]
    title = "Table 2 (Experiment 1)" if key == "1" else "Table 3 (Experiment 2)"
    print(f"\nPaper 0 {title}: {exp['scenario']}, {exp['nodes']} nodes, {exp['steps']} steps, "
          f"ours = median [IQR] over {exp['runs']} runs")
    rows = []
    for name, f in exp["filters"].items():
        p = f["paper"]
        ratio_cols = [c for c in cols if c in f["rmse_over_sqrt_bound"]]
        rows.append([name.upper(), "paper"] + ([fmt_num(p[c], 4) for c in cols] + [fmt_num(p["time_s"], 4)] if p else ["-"] * (len(cols) + 1)) + [""] * (4 + len(ratio_cols)))
        band = f["anees_band"]
        rows.append(["", "ours"] + [fmt_stats(f["rmse"][c]) for c in cols] + [
            fmt_num(f["time_per_run_s"], 3), fmt_num(f["single_run_s"], 3)]
            + [fmt_stats(f["rmse_over_sqrt_bound"][c], 2) for c in ratio_cols] + [fmt_num(f["anees"], 2),
            f"[{band[0]:.2f}, {band[1]:.2f}]" if band else "n/a", f"{f['diverged_runs']}/{exp['runs']}"])
    ratio_heads = [f"{c}/sqrt(B)" for c in cols if c != "tot"]
    heads = ["algorithm", ""] + [f"RMSE {c}" for c in cols] + ["time/run s", "1-run s"] + ratio_heads + [
        "ANEES", "95% band", "diverged"]
    print(table(heads, rows))
    print(PAPER_NAMES)


def shape_checks(exps: dict) -> list[str]:
    """The expected shape of the results (paper 0 Section 6), stated with the measured figures."""
    lines = []
    if "2" in exps:
        f = exps["2"]["filters"]
        med = {n: f[n]["rmse"]["p"]["median"] for n in f}
        worst = max(med, key=lambda n: med[n])
        lines.append(f"Exp 2: worst median position RMSE is {worst.upper()} ({fmt_num(med[worst])}); paper: DEKF")
        ratio = med["dteskf"] / med["cteskf"]
        lines.append(f"Exp 2: DTESKF / CTESKF median position RMSE = {ratio:.2f} (expected <= 1.3)")
        d = f["dteskf"]
        if d["anees_band"]:
            lines.append(f"Exp 2: DTESKF ANEES {d['anees']:.2f} vs 95% band [{d['anees_band'][0]:.2f}, "
                         f"{d['anees_band'][1]:.2f}] (expected at or below the upper bound; eta {d['eta']:.2f})")
    if "1" in exps:
        f = exps["1"]["filters"]
        ratio = f["dteskf"]["rmse"]["tot"]["median"] / f["cteskf"]["rmse"]["tot"]["median"]
        lines.append(f"Exp 1: DTESKF / CTESKF median total RMSE = {ratio:.2f} (paper 1.18)")
    return lines


def plot(exps: dict, path: Path) -> list[Path]:
    """Per experiment, two panels: each filter's RMSE (median and IQR over the runs; a log scale when the values
    span more than 5x, e.g. Exp 2's DEKF) beside the paper's single run, and its RMSE / sqrt(PCRLB). Written as PNG and SVG."""
    fig, axes = new_figure(len(exps), 2, width=12.0, height=4.2 * len(exps))
    for row, (key, exp) in enumerate(exps.items()):
        rmse_ax, ratio_ax = axes[2 * row], axes[2 * row + 1]
        names = list(exp["filters"])
        col = "tot"
        ratio_col = "p" if "p" in exp["cols"] else exp["cols"][0]
        for x, name in enumerate(names):
            f = exp["filters"][name]
            colour = color_of(name)
            s = f["rmse"][col]
            rmse_ax.errorbar([x], [s["median"]], yerr=[[s["median"] - s["q25"]], [s["q75"] - s["median"]]], fmt="o",
                             color=colour, capsize=3, label="ours: median, IQR" if x == 0 else None)
            if f["paper"]:
                rmse_ax.plot([x], [f["paper"][col]], "x", color="black", markersize=8,
                             label="paper (one run)" if "paper (one run)" not in
                             [h.get_label() for h in rmse_ax.get_lines()] else None)
            r = f["rmse_over_sqrt_bound"].get(ratio_col)
            if r is not None:
                ratio_ax.errorbar([x], [r["median"]], yerr=[[r["median"] - r["q25"]], [r["q75"] - r["median"]]],
                                  fmt="o", color=colour, capsize=3)
        ratio_ax.axhline(1.0, color="black", linewidth=0.8, label="the bound")
        title = "Table 2, Experiment 1" if key == "1" else "Table 3, Experiment 2"
        for ax in (rmse_ax, ratio_ax):
            ax.set_xticks(range(len(names)), [n.upper() for n in names], rotation=30, ha="right")
        shown = [v for f in exp["filters"].values() for v in [f["rmse"][col]["q75"], f["rmse"][col]["q25"]]
                 + ([f["paper"][col]] if f["paper"] else []) if np.isfinite(v) and v > 0]
        wide = bool(shown) and max(shown) / min(shown) > 5  # a diverged filter: a log scale keeps the rest readable
        if wide:
            log_scale(rmse_ax)
        style_axes(rmse_ax, f"{title} ({exp['scenario']}, {exp['runs']} runs of {exp['steps']} steps)", "filter",
                   f"total RMSE (m{', log scale' if wide else ''})")
        style_axes(ratio_ax, f"{title}: against the PCRLB", "filter", f"RMSE {ratio_col} / sqrt(PCRLB)")
        rmse_ax.legend(fontsize=8, loc="upper left")
        ratio_ax.legend(fontsize=8, loc="upper left")
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    keys = [k.strip() for k in args.experiments.split(",") if k.strip()]
    bad = [k for k in keys if k not in EXPERIMENTS]
    if bad or not keys:
        raise ValueError(f"--experiments takes 1, 2 or 1,2; got {args.experiments!r}")
    with Progress(sum(len(EXPERIMENTS[k][1]) for k in keys), "filters", label="bench paper0") as bar:
        exps = {k: run_experiment(k, args.runs, args.seed, args.steps, bar) for k in keys}
    for k, exp in exps.items():
        print_table(k, exp)
    checks = shape_checks(exps)
    print("\nShape checks (measured, not tuned):")
    for line in checks:
        print("  " + line)
    if args.json:
        write_json(args.json, {"command": "bench paper0", "runs": args.runs, "seed": args.seed,
                               "experiments": exps, "shape_checks": checks, "numpy": np.__version__})
    plot_path = figure_path(args.plot, args.json)
    figures = plot(exps, plot_path) if plot_path is not None else None
    print(outputs_line("bench paper0 done", json=args.json, plot=figures))
    return 0
