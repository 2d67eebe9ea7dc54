"""``zentrack bench async``: sensors of their own (issue 52): late and reordered detections, per method, against the
bound.

Two scenarios: paper 0's Experiment 2 geometry (``exp2``, 6 nodes on the ring by default) and one real trajectory
(``adsb-aircraft``: an airliner's recorded path over Paris, 8 photoelectric stations). Every node's sensor runs at its
own rate (1, 4 and 10 Hz, cycled over the nodes), phase and clock (offsets within +-200 ms, the trackers told them),
its detections arriving 10-300 ms late and 10 % of them one sample period later still (reordered):
:mod:`zentrack.study.async_network`. Every node is a tracker of its own sensor (the scenario's filter, TESKF) fusing
with its ring neighbours by covariance intersection every sample period (single round, the scenario's weights).
Methods (:mod:`zentrack.study.async_methods`): **zero latency** (the reference: every detection at its measurement
time), **drop late**, the live tracker's **fixed lag** (350 ms), **re-processing** and the OOSM algorithm **Al1**;
beside them **Stone Soup** on the same detections in one process (centralized, its accumulated-state-density
out-of-sequence processing: :mod:`zentrack.study.stonesoup_async`). Per method and scenario:

- position RMSE of every tracker's published estimate at every fusion tick, and RMSE / sqrt(PCRLB) per run with
  the bound of every sensor's measurements at their true times (:func:`zentrack.study.pcrlb.pcrlb_timed`), median
  and inter-quartile range over the runs; each method's RMSE against the zero-latency run's on the same detections
  (median over the runs of the per-run ratio), against the aim of 5 %;
- ANEES with its 95 % band;
- detections applied in time order, applied late (re-processed, or by the OOSM update), dropped (drop late) and too
  old (beyond the lag or the buffer);
- processor time per detection: ``time.process_time`` around each tracker's handling of its detections and of its
  fusion ticks (prediction, update, its fusion message and the fusion), summed over the trackers and divided by the
  detections they got (Stone Soup: its detections and its predictions to the ticks);
- the estimate's age when published (how far behind the wall clock: the publication lag plus the processor time of
  the tick before it is published), max and 99th percentile, against the aim of one fusion period plus the lag.

Deterministic for a seed (the measured processor times aside). A figure (``--plot``, PNG and SVG) shows RMSE /
sqrt(PCRLB) and the processor time per detection of every method.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import name_list, positive_float, positive_int
from zentrack.common.plots import COLORS, new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, outputs_line
from zentrack.common.report import figure_path, fmt_num, fmt_stats, stats, table, write_json
from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.fusion.rules import make_rule
from zentrack.study.async_methods import METHODS, MethodCounts, NodeModel
from zentrack.study.async_network import (
    AsyncSettings,
    RingFusion,
    run_detections,
    run_method,
    stream_specs,
    timed_bound,
)
from zentrack.study.simulator import NetworkResult, evaluate
from zentrack.study.stonesoup_async import max_nstep, run_stonesoup_asd, run_stonesoup_buffered
from zentrack.study.stonesoup_multitarget import stonesoup_version
from zentrack.truth.simulation.simulate import simulate

SCENARIOS = ("exp2", "adsb-aircraft")
#: per scenario: nodes (None: the file's), steps and runs when not given (the default run takes about two minutes on
#: two cores, most of it Stone Soup's)
DEFAULTS: dict[str, tuple[int | None, int, int]] = {"exp2": (6, 300, 10), "adsb-aircraft": (None, 200, 3)}
#: Stone Soup's rows: its accumulated state densities, and its time-buffered feeder
STONESOUP = {"stonesoup-asd": "Stone Soup ASD", "stonesoup-buffered": "Stone Soup time-buffered"}
#: the issue's aims: within 5 % of the zero-latency RMSE; an estimate at most one fusion period plus the lag old
AIM_EXCESS = 0.05
REFERENCE = "zero-latency"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenarios", type=name_list(SCENARIOS, "scenario"), default=list(SCENARIOS),
                   help=f"comma-separated (default {','.join(SCENARIOS)})")
    p.add_argument("--runs", type=positive_int, help="Monte Carlo runs per scenario (default 10 on exp2, 3 on "
                                                       "adsb-aircraft)")
    p.add_argument("--steps", type=positive_int, help="fusion periods per run (default 300 on exp2, 200 on "
                                                        "adsb-aircraft)")
    p.add_argument("--nodes", type=positive_int, help="exp2's ring size (default 6)")
    p.add_argument("--seed", type=int, default=0, help="the truth's and the sensors' seed (default 0)")
    p.add_argument("--methods", type=name_list((*METHODS, *STONESOUP), "method"), default=[*METHODS, *STONESOUP],
                   help=f"comma-separated (default {','.join((*METHODS, *STONESOUP))})")
    p.add_argument("--lag", type=positive_float, default=AsyncSettings.lag_s, metavar="S",
                   help=f"the fixed lag, seconds (default {AsyncSettings.lag_s:g})")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="RMSE / sqrt(PCRLB) and CPU per detection per method "
                                                       "(PNG and SVG; default: beside --json)")


def counts_of(counts: MethodCounts, runs: int) -> dict:
    """What the trackers did with their detections, per run (summed over the trackers)."""
    out = {k: getattr(counts, k) / runs for k in ("arrived", "applied", "late", "dropped", "too_old", "rollbacks",
                                                    "replayed")}
    if counts.lag_events:
        lags = np.asarray(counts.lag_events)
        out["oosm_events_after_stored"] = {"mean": float(lags.mean()), "max": int(lags.max()),
                                           "one": float(np.mean(lags == 1))}
    return out


def ages(age: np.ndarray) -> dict:
    """An estimate's age at publication, ms: max, 99th percentile, median."""
    a = np.asarray(age, dtype=float).ravel() * 1e3
    return {"max": float(a.max()), "p99": float(np.percentile(a, 99)), "median": float(np.median(a))}


