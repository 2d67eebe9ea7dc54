"""``zentrack sim``: run filters on a scenario in the batched in-process simulator and report metrics (a
many-target scenario: its multi-target trackers in process, ``zentrack/cli/sim_multitarget.py``)."""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from zentrack.common.argtypes import (
    check_node_steps,
    fusion_param,
    fusion_params_with,
    int_in,
    nodes_int,
    qbar_float,
    runs_int,
    seed_int,
    steps_int,
    theta_float,
)
from zentrack.common.deprecation import deprecated
from zentrack.common.limits import MAX_NODE_STEPS, MAX_NODES, MAX_RUNS, MAX_STEPS
from zentrack.common.report import fmt_num, fmt_stats, stats, table, wrapped, write_json
from zentrack.common.suggest import did_you_mean, names_chosen_by
from zentrack.common.vocabulary import combined_filter
from zentrack.config import catalogue
from zentrack.config.scenario_config import RunConfig, load_scenario_config, resize
from zentrack.config.scenario_file import load_scenario, save_scenario
from zentrack.fusion.defaults import CENTRALIZED, DEFAULT_FILTER, DEFAULT_FUSION, DEFAULT_QBAR, MAX_ROUNDS
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.rules import RULE_REGISTRY, make_rule
from zentrack.fusion.rules.consensus import resolve_rounds
from zentrack.study.pcrlb import scenario_bound
from zentrack.study.simulator import evaluate, run_filter
from zentrack.truth.simulation.scenario import ScenarioData, state_groups
from zentrack.truth.simulation.simulate import simulate


def filter_list(text: str) -> list[tuple[str, str | None, str | None]]:
    """``--filter``: comma-separated local filters, each ``(name, None, None)``; an old combined name
    (``dteskf``, ``cteskf``) is ``(name, "distributed" or CENTRALIZED, old name)``, with a deprecation notice."""
    out: list[tuple[str, str | None, str | None]] = []
    for name in [t.strip() for t in text.split(",") if t.strip()] or [text]:
        if name in FILTER_REGISTRY:
            out.append((name, None, None))
            continue
        combined = combined_filter(FILTER_REGISTRY, name)
        if combined is None:
            raise argparse.ArgumentTypeError(f"unknown filter {name!r}; choose from {', '.join(FILTER_REGISTRY.names())}"
                                             f" (`zentrack sim --list-filters`){did_you_mean(name, FILTER_REGISTRY.names())}")
        kind, arch = combined
        deprecated(f"--filter {name}", f"--filter {kind} --fusion " + (CENTRALIZED if arch == CENTRALIZED else "RULE"),
                   "zentrack sim")
        out.append((kind, arch, name))
    return out


