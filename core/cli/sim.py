"""``zentrack sim``: run filters on a scenario in the batched in-process simulator and report metrics."""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from zentrack.cluster.report import fmt_num, fmt_stats, stats, table, write_json
from zentrack.common.argtypes import (
    check_node_steps,
    fusion_param,
    fusion_params_with,
    int_in,
    name_list,
    nodes_int,
    qbar_float,
    runs_int,
    seed_int,
    steps_int,
    theta_float,
)
from zentrack.common.limits import MAX_NODE_STEPS, MAX_NODES, MAX_RUNS, MAX_STEPS
from zentrack.config.scenario_file import load_scenario, save_scenario
from zentrack.fusion.defaults import DEFAULT_FUSION, DEFAULT_QBAR, MAX_ROUNDS
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.pcrlb import scenario_bound
from zentrack.fusion.rules import RULE_REGISTRY, make_rule
from zentrack.fusion.rules.consensus import resolve_rounds
from zentrack.fusion.scenario import SCENARIOS, ScenarioData, builtin_spec, simulate
from zentrack.fusion.simulator import FILTERS, FUSION_RULES, evaluate, run_filter, state_groups


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="exp2", choices=sorted(SCENARIOS), help="built-in scenario (default exp2)")
    p.add_argument("--scenario-file", metavar="PATH", help="replay a scenario .npz instead of simulating one")
    p.add_argument("--filter", type=name_list(FILTERS, "filter"), default=["dteskf"], metavar="NAMES",
                   help=f"comma-separated filters: {', '.join(FILTERS)} (default dteskf)")
    p.add_argument("--nodes", type=nodes_int, help=f"number of nodes, 1 to {MAX_NODES} (default: the scenario's, 10)")
    p.add_argument("--steps", type=steps_int, help=f"number of steps, 1 to {MAX_STEPS} (default: the scenario's)")
    p.add_argument("--runs", type=runs_int, default=1, help=f"Monte Carlo runs, 1 to {MAX_RUNS} (default 1); "
                   f"runs x steps x nodes at most {MAX_NODE_STEPS}")
    p.add_argument("--seed", type=seed_int, default=0, help="random seed (default 0)")
    p.add_argument("--fusion", choices=FUSION_RULES, default=DEFAULT_FUSION,
                   help=f"fusion rule for distributed filters (default {DEFAULT_FUSION})")
    p.add_argument("--rounds", type=int_in(1, MAX_ROUNDS, "rounds"),
                   help="fusion rounds per step, for rules with a 'rounds' parameter (default: the rule's)")
    p.add_argument("--fusion-param", action="append", type=fusion_param, metavar="KEY=VALUE",
                   help="a parameter of the fusion rule, repeatable (e.g. share_scans=true, omega=10)")
    p.add_argument("--list-filters", action="store_true",
                   help="print the registered local filters and fusion rules with their parameters, and exit")
    p.add_argument("--qbar", type=qbar_float, default=DEFAULT_QBAR, help=f"injection bound qbar (default {DEFAULT_QBAR:g})")
    p.add_argument("--theta", type=theta_float, help="inflation theta (default: trace-balance heuristic)")
    p.add_argument("--json", metavar="PATH", help="write the results as JSON")
    p.add_argument("--save-scenario", metavar="PATH", help="write the simulated scenario to a .npz file")
    p.add_argument("--save-estimates", metavar="PATH",
                   help="write every node's posterior mean/cov per step to a .npz (keys <filter>_mean, <filter>_cov)")


def load_or_simulate(args: argparse.Namespace) -> ScenarioData:
    if args.scenario_file:
        if args.nodes or args.steps or args.runs != 1:
            raise ValueError("--nodes/--steps/--runs come from the file when --scenario-file is given")
        return load_scenario(args.scenario_file)
    spec = builtin_spec(args.scenario, args.nodes, args.steps)
    check_node_steps(args.runs, spec.steps, spec.nodes)
    return simulate(spec, runs=args.runs, seed=args.seed)


def list_components() -> str:
    lines = ["local filters (zentrack sim --filter d<name>|c<name>; TOML [filter] kind = <name>):"]
    lines += [f"  {line}" for line in FILTER_REGISTRY.describe()]
    lines += ["fusion rules (--fusion <name>; TOML [fusion] rule = <name>):"]
    lines += [f"  {line}" for line in RULE_REGISTRY.describe()]
    return "\n".join(lines)


def scenario_bound_or_why(scn: ScenarioData) -> tuple[np.ndarray | None, str]:
    """The scenario's centralized per-run PCRLB and a line saying what it is (or why there is none)."""
    try:
        bound = scenario_bound(scn)
    except ValueError as exc:
        return None, f"no Cramer-Rao bound: {exc}"
    return bound, ("x/sqrt(B): RMSE over the root of the posterior Cramer-Rao bound of all nodes' measurements "
                   "along each run's own trajectory (1 = the best any estimator can do), median [IQR] over runs")


