"""``zentrack bench paper4``: paper 4's comparison of distributed extended-object filters.

For the paper's S2 (ellipse, 170 m x 40 m) and S3 (rectangle, 10 m x 5 m) and point rates lambda in
{5, 10}, R Monte Carlo runs (default the paper's 50) of a 20-node network (6 sensors, 14 relays) run
(:mod:`zentrack.study.eot_network`): the centralized information filter (CEOT), consensus on information
(CI) and consensus on measurements (CM) with L in {1, 2, 6, 10} rounds per point, and the diffusion
baseline (DEOT); beside them, what the tracker processes run (``ci/scan``, ``cm/scan``: the rules ``eot-ci``
and ``eot-cm``, one exchange of L = 6 rounds per scan, scored as a tracker publishes its estimate: the local
posterior before the exchange).  Reported per method, averaged over runs, nodes and scans: the Gaussian Wasserstein
distance (S2) or the OSPA on the rectangle's corners (S3), the ACEE of the kinematics and of the extent
(disagreement between nodes), the ANEES of both blocks with its 95 % band, and the run time per scan.  The
paper's qualitative findings are checked one by one and printed with the figures; curves over time (PNG, SVG) and
a JSON of everything are written. No RMSE / sqrt(PCRLB) here (:data:`NO_BOUND`).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import positive_int
from zentrack.common.plots import COLORS as PALETTE
from zentrack.common.plots import new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, note, outputs_line
from zentrack.common.report import figure_path, fmt_num, table, write_json
from zentrack.config import catalogue
from zentrack.config.scenario_config import load_scenario_config
from zentrack.fusion.consistency import anees_band, nees
from zentrack.fusion.extent import OSPA_CUTOFF_S3, OSPA_ORDER, acee, gaussian_wasserstein, rectangle_corners
from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.multitarget.metrics import ospa
from zentrack.fusion.rules import make_rule
from zentrack.study.eot_network import EotResult, run_eot_scenario
from zentrack.study.simulator import run_filter
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.simulate import simulate

ROUNDS = (1, 2, 6, 10)
RATES = (5.0, 10.0)
#: each method's colour and line style in the figure
COLORS = {"ceot": "black", "ci": PALETTE[0], "cm": PALETTE[1], "deot": PALETTE[7]}
STYLES = {"ceot": "--", "ci": "-", "cm": "-", "deot": ":"}


#: why this benchmark reports no RMSE / sqrt(PCRLB) (printed, and in the JSON)
NO_BOUND = ("no PCRLB: a point is y = H x + S h + v with h uniform over the shape, a non-Gaussian scatter whose "
            "Fisher information zentrack does not compute; the Gaussian recursion with S h's covariance as noise "
            "is not a lower bound for it, so no RMSE / sqrt(bound) is reported")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=50, help="Monte Carlo runs (default the paper's 50)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--scenarios", default="eot-s2,eot-s3", type=catalogue.scenario_list,
                   help="comma-separated extended-object scenarios (default: S2 ellipse, S3 rectangle)")
    p.add_argument("--rates", default="5,10", help="comma-separated point rates lambda (default 5,10)")
    p.add_argument("--rounds", default="1,2,6,10", help="comma-separated consensus rounds L (default 1,2,6,10)")
    p.add_argument("--steps", type=positive_int, default=103, help="scans per run (default the paper's 103)")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="error curves over time (default: beside --json)")


def _csv(text: str, kind: type) -> list:
    try:
        values = [kind(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise SystemExit(f"bench paper4: bad list {text!r}: {exc}") from None
    if not values:
        raise SystemExit(f"bench paper4: empty list {text!r}")
    return values


def shape_error(data: ScenarioData, res: EotResult) -> np.ndarray:
    """``(R, K, M)``: GW distance (ellipse) or OSPA on the corners (rectangle) of every node's estimate."""
    m_true, p_true = data.truth[:, :, None, :2], data.truth[:, :, None, 4:]
    if data.measurement == "extent-ellipse":
        return gaussian_wasserstein(res.x[..., :2], res.p, m_true, p_true)
    est = rectangle_corners(res.x[..., :2], res.p)
    true = np.broadcast_to(rectangle_corners(m_true, p_true), est.shape)
    return ospa(est, true, OSPA_CUTOFF_S3, OSPA_ORDER).total


