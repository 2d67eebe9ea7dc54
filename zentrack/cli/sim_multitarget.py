"""``zentrack sim`` on a many-target scenario: zentrack's multi-target trackers in process, on ``--runs``
simulated runs of the scenario, scored with GOSPA and its parts.

The methods are those of ``zentrack bench multitarget`` (:mod:`zentrack.study.multitarget_runs`) without Stone Soup's
comparator: each node **alone**, the **distributed** network (local trackers and one track-list exchange per step,
as the live trackers do; bearing sensors share their scans too; a mixed network's nodes each track by their own
sensor's kind) and, for point sensors, a **centralized** tracker on every scan (a bearing-only centre would have to triangulate every sensor against every other: not built). The
scoring and the table are the bench's (:func:`zentrack.bench.multitarget.run_methods`). The single-target flags
that do not apply are refused in one line.
"""
from __future__ import annotations

import argparse

from zentrack.bench.multitarget import ORDER, aggregate, aims, print_table, run_methods, settings_summary
from zentrack.cluster.report import write_json
from zentrack.common.progress import Progress
from zentrack.config.scenario_config import RunConfig, resize
from zentrack.study.multitarget_runs import node_settings

#: what runs per sensor kind (a lone bearing node starts no track: its row shows what sharing scans brings)
METHODS = {"point": ["alone", "distributed", "centralized"], "bearing": ["alone", "distributed"],
           "mixed": ["alone", "distributed"]}  # a mixed network: one tracker of every kind's scans is not built
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
    settings = node_settings(cfg)
    kinds = list(dict.fromkeys(s.measurement for s in settings))
    methods = METHODS[kinds[0] if len(kinds) == 1 else "mixed"]
    per_node = settings[0] if len(kinds) == 1 else settings
    seed = cfg.seed if args.seed is None else args.seed
    per_run, cutoff = [], None
    with Progress(args.runs, "runs", label="sim") as bar:
        for r in range(args.runs):
            data = cfg.multitarget_data(seed + r)
            cutoff = data.gospa_cutoff
            per_run.append(run_methods(data, per_node, cfg, methods))
            bar.advance(1)
    summary = (settings_summary(settings[0]) if len(kinds) == 1 else  # a mixed network: each kind's
               {kind: settings_summary(next(s for s in settings if s.measurement == kind)) for kind in kinds})
    result = {"scenario": cfg.spec.name, "nodes": cfg.spec.nodes, "steps": cfg.spec.steps, "ts": cfg.ts,
              "runs": args.runs, "seed": seed, "cutoff": cutoff, "order": ORDER, "alpha": 2.0,
              "settings": summary, "methods": aggregate(per_run, methods)}
    result["aims"] = aims(result["methods"])
    print_table(result)
    if args.json:
        write_json(args.json, {"command": "sim"} | result)
    return 0