def row_of(scn, result: NetworkResult, bound: np.ndarray, name: str, label: str, lag: float, cpu_s: float,
           detections: int, age: np.ndarray, counts: dict, wall: float) -> dict:
    m = evaluate(scn, result, bound)
    return {"method": name, "label": label, "publish_lag_s": lag, "nodes": int(result.mean.shape[2]),
            "rmse": {g: stats(v) | {"runs": v} for g, v in m["rmse"].items() if g != "tot"},
            "rmse_over_sqrt_bound": {g: stats(v) | {"runs": v} for g, v in m["bound_ratio"].items()},
            "anees": m["anees"], "anees_band": m["anees_band"], "diverged_runs": m["diverged_runs"],
            "counts": counts, "cpu_us_per_detection": cpu_s / max(detections, 1) * 1e6, "detections": detections,
            "age_ms": ages(age), "wall_s": wall}


def excess_over(row: dict, reference: dict) -> dict:
    """``row``'s RMSE against the reference's on the same detections: the median over the runs of the per-run
    ratio, less one (p and v)."""
    out = {}
    for g in ("p", "v"):
        ratio = np.asarray(row["rmse"][g]["runs"]) / np.asarray(reference["rmse"][g]["runs"])
        out[g] = float(np.median(ratio) - 1.0)
    return out