def evaluate(data: ScenarioData, res: EotResult) -> dict:
    """The figures of one method: shape error and ACEE over time and averaged, ANEES of both blocks."""
    err = shape_error(data, res)  # (R, K, M)
    ex = res.x - data.truth[:, :, None, :4]
    ep = res.p - data.truth[:, :, None, 4:]
    ep[..., 0] = wrap_angle(ep[..., 0])
    nees_x = nees(ex, res.cx)
    nees_p = nees(ep, res.cp)
    acee_x = acee(res.x) if res.x.shape[2] > 1 else np.zeros(err.shape[:2])
    acee_p = acee(res.p) if res.p.shape[2] > 1 else np.zeros(err.shape[:2])
    return {
        "shape_error_per_scan": err.mean(axis=(0, 2)).tolist(),
        "shape_error": float(err.mean()),
        "acee_kinematic": float(acee_x.mean()), "acee_extent": float(acee_p.mean()),
        "acee_kinematic_per_scan": acee_x.mean(axis=0).tolist(),
        "anees_kinematic": float(nees_x.mean()), "anees_extent": float(nees_p.mean()),
        "ms_per_scan": 1e3 * res.wall_s / res.x.shape[1],
    }


def findings(rows: dict[str, dict], rounds: list[int]) -> list[tuple[str, bool, str]]:
    """The paper's qualitative findings, each with whether it holds here and the numbers behind it."""
    out = []
    ceot = rows["ceot"]["shape_error"]
    cm = [rows[f"cm L={L}"]["shape_error"] for L in rounds]
    ci = [rows[f"ci L={L}"]["shape_error"] for L in rounds]
    monotone = all(b <= a * 1.02 for a, b in zip(cm, cm[1:]))
    out.append(("CM improves with L", monotone and cm[-1] < cm[0],
                " > ".join(fmt_num(v, 3) for v in cm)))
    out.append(("CM at the largest L is close to CEOT (within 10 %)", cm[-1] <= 1.10 * ceot,
                f"CM {fmt_num(cm[-1], 3)} vs CEOT {fmt_num(ceot, 3)}"))
    out.append(("CI converges already at L = 1 (within 15 % of its largest L)", ci[0] <= 1.15 * ci[-1],
                f"L={rounds[0]} {fmt_num(ci[0], 3)} vs L={rounds[-1]} {fmt_num(ci[-1], 3)}"))
    ci_rows = [rows[f"ci L={L}"] for L in rounds]
    conservative = all(r["anees_kinematic"] < 4 and r["anees_extent"] < 3 for r in ci_rows)
    out.append(("CI is conservative (ANEES below the dimension, every L)", conservative,
                ", ".join(f"{fmt_num(r['anees_kinematic'], 2)}/{fmt_num(r['anees_extent'], 2)}" for r in ci_rows)))
    deot = rows["deot"]["shape_error"]
    out.append(("DEOT fails with relays (error above 1.5 x CI and CM at the largest L)",
                deot > 1.5 * max(ci[-1], cm[-1]), f"DEOT {fmt_num(deot, 3)}"))
    return out


