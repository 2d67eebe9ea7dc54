"""``zentrack bench accuracy``: every local filter with every single-round fusion rule, against the PCRLB.

Two scenarios: paper 0 Experiment 2 (ring of 10 bearing sensors, ring graph) and ``exp2-irregular``
(sensors at irregular places, a random connected graph with Metropolis weights, a turning target;
``deploy/scenarios/exp2-irregular.toml``). For each, the centralized filters (the reference, one
fusion centre with every measurement) and every distributed filter with every fusion rule that uses one
exchange round per step run R Monte Carlo runs (batched simulator, fixed seeds). Per configuration:

- RMSE of position and velocity, and RMSE / sqrt(PCRLB) per run (each run's own bound, every sensor's
  measurements: :func:`zentrack.study.pcrlb.scenario_bound`), median and inter-quartile range over the runs;
- ANEES with its 95 % band (consistency), diverged runs;
- payload bytes each node sends per step for the fusion (its round messages and, for rules that share
  measurements, its forwarded scan and, with ``+relay``, its relay of the neighbours' scans), measured by encoding the real wire messages; the estimate every node also
  publishes to the recorder is the same for all and not counted, nor is Zenoh's framing;
- microseconds per node-step of the batched simulator (wall time / (runs x steps x nodes)).

A figure (PNG and SVG) plots RMSE_p / sqrt(bound) per configuration, the rules ordered by the bytes they send. Nothing here is tuned
to a target: the rules run with their defaults.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import name_list, positive_int
from zentrack.common.plots import color_of, legend_outside, new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, outputs_line
from zentrack.common.report import figure_path, fmt_num, fmt_stats, stats, table, write_json
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.rules import FusionRule, make_rule
from zentrack.study.pcrlb import scenario_bound
from zentrack.study.simulator import build_filter, evaluate, network_blocks, run_filter
from zentrack.transport.messages import RoundMessage
from zentrack.transport.scan_messages import ForwardedScan, Relay, RelayedScan
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.simulate import simulate

SCENARIOS = ("exp2", "exp2-irregular")
FILTERS = ("teskf", "eskf", "ukf", "ckf", "ekf")
#: label -> (registered rule, parameters); every rule here exchanges once per step. "N" stands for the
#: network size (hcmci with the paper's omega = N)
RULES: dict[str, tuple[str, dict]] = {
    "ci": ("ci", {}),
    "ci+share": ("ci", {"share_scans": True}),
    "ci-fast": ("ci-fast", {}),
    "ci-fast+share": ("ci-fast", {"share_scans": True}),
    "ci-trace+share": ("ci-trace", {"share_scans": True}),
    "hcmci": ("hcmci", {}),
    "hcmci(omega=N)": ("hcmci", {"omega": "N"}),
    "diff-fci": ("diff-fci", {}),
    "diff-ici": ("diff-ici", {}),
    "ci+relay": ("ci", {"share_scans": True, "relay_scans": True}),
    "diff-fci+relay": ("diff-fci", {"relay_scans": True}),
    "diff-ici+relay": ("diff-ici", {"relay_scans": True}),
}
#: the issue's target for the best single-round configuration on Experiment 2
TARGET_RATIO = 1.15


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=20, help="Monte Carlo runs per configuration (default 20)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--steps", type=positive_int, help="override the scenarios' 1000 steps (quick looks only)")
    p.add_argument("--scenarios", type=name_list(tuple(SCENARIOS), "scenario"), default=list(SCENARIOS),
                   help=f"comma-separated (default {','.join(SCENARIOS)})")
    p.add_argument("--filters", type=name_list(tuple(FILTERS), "filter"), default=list(FILTERS),
                   help=f"comma-separated (default {','.join(FILTERS)})")
    p.add_argument("--rules", type=name_list(tuple(RULES), "rule"), default=list(RULES),
                   help=f"comma-separated labels (default {','.join(RULES)})")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="RMSE/sqrt(bound) against bytes per step (default: beside --json)")


def make_config_rule(label: str, nodes: int) -> FusionRule:
    name, params = RULES[label]
    return make_rule(name, {k: (float(nodes) if v == "N" else v) for k, v in params.items()})


def bytes_per_step(scn: ScenarioData, kind: str, rule: FusionRule | None) -> int:
    """Payload bytes one node publishes per step for the fusion: its round messages (encoded as the tracker
    encodes them) and, where the rule shares measurements, its forwarded scan. 0 for a centralized filter."""
    if rule is None:
        return 0
    one = scn.run(0)
    filt = build_filter(one, kind)
    state = filt.initial_state(one.x0_estimate[:1], one.p0, one.lumped_var)
    message = rule.share(1, network_blocks(filt, state, 1, 1)).blocks
    blocks = {name: (pair.matrix[0, 0], pair.vector[0, 0]) for name, pair in message.items()}
    size = rule.rounds(1) * len(RoundMessage(1, 0.1, 0, 1, blocks, time.time()).encode())
    if rule.exchanges_scans:
        z = one.measurements[0, 1, 0]
        size += len(ForwardedScan(1, 0.1, 0, 0, z[None, :], one.sensors_at(1)[0], one.noise_cov[0], time.time()).encode())
    if rule.relays_scans:  # node 0's relay of its neighbours' scans
        relayed = tuple(RelayedScan(int(j), one.measurements[0, 1, j], one.sensors_at(1)[j], one.noise_cov[j])
                        for j in np.flatnonzero(one.adjacency[0]))
        size += len(Relay(1, 0.1, 0, relayed, time.time()).encode_capped()[0])
    return size


def measure(scn: ScenarioData, bound: np.ndarray, name: str, label: str | None) -> dict:
    rule = None if label is None else make_config_rule(label, scn.nodes)
    t0 = time.perf_counter()
    res = run_filter(scn, name) if rule is None else run_filter(scn, name, fusion=rule)
    wall = time.perf_counter() - t0
    m = evaluate(scn, res, bound)
    node_steps = scn.runs * scn.steps * (1 if rule is None else scn.nodes)
    return {
        "filter": name, "rule": label, "rounds": 0 if rule is None else rule.rounds(1),
        "rmse": {g: stats(v) for g, v in m["rmse"].items()},
        "rmse_over_sqrt_bound": {g: stats(v) | {"runs": v} for g, v in m["bound_ratio"].items()},
        "anees": m["anees"], "anees_band": m["anees_band"], "diverged_runs": m["diverged_runs"],
        "bytes_per_node_step": bytes_per_step(scn, name[1:], rule),
        "us_per_node_step": wall / node_steps * 1e6, "wall_s": wall,
    }


def configurations(filters: list[str], rules: list[str]) -> list[tuple[str, str | None]]:
    """(filter name, rule label or None): the centralized filters, then every distributed filter with every rule."""
    return [("c" + f, None) for f in filters] + [("d" + f, r) for f in filters for r in rules]


def run_scenario(scenario: str, filters: list[str], rules: list[str], runs: int, seed: int, steps: int | None,
                 bar: Progress | None = None) -> dict:
    """Every configuration on ``scenario``; ``bar`` advances by one per configuration (its lines above it)."""
    bar = bar or Progress(None, enabled=False)
    scn = simulate(builtin_spec(scenario, steps=steps), runs=runs, seed=seed)
    bound = scenario_bound(scn)
    configs = configurations(filters, rules)
    rows = []
    for i, (name, label) in enumerate(configs, 1):
        row = measure(scn, bound, name, label)
        rows.append(row)
        bar.advance(1)
        bar.write_above(f"[{scenario} {i}/{len(configs)}] {name}{' + ' + label if label else ''}: RMSE_p/sqrt(B) "
                 f"{fmt_stats(row['rmse_over_sqrt_bound']['p'], 2)}, ANEES {row['anees']:.2f}, {row['wall_s']:.1f} s")
    return {"scenario": scenario, "nodes": scn.nodes, "steps": scn.steps, "runs": runs, "rows": rows}


def best_distributed(result: dict) -> dict | None:
    """The distributed configuration with the lowest median RMSE_p / sqrt(bound) whose ANEES is at or below
    its upper band (consistent or conservative), or None."""
    ok = [r for r in result["rows"] if r["rule"] and r["anees_band"] and r["anees"] <= r["anees_band"][1]
          and r["diverged_runs"] == 0]
    return min(ok, key=lambda r: r["rmse_over_sqrt_bound"]["p"]["median"], default=None)


def print_table(result: dict) -> None:
    print(f"\n{result['scenario']}: {result['nodes']} nodes, {result['steps']} steps, median [IQR] over "
          f"{result['runs']} runs; RMSE / sqrt(PCRLB) per run")
    heads = ["filter", "rule", "RMSE p (m)", "RMSE v (m/s)", "p/sqrt(B)", "v/sqrt(B)", "ANEES", "95% band",
             "diverged", "bytes/step", "us/node-step"]
    rows = []
    for r in result["rows"]:
        band = r["anees_band"]
        rows.append([r["filter"].upper(), r["rule"] or "(centralized)", fmt_stats(r["rmse"]["p"], 3),
                     fmt_stats(r["rmse"]["v"], 3), fmt_stats(r["rmse_over_sqrt_bound"]["p"], 2),
                     fmt_stats(r["rmse_over_sqrt_bound"]["v"], 2), fmt_num(r["anees"], 2),
                     f"[{band[0]:.2f}, {band[1]:.2f}]" if band else "n/a", f"{r['diverged_runs']}/{result['runs']}",
                     str(r["bytes_per_node_step"]), fmt_num(r["us_per_node_step"], 3)])
    print(table(heads, rows))
    best = best_distributed(result)
    if best is None:
        print("best single-round distributed configuration: none is consistent")
    else:
        ratio = best["rmse_over_sqrt_bound"]["p"]["median"]
        print(f"best single-round distributed configuration (ANEES at or below its upper band): "
              f"{best['filter'].upper()} + {best['rule']}, RMSE_p / sqrt(bound) {ratio:.3f} (target <= {TARGET_RATIO}: "
              f"{'met' if ratio <= TARGET_RATIO else 'NOT met'}), ANEES {best['anees']:.2f}, "
              f"{best['bytes_per_node_step']} bytes per node-step")


#: RMSE_p / sqrt(bound) above this is drawn at it (a triangle): a diverged filter would squeeze the others
PLOT_CAP = 4.0


def plot(results: list[dict], path: Path) -> list[Path]:
    """One panel per scenario: median RMSE_p / sqrt(bound) (bars: inter-quartile range) of every distributed
    configuration, one column per fusion rule (ordered by the payload bytes it sends per node per step, named
    with them), one colour per local filter; each centralized filter a dashed line of its colour, the target
    a grey line. Written as PNG and SVG; their paths."""
    fig, axes = new_figure(len(results), 1, width=11.0, height=4.6 * len(results))
    for ax, res in zip(axes, results):
        rows = [r for r in res["rows"] if r["rule"]]
        rules = sorted({r["rule"] for r in rows}, key=lambda label: (min(r["bytes_per_node_step"] for r in rows
                                                                          if r["rule"] == label), label))
        filters = list(dict.fromkeys(r["filter"][1:] for r in res["rows"]))
        width = 0.8 / max(len(filters), 1)
        for f_i, kind in enumerate(filters):
            colour = color_of(kind)
            mine = {r["rule"]: r for r in rows if r["filter"][1:] == kind}
            xs = [rules.index(label) + (f_i - (len(filters) - 1) / 2) * width for label in mine]
            st = [r["rmse_over_sqrt_bound"]["p"] for r in mine.values()]
            med = np.array([min(s["median"], PLOT_CAP) for s in st])
            lo = np.array([min(s["q25"], PLOT_CAP) for s in st])
            hi = np.array([min(s["q75"], PLOT_CAP) for s in st])
            over = np.array([s["median"] > PLOT_CAP for s in st], dtype=bool)
            ax.errorbar(xs, med, yerr=[med - lo, hi - med], fmt="o", color=colour, markersize=5, capsize=2,
                        linewidth=0.8, label=f"D{kind.upper()}")
            if over.any():
                ax.plot(np.asarray(xs)[over], med[over], "^", color=colour, markersize=9)
            central = next((r for r in res["rows"] if r["filter"] == "c" + kind and not r["rule"]), None)
            if central is not None and np.isfinite(central["rmse_over_sqrt_bound"]["p"]["median"]):
                ax.axhline(min(central["rmse_over_sqrt_bound"]["p"]["median"], PLOT_CAP), color=colour,
                           linestyle="--", linewidth=0.9, label=f"C{kind.upper()} (centralized)")
        ax.axhline(TARGET_RATIO, color="#888888", linewidth=1.2, label=f"target {TARGET_RATIO:g}")
        ax.axhline(1.0, color="black", linewidth=0.8, label="the bound (1)")
        nbytes = {label: min(r["bytes_per_node_step"] for r in rows if r["rule"] == label) for label in rules}
        ax.set_xticks(range(len(rules)), [f"{label}\n{nbytes[label]} B" for label in rules], rotation=35,
                      ha="right", fontsize=8)
        ax.set_ylim(bottom=min(0.9, ax.get_ylim()[0]), top=min(ax.get_ylim()[1], PLOT_CAP * 1.05))
        style_axes(ax, f"{res['scenario']}: {res['nodes']} nodes, {res['steps']} steps, median and IQR over "
                       f"{res['runs']} runs (triangles: above {PLOT_CAP:g})",
                   "fusion rule (payload bytes per node per step)", "position RMSE / sqrt(PCRLB)")
        ax.tick_params(axis="x", labelsize=8)
        legend_outside(ax)
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    scenarios, filters, rules = args.scenarios, args.filters, args.rules
    t0 = time.perf_counter()
    with Progress(len(scenarios) * len(configurations(filters, rules)), "configurations", label="bench accuracy") as bar:
        results = [run_scenario(s, filters, rules, args.runs, args.seed, args.steps, bar) for s in scenarios]
    for res in results:
        print_table(res)
    print(f"\nwall {time.perf_counter() - t0:.0f} s")
    plot_path = figure_path(args.plot, args.json)
    figures = plot(results, plot_path) if plot_path is not None else None
    if args.json:
        best = {r["scenario"]: best_distributed(r) for r in results}
        write_json(args.json, {"command": "bench accuracy", "runs": args.runs, "seed": args.seed,
                               "target_ratio": TARGET_RATIO, "scenarios": results,
                               "best": {s: None if b is None else {k: b[k] for k in ("filter", "rule", "anees")}
                                        | {"ratio_p": b["rmse_over_sqrt_bound"]["p"]["median"],
                                           "bytes_per_node_step": b["bytes_per_node_step"]}
                                        for s, b in best.items()}})
    print(outputs_line("bench accuracy done", json=args.json, plot=figures))
    return 0
