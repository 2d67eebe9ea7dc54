"""``zentrack sim`` on a many-target scenario: zentrack's multi-target trackers in process, on ``--runs``
simulated runs of the scenario, scored with GOSPA and its parts.

The methods are those of ``zentrack bench multitarget`` (:mod:`zentrack.study.multitarget_runs`) without Stone Soup's
comparator: each node **alone**, the **distributed** network (local trackers and one track-list exchange per step,
as the live trackers do; bearing sensors share their scans too; a mixed network's nodes each track by their own
sensor's kind) and a **centralized** tracker on every scan (bearing sensors: triangulating each scan's leftover
rays with the step's other scans; a mixed network's centre updates with each sensor's own model). The
scoring and the table are the bench's (:func:`zentrack.bench.multitarget.run_methods`). The single-target flags
that do not apply are refused in one line.
"""
from __future__ import annotations

import argparse

from zentrack.bench.multitarget import ORDER, aggregate, aims, print_table, run_methods, scenario_settings
from zentrack.common.progress import Progress
from zentrack.common.report import write_json
from zentrack.config.scenario_config import RunConfig, resize

#: what runs, whatever the sensors' kinds (a lone bearing node starts no track: its row shows what sharing scans
#: brings)
METHODS = ["alone", "distributed", "centralized"]
#: sim's flags for one target that a many-target scenario does not take
SINGLE_TARGET_FLAGS = ("scenario_file", "filter", "fusion", "rounds", "fusion_param", "qbar", "theta", "nodes",
                       "save_scenario", "save_estimates")


def run(args: argparse.Namespace, cfg: RunConfig) -> int:
    """Every method on ``--runs`` runs of the many-target scenario ``cfg`` (ValueError for a flag it does not take)."""
    given = [f"--{flag.replace('_', '-')}" for flag in SINGLE_TARGET_FLAGS if getattr(args, flag, None)]
    if given:
        raise ValueError(f"{cfg.source}: {', '.join(given)} do not apply to a many-target scenario (sim runs its "
                         "trackers as the scenario sets them; `zentrack run` takes --fusion)")
    resize(cfg, steps=args.steps)
    per_node, summary = scenario_settings(cfg)
    seed = cfg.seed if args.seed is None else args.seed
    per_run, cutoff = [], None
    with Progress(args.runs, "runs", label="sim") as bar:
        for r in range(args.runs):
            data = cfg.multitarget_data(seed + r)
            cutoff = data.gospa_cutoff
            per_run.append(run_methods(data, per_node, cfg, METHODS))
            bar.advance(1)
    result = {"scenario": cfg.spec.name, "nodes": cfg.spec.nodes, "steps": cfg.spec.steps, "ts": cfg.ts,
              "runs": args.runs, "seed": seed, "cutoff": cutoff, "order": ORDER, "alpha": 2.0,
              "settings": summary, "methods": aggregate(per_run, METHODS)}
    result["aims"] = aims(result["methods"])
    print_table(result)
    if args.json:
        write_json(args.json, {"command": "sim"} | result)
    return 0