def fusion_list(text: str) -> list[str]:
    """``--fusion``: comma-separated fusion rules, ``centralized`` among them if wanted."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n != CENTRALIZED and n not in RULE_REGISTRY]
    if bad or not names:
        hint = did_you_mean(bad[0], [*RULE_REGISTRY.names(), CENTRALIZED]) if bad else ""
        raise argparse.ArgumentTypeError(f"unknown fusion rule(s) {bad or text!r}; choose from "
                                         f"{', '.join(RULE_REGISTRY.names())}, or {CENTRALIZED}{hint}")
    return names


names_chosen_by(filter_list, FILTER_REGISTRY.names)
names_chosen_by(fusion_list, lambda: [*RULE_REGISTRY.names(), CENTRALIZED])


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", metavar="NAME|PATH", type=catalogue.scenario_arg, help=catalogue.help_text())
    p.add_argument("--scenario-file", metavar="PATH", help="replay a scenario .npz instead of simulating one")
    p.add_argument("--filter", type=filter_list, metavar="NAMES",
                   help="comma-separated local filters, each run with every --fusion rule (default: the scenario's "
                        f"[filter] kind, else {DEFAULT_FILTER}; `--list-filters`); sim's old combined names "
                        "d<filter> and c<filter> still work for one release")
    p.add_argument("--nodes", type=nodes_int, help=f"number of nodes, 1 to {MAX_NODES} (default: the scenario's, 10)")
    p.add_argument("--steps", type=steps_int, help=f"number of steps, 1 to {MAX_STEPS} (default: the scenario's)")
    p.add_argument("--runs", type=runs_int, default=1, help=f"Monte Carlo runs, 1 to {MAX_RUNS} (default 1); "
                   f"runs x steps x nodes at most {MAX_NODE_STEPS}")
    p.add_argument("--seed", type=seed_int, help="random seed (default: the scenario's, 0)")
    p.add_argument("--fusion", type=fusion_list, metavar="RULES",
                   help=f"comma-separated fusion rules, {CENTRALIZED} for one centre with every measurement (default: "
                        f"the scenario's [fusion] rule, else {DEFAULT_FUSION})")
    p.add_argument("--rounds", type=int_in(1, MAX_ROUNDS, "rounds"),
                   help="fusion rounds per step, for rules with a 'rounds' parameter (default: the rule's)")
    p.add_argument("--fusion-param", action="append", type=fusion_param, metavar="KEY=VALUE",
                   help="a parameter of the fusion rule, repeatable (e.g. share_scans=true for ci; omega=10 for hcmci)")
    p.add_argument("--list-filters", action="store_true",
                   help="print the registered local filters and fusion rules with their parameters, and exit")
    p.add_argument("--qbar", type=qbar_float,
                   help=f"injection bound qbar (default: the scenario's, else {DEFAULT_QBAR:g})")
    p.add_argument("--theta", type=theta_float, help="inflation theta (default: the scenario's, else trace balance)")
    p.add_argument("--json", metavar="PATH", help="write the results as JSON")
    p.add_argument("--save-scenario", metavar="PATH", help="write the simulated scenario to a .npz file")
    p.add_argument("--save-estimates", metavar="PATH",
                   help="write every node's posterior mean/cov per step to a .npz (keys <row>_mean, <row>_cov; a row "
                        "is <filter>+<rule>)")


def load_or_simulate(args: argparse.Namespace) -> tuple[ScenarioData, RunConfig | None]:
    """The scenario's runs, and its TOML configuration (None for a replayed ``--scenario-file``)."""
    if args.scenario_file:
        if args.scenario:
            raise ValueError("--scenario and --scenario-file: give one")
        if args.nodes or args.steps or args.runs != 1 or args.seed is not None:
            raise ValueError("--nodes/--steps/--runs/--seed come from the file when --scenario-file is given")
        return load_scenario(args.scenario_file), None
    cfg = resize(load_scenario_config(args.scenario or catalogue.DEFAULT_SCENARIO), args.nodes, args.steps)
    check_node_steps(args.runs, cfg.spec.steps, cfg.spec.nodes)
    seed = cfg.seed if args.seed is None else args.seed
    return simulate(cfg.spec, runs=args.runs, seed=seed, ts=cfg.ts), cfg


def combinations(args: argparse.Namespace, cfg: RunConfig | None) -> list[tuple[str, str, str]]:
    """``(row, filter, rule)`` of every filter with every ``--fusion`` rule (a row is named ``<filter>+<rule>``,
    or by the old combined name that asked for it)."""
    filters = args.filter or [(cfg.filter_kind if cfg else DEFAULT_FILTER, None, None)]
    rules = args.fusion or [cfg.fusion if cfg else DEFAULT_FUSION]
    out: list[tuple[str, str, str]] = []
    for kind, arch, old in filters:
        targets = [CENTRALIZED] if arch == CENTRALIZED else rules if arch is None else \
            [r for r in rules if r != CENTRALIZED]
        if not targets:
            raise ValueError(f"--filter {old}: a distributed filter needs a fusion rule besides {CENTRALIZED}")
        out += [(old if old and len(targets) == 1 else f"{kind}+{rule}", kind, rule) for rule in targets]
    rows = [row for row, _, _ in out]
    twice = sorted({row for row in rows if rows.count(row) > 1})
    if twice:
        raise ValueError(f"--filter/--fusion: {', '.join(twice)} asked for twice")
    return out


def rule_params(args: argparse.Namespace, cfg: RunConfig | None, rule: str, scn: ScenarioData) -> dict:
    """The parameters of fusion rule ``rule``: the scenario's (when it names that rule), then ``--rounds`` and
    ``--fusion-param``, with ``rounds = "auto"`` worked out on the scenario's graph."""
    params = dict(cfg.fusion_params) if cfg is not None and rule == cfg.fusion else {}
    if args.rounds is not None:
        if "rounds" not in {p.name for p in RULE_REGISTRY.params(rule)}:
            raise ValueError(f"--rounds: fusion rule {rule!r} has no 'rounds' parameter")
        params["rounds"] = args.rounds
    params = fusion_params_with(rule, params, args.fusion_param)
    if RULE_REGISTRY.validate(rule, params).get("rounds") == "auto":
        params = resolve_rounds(rule, {**params, "rounds": "auto"}, scn.weights, scn.adjacency)
    return params