def bound_summary(scn: ScenarioData, bound: np.ndarray | None) -> dict | None:
    """The bound's figures for the JSON: per group the root of its time-averaged trace (mean over runs), for the
    network and for each node alone (what that node's own measurements allow)."""
    if bound is None:
        return None
    groups = {g: ix for g, ix in state_groups(scn).items()}

    def floors(b: np.ndarray) -> dict:
        return {g: float(np.mean(np.sqrt(np.mean(np.trace(b[:, :, ix][:, :, :, ix], axis1=2, axis2=3), axis=1))))
                for g, ix in groups.items()}

    alone = [floors(scenario_bound(scn, [i])) if np.asarray(scn.present)[..., i].any() else None
             for i in range(scn.nodes)]
    return {"network_sqrt_bound": floors(bound), "node_alone_sqrt_bound": alone}


def run(args: argparse.Namespace) -> int:
    if args.list_filters:
        print(list_components())
        return 0
    fusion = args.fusion
    params = {}
    if args.rounds is not None:
        if "rounds" not in {p.name for p in RULE_REGISTRY.params(fusion)}:
            raise ValueError(f"--rounds: fusion rule {fusion!r} has no 'rounds' parameter")
        params["rounds"] = args.rounds
    params = fusion_params_with(fusion, params, args.fusion_param)
    scn = load_or_simulate(args)
    if RULE_REGISTRY.validate(fusion, params).get("rounds") == "auto":
        params = resolve_rounds(fusion, {**params, "rounds": "auto"}, scn.weights, scn.adjacency)
    if params:
        fusion = make_rule(fusion, params)
    if args.save_scenario:
        save_scenario(args.save_scenario, scn)
        print(f"scenario written to {args.save_scenario}", file=sys.stderr)
    results, estimates, rows = {}, {}, []
    groups = None
    bound, bound_note = scenario_bound_or_why(scn)
    for name in args.filter:
        t0 = time.perf_counter()
        res = run_filter(scn, name, fusion=fusion, qbar=args.qbar, theta=args.theta)
        wall = time.perf_counter() - t0
        metrics = evaluate(scn, res, bound)
        node_steps = scn.runs * scn.steps * res.mean.shape[2]
        entry = {
            "rmse": {k: stats(v) | {"runs": v} for k, v in metrics["rmse"].items()},
            "anees": metrics["anees"],
            "anees_band": metrics["anees_band"],
            "eta": metrics["eta"],
            "diverged_runs": metrics["diverged_runs"],
            "diverged_at": metrics["diverged_at"],  # per run, the first diverged step (-1: never)
            "rmse_over_sqrt_bound": {k: stats(v) | {"runs": v} for k, v in metrics.get("bound_ratio", {}).items()},
            "wall_time_s": wall,
            "us_per_node_step": wall / node_steps * 1e6,
        }
        results[name] = entry
        groups = list(metrics["rmse"])
        estimates[f"{name}_mean"], estimates[f"{name}_cov"] = res.mean, res.cov
        band = entry["anees_band"]
        ratios = [fmt_stats(entry["rmse_over_sqrt_bound"][g], 2) for g in groups if g in entry["rmse_over_sqrt_bound"]]
        rows.append(
            [name]
            + [fmt_stats(entry["rmse"][g]) for g in groups]
            + ratios
            + [fmt_num(entry["anees"], 2), f"[{band[0]:.2f}, {band[1]:.2f}]" if band else "n/a",
               fmt_num(entry["eta"], 2), f"{entry['diverged_runs']}/{scn.runs}", f"{wall:.3f}"]
        )
    print(f"scenario {scn.name}: {scn.nodes} nodes, {scn.steps} steps, {scn.runs} run(s), fusion {args.fusion}"
          + (f", seed {scn.seed}" if not args.scenario_file else f", file {args.scenario_file}"))
    print("RMSE: final node-averaged running RMSE, median [IQR] over runs")
    assert groups is not None  # --filter names at least one filter
    bound_heads = [f"{g}/sqrt(B)" for g in groups if g != "tot"] if bound is not None else []
    print(table(["filter"] + [f"RMSE {g}" for g in groups] + bound_heads + ["ANEES", "95% band", "eta", "diverged",
                                                                           "time s"], rows))
    print(bound_note)
    if args.save_estimates:
        np.savez(args.save_estimates, **estimates)  # type: ignore[arg-type]  # numpy stub: **kwds vs allow_pickle: bool
    if args.json:
        write_json(args.json, {
            "command": "sim",
            "scenario": scn.name,
            "scenario_file": args.scenario_file,
            "nodes": scn.nodes, "steps": scn.steps, "runs": scn.runs, "seed": scn.seed,
            "fusion": args.fusion, "fusion_params": params, "qbar": args.qbar, "theta": args.theta,
            "bound": bound_summary(scn, bound),
            "filters": results,
        })
    return 0
