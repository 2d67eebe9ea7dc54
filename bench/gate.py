"""``zentrack bench gate``: how often the chi-square gate refuses an honest neighbour.

Each configuration (scenario, local filter, fusion rule) runs as a lockstep cluster of processes with nobody
attacking it. The recorder's summary gives, per run, the neighbours' messages the nodes received and the ones
their gate refused (``gated``), and the rounds in which a node was outvoted by agreeing neighbours or lifted its
gate after a streak of refusals. Lockstep is deterministic and does not depend on the machine's load, so the
rate is the gate's own; the bound it is held to is ``--gate P`` (the false-rejection probability the gate is
built for, ``fusion/gate.py``). Rules whose messages are not estimates of the state are not gated, so their
messages count as received and never as refused: the table says which rule each row ran.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from zentrack.cluster.run.cluster import Cluster
from zentrack.common.argtypes import gate_probability, positive_int
from zentrack.common.report import table, write_json
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.fusion.defaults import DEFAULT_GATE

#: (scenario, filter or None for the scenario's, fusion rule or None for the scenario's)
CONFIGS = [("exp2", "teskf", None), ("exp2", "ekf", None), ("exp2", "ukf", None), ("exp2", "eskf", None),
           ("exp2", "teskf", "ci3"), ("exp1", None, None), ("exp2-point", None, None),
           ("fpf-clutter", None, None), ("dce-ici", None, None), ("seckf-constellation", None, None)]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steps", type=positive_int, default=300, help="steps of each run (default 300)")
    p.add_argument("--gate", type=gate_probability, default=DEFAULT_GATE, metavar="P",
                   help="the gate's false-rejection probability (default 0.001, the runtime's default)")
    p.add_argument("--only", metavar="N", type=positive_int, help="run only the first N configurations")
    p.add_argument("--out", metavar="DIR", help="keep each run's output here (default: a temporary folder)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def setup_for(scenario: str, filter_kind: str | None, fusion: str | None, steps: int, gate: float):
    """The lockstep run of one configuration, built as ``zentrack run`` builds it from its flags."""
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    flags = ["--scenario", scenario, "--timing", "lockstep", "--steps", str(steps), "--gate", repr(gate)]
    flags += (["--filter", filter_kind] if filter_kind else []) + (["--fusion", fusion] if fusion else [])
    return resolve_setup(p.parse_args(flags))


def measure(scenario: str, filter_kind: str | None, fusion: str | None, steps: int, gate: float, out: Path) -> dict:
    setup = setup_for(scenario, filter_kind, fusion, steps, gate)
    t0 = time.time()
    with Cluster(setup, out) as cluster:
        cluster.start()
        code = cluster.wait(timeout=60 + 2.0 * steps)
        summary = cluster.write_results()
    if code != 0:
        raise RuntimeError(f"{scenario}/{filter_kind or 'default'}/{fusion or 'default'}: the run exited {code}")
    net, nodes = summary["network"], summary["nodes"]
    received, gated = int(net["priors_received"]), int(net["gated"])
    return {"scenario": scenario, "filter": setup.filter_kind, "fusion": setup.fusion, "nodes": len(nodes),
            "steps": steps, "received": received, "gated": gated, "rate": gated / received if received else None,
            "outvoted": sum(int(n["messages"].get("outvoted", 0)) for n in nodes),
            "gate_lifted": sum(int(n["messages"].get("gate_lifted", 0)) for n in nodes),
            "conflicts": sum(int(n["messages"]["conflicts"]) for n in nodes),
            "wall_s": round(time.time() - t0, 1)}


def run(args: argparse.Namespace) -> int:
    configs = CONFIGS[: args.only] if args.only else CONFIGS
    with tempfile.TemporaryDirectory(prefix="zentrack-gate-") as tmp:
        base = Path(args.out) if args.out else Path(tmp)
        rows = []
        for n, (scenario, filter_kind, fusion) in enumerate(configs):
            rows.append(measure(scenario, filter_kind, fusion, args.steps, args.gate, base / f"run-{n}"))
            r = rows[-1]
            print(f"{r['scenario']} {r['filter']} {r['fusion']}: {r['gated']} of {r['received']} refused "
                  f"({r['wall_s']} s)", flush=True)
    received, gated = sum(r["received"] for r in rows), sum(r["gated"] for r in rows)
    print(table(["scenario", "filter", "fusion", "N", "received", "refused", "rate", "outvoted", "lifted"],
                [[r["scenario"], r["filter"], r["fusion"], r["nodes"], r["received"], r["gated"],
                  f"{r['rate']:.2e}" if r["rate"] is not None else "-", r["outvoted"], r["gate_lifted"]] for r in rows]))
    rate = gated / received if received else 0.0
    print(f"honest neighbours' messages refused: {gated} of {received} ({rate:.2e}; the gate is built for at most "
          f"{args.gate:g})")
    if args.json:
        write_json(args.json, {"gate": args.gate, "steps": args.steps, "received": received, "gated": gated,
                               "rate": rate, "configs": rows})
    return 0 if rate <= args.gate else 1