def run_scenario(name: str, args: argparse.Namespace, settings: AsyncSettings, bar: Progress) -> dict:
    """Every method on scenario ``name``; ``bar`` advances by one per method."""
    nodes, steps, runs = DEFAULTS[name]
    cfg = resize(load_scenario_config(name), args.nodes if name == "exp2" and args.nodes else nodes,
                 args.steps or steps)
    runs = args.runs or runs
    scn = simulate(cfg.spec, runs=runs, seed=args.seed, ts=cfg.ts)
    specs = stream_specs(scn.nodes, settings, args.seed)
    detections = [run_detections(scn, specs, args.seed, r) for r in range(runs)]
    bound = timed_bound(scn, detections)
    params = {"qbar": cfg.qbar, "theta": cfg.theta, **cfg.filter_params}
    node = NodeModel.of(scn, cfg.filter_kind, params)
    fusion = RingFusion(scn, node, make_rule(cfg.fusion, cfg.fusion_params))
    rows = []
    for method in [m for m in args.methods if m in METHODS]:
        t0 = time.perf_counter()
        result, records = run_method(scn, detections, specs, method, node, fusion, settings)
        wall = time.perf_counter() - t0
        total = MethodCounts()
        for rec in records:
            total.add(rec.counts)
        rows.append(row_of(scn, result, bound, method, METHODS[method].label, lag=settings.lag_s if method ==
                           "fixed-lag" else 0.0, cpu_s=float(sum(rec.cpu_s.sum() for rec in records)),
                           detections=total.arrived, age=np.stack([rec.age for rec in records]),
                           counts=counts_of(total, runs), wall=wall))
        bar.advance(1)
        r = rows[-1]
        bar.write_above(f"[{name}] {r['label']}: RMSE_p/sqrt(B) {fmt_stats(r['rmse_over_sqrt_bound']['p'], 2)}, "
                        f"ANEES {r['anees']:.2f}, {r['cpu_us_per_detection']:.0f} us/detection, {wall:.1f} s")
    rate = sum(s.rate_hz for s in specs)
    for method in [m for m in args.methods if m in STONESOUP]:
        if method == "stonesoup-asd":
            size = max_nstep(rate, settings.latest_s())
            t0 = time.perf_counter()
            out = [run_stonesoup_asd(scn, r, detections[r], specs, size) for r in range(runs)]
        else:  # a buffer as long as the latencies' spread at the network's rate
            size = int(np.ceil(rate * (settings.latency.high_s - settings.latency.low_s))) + 1
            t0 = time.perf_counter()
            out = [run_stonesoup_buffered(scn, r, detections[r], specs, size) for r in range(runs)]
        wall = time.perf_counter() - t0
        result = NetworkResult(method, np.stack([o.mean for o in out]), np.stack([o.cov for o in out]),
                               np.array([o.diverged_at for o in out]))
        arrived = sum(o.arrived for o in out)
        counts = {"arrived": arrived / runs, "applied": sum(o.applied for o in out) / runs,
                  "late": sum(o.late for o in out) / runs, "dropped": 0.0,
                  "too_old": sum(o.too_old for o in out) / runs, "rollbacks": 0.0, "replayed": 0.0,
                  "max_nstep" if method == "stonesoup-asd" else "buffer_size": size}
        rows.append(row_of(scn, result, bound, method, STONESOUP[method], 0.0, cpu_s=sum(o.cpu_s for o in out),
                           detections=arrived, age=np.stack([o.age for o in out]), counts=counts, wall=wall))
        bar.advance(1)
        r = rows[-1]
        bar.write_above(f"[{name}] {r['label']}: RMSE_p/sqrt(B) {fmt_stats(r['rmse_over_sqrt_bound']['p'], 2)}, "
                        f"ANEES {r['anees']:.2f}, diverged {r['diverged_runs']}/{runs}, "
                        f"{r['cpu_us_per_detection']:.0f} us/detection, {wall:.1f} s")
    reference = next((r for r in rows if r["method"] == REFERENCE), None)
    age_aim_ms = (cfg.ts + settings.lag_s) * 1e3
    for r in rows:  # (Stone Soup is one centralized track: no network's figure to hold it to)
        r["vs_zero_latency"] = (None if reference is None or r is reference or r["method"] in STONESOUP
                                else excess_over(r, reference))
        r["aims"] = {"within_5_percent": None if r["vs_zero_latency"] is None else
                     bool(r["vs_zero_latency"]["p"] <= AIM_EXCESS),
                     "age_within_period_plus_lag": bool(r["age_ms"]["max"] <= age_aim_ms)}
    sqrt_bound = float(np.sqrt(np.mean(np.trace(bound[:, :, :3, :3], axis1=2, axis2=3))))
    return {"scenario": name, "nodes": scn.nodes, "steps": scn.steps, "ts": cfg.ts, "runs": runs,
            "filter": cfg.filter_kind, "fusion": cfg.fusion, "fusion_params": cfg.fusion_params,
            "sensors": [{"node": s.sensor, "rate_hz": s.rate_hz, "phase_s": s.phase_s, "offset_s": s.offset_s}
                        for s in specs],
            "detections_per_run": float(np.mean([sum(len(d) for d in run) for run in detections])),
            "sqrt_bound_p": sqrt_bound, "age_aim_ms": age_aim_ms, "rows": rows}