def list_components() -> str:
    """The shared names: every command's ``--filter`` and ``--fusion`` and the TOML keys take the same ones."""
    lines = ["local filters (--filter <name> in sim, run, node, truth; TOML [filter] kind = <name>):"]
    lines += [f"  {line}" for line in FILTER_REGISTRY.describe()]
    lines += ["fusion rules (--fusion <name> in sim, run, node, truth; TOML [fusion] rule = <name>):"]
    lines += [f"  {line}" for line in RULE_REGISTRY.describe()]
    lines += [f"  {CENTRALIZED}: one centre with every node's measurements stacked (paper 0, Algorithm 1); zentrack "
              "sim only (a live run has a tracker per sensor); params: none"]
    lines += ["sim runs every --filter with every --fusion rule, one row each (<filter>+<rule>); its old combined "
              f"names still work for one release: d<filter> = --filter <filter> --fusion <rule>, c<filter> = "
              f"--filter <filter> --fusion {CENTRALIZED}"]
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
    if not args.scenario_file:
        many = load_scenario_config(args.scenario or catalogue.DEFAULT_SCENARIO, multitarget=True)
        if many.multitarget is not None:  # many targets: the multi-target trackers (zentrack/cli/sim_multitarget.py)
            from zentrack.cli import sim_multitarget

            return sim_multitarget.run(args, many)
    scn, cfg = load_or_simulate(args)
    if scn.nodes == 1:
        print("zentrack sim: warning: one node has no neighbours, so nothing is fused "
              "(a network needs --nodes 2 or more)", file=sys.stderr)
    combos = combinations(args, cfg)
    rules = list(dict.fromkeys(rule for _, _, rule in combos))
    if (args.rounds is not None or args.fusion_param) and all(rule == CENTRALIZED for rule in rules):
        raise ValueError(f"--rounds/--fusion-param: the {CENTRALIZED} filter has no fusion rule to take them")
    params = {rule: rule_params(args, cfg, rule, scn) for rule in rules if rule != CENTRALIZED}
    qbar = args.qbar if args.qbar is not None else cfg.qbar if cfg else DEFAULT_QBAR
    theta = args.theta if args.theta is not None else cfg.theta if cfg else None
    if args.save_scenario:
        save_scenario(args.save_scenario, scn)
        print(f"scenario written to {args.save_scenario}", file=sys.stderr)
    results, estimates, rows = {}, {}, []
    groups = None
    bound, bound_note = scenario_bound_or_why(scn)
    for row, kind, rule in combos:
        fusion = make_rule(rule, params[rule]) if params.get(rule) else rule
        filter_params = dict(cfg.filter_params) if cfg is not None and kind == cfg.filter_kind else {}
        t0 = time.perf_counter()
        res = run_filter(scn, kind, fusion=fusion, qbar=qbar, theta=theta, params=filter_params)
        wall = time.perf_counter() - t0
        metrics = evaluate(scn, res, bound)
        node_steps = scn.runs * scn.steps * res.mean.shape[2]
        entry = {
            "filter": kind,
            "fusion": rule,
            "fusion_params": params.get(rule, {}),
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
        results[row] = entry
        groups = list(metrics["rmse"])
        estimates[f"{row}_mean"], estimates[f"{row}_cov"] = res.mean, res.cov
        band = entry["anees_band"]
        ratios = [fmt_stats(entry["rmse_over_sqrt_bound"][g], 2) for g in groups if g in entry["rmse_over_sqrt_bound"]]
        rows.append(
            [row]
            + [fmt_stats(entry["rmse"][g]) for g in groups]
            + ratios
            + [fmt_num(entry["anees"], 2), f"[{band[0]:.2f}, {band[1]:.2f}]" if band else "n/a",
               fmt_num(entry["eta"], 2), f"{entry['diverged_runs']}/{scn.runs}", f"{wall:.3f}"]
        )
    print(f"scenario {scn.name}: {scn.nodes} nodes, {scn.steps} steps, {scn.runs} run(s), fusion {','.join(rules)}"
          + (f", seed {scn.seed}" if not args.scenario_file else f", file {args.scenario_file}"))
    print("RMSE: final node-averaged running RMSE, median [IQR] over runs")
    assert groups is not None  # at least one filter and one rule
    bound_heads = [f"{g}/sqrt(B)" for g in groups if g != "tot"] if bound is not None else []
    print(table(["filter"] + [f"RMSE {g}" for g in groups] + bound_heads + ["ANEES", "95% band", "eta", "diverged",
                                                                           "time s"], rows))
    print(wrapped(bound_note))
    if args.save_estimates:
        np.savez(args.save_estimates, **estimates)  # type: ignore[arg-type]  # numpy stub: **kwds vs allow_pickle: bool
    if args.json:
        write_json(args.json, {
            "command": "sim",
            "scenario": scn.name,
            "scenario_file": args.scenario_file,
            "nodes": scn.nodes, "steps": scn.steps, "runs": scn.runs, "seed": scn.seed,
            # the one rule and its parameters (every row's own are in its entry)
            "fusion": ",".join(rules), "fusion_params": params.get(rules[0], {}) if len(rules) == 1 else None,
            "qbar": qbar, "theta": theta,
            "bound": bound_summary(scn, bound),
            "filters": results,
        })
    return 0