def plot(curves: dict[str, dict[str, list[float]]], metrics: dict[str, str], path: Path) -> list[Path]:
    """One panel per scenario and rate (two columns): the shape error per scan of CEOT, CI, CM (largest L) and
    DEOT, in that case's metric (``metrics``: case -> axis label); one legend above the panels. PNG and SVG."""
    cols = 2 if len(curves) > 1 else 1
    rows = -(-len(curves) // cols)
    fig, axes = new_figure(rows, cols, width=12.0, height=3.6 * rows)
    for ax, (case, per_method) in zip(axes, curves.items()):
        for name, values in per_method.items():
            kind = name.split()[0]
            ax.plot(np.arange(1, len(values) + 1), values, color=COLORS[kind], linestyle=STYLES[kind], linewidth=1.4,
                    label=name.upper() if kind in ("ceot", "deot") else name.replace(" L=", ", L = ").upper())
        style_axes(ax, case.replace("lambda=", "point rate \u03bb = "), "scan", metrics[case])
        ax.set_ylim(bottom=0.0)
    for ax in axes[len(curves):]:
        ax.set_visible(False)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper center", ncols=len(labels), fontsize=9, frameon=False)
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    rounds = sorted(_csv(args.rounds, int))
    if rounds[0] < 1:
        raise SystemExit("bench paper4: rounds must be >= 1")
    out: dict = {"command": "bench paper4", "runs": args.runs, "seed": args.seed, "rounds": rounds, "cases": {}}
    curves: dict[str, dict[str, list[float]]] = {}
    metrics: dict[str, str] = {}
    all_hold = True
    cases = len(_csv(args.scenarios, str)) * len(_csv(args.rates, float))
    with Progress(cases * (2 * len(rounds) + 4), "methods", label="bench paper4"):  # CEOT, CI, CM, DEOT, 2 rules
        for name in _csv(args.scenarios, str):
            for rate in _csv(args.rates, float):
                cfg = load_scenario_config(name)
                assert cfg.spec.extent is not None, f"{name} is not an extended-object scenario"
                cfg.spec.extent.rate, cfg.spec.steps = rate, args.steps
                data = simulate(cfg.spec, args.runs, args.seed, cfg.ts)
                shape = data.measurement.removeprefix("extent-")
                metric = "GW distance (m)" if shape == "ellipse" else f"OSPA corners (m, c={OSPA_CUTOFF_S3:g})"
                methods = [("ceot", 1), *[("ci", L) for L in rounds], *[("cm", L) for L in rounds], ("deot", 1)]
                rows = {}
                for algo, L in methods:
                    label = algo if algo in ("ceot", "deot") else f"{algo} L={L}"
                    t0 = time.perf_counter()
                    res = run_eot_scenario(algo, data, rounds=L)
                    res.wall_s = time.perf_counter() - t0
                    rows[label] = evaluate(data, res)
                    note(f"[paper4] {name} lambda={rate:g} {label}: {rows[label]['shape_error']:.3f} "
                         f"({res.wall_s:.1f} s)", done=1)
                live = rounds[-1] if 6 not in rounds else 6
                for rule in ("eot-ci", "eot-cm"):  # what the trackers run: one exchange of L rounds per scan
                    label = f"{rule.removeprefix('eot-')}/scan L={live}"
                    t0 = time.perf_counter()
                    net = run_filter(data, "dmem-if", make_rule(rule, {"rounds": live}))
                    res = EotResult(label, net.mean[..., :4], net.cov[..., :4, :4], net.mean[..., 4:], net.cov[..., 4:, 4:],
                                    time.perf_counter() - t0)
                    rows[label] = evaluate(data, res)
                    note(f"[paper4] {name} lambda={rate:g} {label}: {rows[label]['shape_error']:.3f} "
                         f"({res.wall_s:.1f} s)", done=1)
                samples = args.runs * args.steps
                band_x, band_p = anees_band(4, samples), anees_band(3, samples)
                print(f"\npaper 4, {name} ({shape}), lambda = {rate:g}: {args.runs} runs x {args.steps} scans, "
                      f"{data.nodes} nodes ({int(np.sum(data.roles == 'sensor'))} sensors)")
                print(table(["method", metric, "ACEE kin", "ACEE ext",
                             f"ANEES kin (band {band_x[0]:.2f}-{band_x[1]:.2f})",
                             f"ANEES ext (band {band_p[0]:.2f}-{band_p[1]:.2f})", "ms/scan"],
                            [[k, fmt_num(v["shape_error"], 3), fmt_num(v["acee_kinematic"], 3),
                              fmt_num(v["acee_extent"], 3), fmt_num(v["anees_kinematic"], 2),
                              fmt_num(v["anees_extent"], 2), fmt_num(v["ms_per_scan"], 1)] for k, v in rows.items()]))
                checks = findings(rows, rounds)
                for text, holds, numbers in checks:
                    print(f"  [{'holds' if holds else 'DOES NOT HOLD'}] {text}: {numbers}")
                    all_hold &= holds
                key = f"{name} lambda={rate:g}"
                out["cases"][key] = {"scenario": name, "shape": shape, "rate": rate, "metric": metric,
                                     "methods": rows, "anees_band_95": {"kinematic": band_x, "extent": band_p},
                                     "findings": [{"finding": t, "holds": h, "numbers": n} for t, h, n in checks]}
                top = rounds[-1]
                metrics[key] = metric
                curves[key] = {
                    m: rows[m]["shape_error_per_scan"] for m in ("ceot", f"ci L={top}", f"cm L={top}", "deot")}
    out["all_findings_hold"] = all_hold
    out["wall_s"] = time.perf_counter() - t_start
    out["bound"] = NO_BOUND
    print(f"\nall findings hold: {'yes' if all_hold else 'no'}; wall time {out['wall_s']:.0f} s")
    print(NO_BOUND)
    plot_path = figure_path(args.plot, args.json)
    figures = plot(curves, metrics, plot_path) if plot_path is not None else None
    if args.json:
        write_json(args.json, out)
    print(outputs_line("bench paper4 done", json=args.json, plot=figures))
    return 0