def print_table(res: dict) -> None:
    band = next((r["anees_band"] for r in res["rows"] if r["anees_band"]), None)
    print(f"\n{res['scenario']}: {res['nodes']} trackers ({res['filter'].upper()}, {res['fusion']} on a ring every "
          f"{res['ts']:g} s), {res['steps']} fusion periods, {res['runs']} runs, {res['detections_per_run']:.0f} "
          f"detections a run; sqrt(PCRLB) of the position {res['sqrt_bound_p']:.2f} m; median [IQR] over the runs; "
          f"ANEES 95% band {'n/a' if band is None else f'[{band[0]:.2f}, {band[1]:.2f}]'}; Stone Soup: one "
          "centralized track")
    heads = ["method", "RMSE p (m)", "p/sqrt(B)", "vs zero lat.", "ANEES", "in order", "late used", "dropped",
             "too old", "diverged", "us/det", "age max/p99 ms"]
    rows = []
    for r in res["rows"]:
        c, vs = r["counts"], r["vs_zero_latency"]
        rows.append([r["label"], fmt_stats(r["rmse"]["p"], 2), fmt_stats(r["rmse_over_sqrt_bound"]["p"], 2),
                     "ref." if r["method"] == REFERENCE else "-" if vs is None else f"{vs['p'] * 100:+.1f} %",
                     fmt_num(r["anees"], 2), f"{c['applied']:.0f}", f"{c['late']:.0f}", f"{c['dropped']:.0f}",
                     f"{c['too_old']:.0f}", f"{r['diverged_runs']}/{res['runs']}", f"{r['cpu_us_per_detection']:.0f}",
                     f"{r['age_ms']['max']:.1f} / {r['age_ms']['p99']:.1f}"])
    print(table(heads, rows))
    print(f"detection counts per run, over all trackers; us/det: processor time per detection; aims: RMSE within "
          f"{AIM_EXCESS:.0%} of zero latency's, an estimate at most one fusion period plus the lag "
          f"({res['age_aim_ms']:.0f} ms) old when published")
    for r in res["rows"]:
        a = r["aims"]
        if a["within_5_percent"] is not None:
            print(f"  {r['label']}: {r['vs_zero_latency']['p'] * 100:+.1f} % "
                  f"({'met' if a['within_5_percent'] else 'NOT met'}), age max {r['age_ms']['max']:.1f} ms "
                  f"({'met' if a['age_within_period_plus_lag'] else 'NOT met'})")


def _ms(v: float) -> str:
    return f"{v:.1f} ms" if v < 10 else f"{v:.0f} ms"


def plot(results: list[dict], path: Path) -> list[Path]:
    """Per scenario: RMSE_p / sqrt(PCRLB) of every method (median, IQR; its ANEES and diverged runs beside it) with
    the zero-latency figure and its 5 % aim, and the processor time per detection (log scale) with each method's
    largest estimate age."""
    fig, axes = new_figure(len(results), 2, width=12.0, height=4.6 * len(results))
    for row_i, res in enumerate(results):
        ratio_ax, cpu_ax = axes[2 * row_i], axes[2 * row_i + 1]
        rows = res["rows"]
        for x, r in enumerate(rows):
            s = {k: float(v) for k, v in r["rmse_over_sqrt_bound"]["p"].items() if k != "runs"}  # (JSON: "inf")
            colour = COLORS[x % len(COLORS)]
            anees = float(r["anees"])
            note = f"ANEES {anees:.1f}" if np.isfinite(anees) else ""
            if r["diverged_runs"]:
                note += f"\ndiverged {r['diverged_runs']}/{res['runs']}"
            if np.isfinite(s["median"]):
                lo, hi = (s["median"] - s["q25"], s["q75"] - s["median"])
                ratio_ax.errorbar([x], [s["median"]], yerr=[[lo], [hi if np.isfinite(hi) else 0.0]], fmt="o",
                                  color=colour, capsize=3)
                ratio_ax.annotate(note, (x, s["median"]), xytext=(6, 0), textcoords="offset points", fontsize=7,
                                  va="center")
            cpu_ax.bar([x], [r["cpu_us_per_detection"]], color=colour)
            cpu_ax.annotate(f"age ≤ {_ms(r['age_ms']['max'])}", (x, r["cpu_us_per_detection"]), ha="center",
                            va="bottom", fontsize=7, xytext=(0, 2), textcoords="offset points")
        ref = next((r for r in rows if r["method"] == REFERENCE), None)
        if ref is not None:
            level = ref["rmse_over_sqrt_bound"]["p"]["median"]
            ratio_ax.axhline(level, color="#555555", linestyle="--", linewidth=0.9, label="zero latency")
            ratio_ax.axhline(level * (1 + AIM_EXCESS), color="#555555", linestyle=":", linewidth=0.9,
                             label=f"zero latency + {AIM_EXCESS:.0%} (aim)")
        ratio_ax.axhline(1.0, color="black", linewidth=0.8, label="the bound")
        ratio_ax.set_ylim(bottom=0.0)
        for ax in (ratio_ax, cpu_ax):
            ax.set_xticks(range(len(rows)), [r["label"] for r in rows], rotation=25, ha="right", fontsize=8)
            ax.set_xlim(-0.5, len(rows) - 0.2)
        cpu_ax.set_yscale("log")
        title = (f"{res['scenario']}: {res['nodes']} trackers, {res['steps']} periods of {res['ts']:g} s, "
                 f"{res['runs']} runs (Stone Soup: one centralized track)")
        style_axes(ratio_ax, title, "method", "position RMSE / sqrt(PCRLB)")
        style_axes(cpu_ax, f"{res['scenario']}: processor time per detection, largest estimate age", "method",
                   "µs per detection (log)")
        ratio_ax.legend(fontsize=7, loc="lower left")
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    settings = AsyncSettings(lag_s=args.lag)
    version = stonesoup_version()
    if version is None and set(STONESOUP) & set(args.methods):
        args.methods = [m for m in args.methods if m not in STONESOUP]
        print("Stone Soup is not installed (pip install 'zentrack[bench]'): its rows are left out")
    t0 = time.perf_counter()
    with Progress(len(args.scenarios) * len(args.methods), "methods", label="bench async") as bar:
        results = [run_scenario(s, args, settings, bar) for s in args.scenarios]
    for res in results:
        print_table(res)
    print(f"\nwall {time.perf_counter() - t0:.0f} s")
    plot_path = figure_path(args.plot, args.json)
    figures = plot(results, plot_path) if plot_path is not None else None
    if args.json:
        s = settings
        write_json(args.json, {
            "command": "bench async", "seed": args.seed, "stonesoup": version, "aim_excess": AIM_EXCESS,
            "settings": {"rates_hz": list(s.rates_hz), "latency_s": [s.latency.low_s, s.latency.high_s],
                         "latency_kind": s.latency.kind, "reorder": s.reorder, "offset_s": s.offset_s,
                         "lag_s": s.lag_s, "max_lag_s": s.max_lag_s, "offsets": "told to the trackers"},
            "scenarios": results})
    print(outputs_line("bench async done", json=args.json, plot=figures))
    return 0
