"""``zentrack bench scale``: the largest N for which a realtime cluster keeps every deadline.

For each N in ``--sizes`` (ascending) a realtime Experiment 2 cluster of N trackers on a ring runs for
``--duration`` seconds; the figure per N is the number of deadline misses, late priors, step latency p99 and
the machine's load. The answer is the largest N with zero misses (the search stops at the first failure
unless ``--all``).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from zentrack.cluster.orchestrator import Cluster
from zentrack.cluster.report import fmt_num, table, write_json
from zentrack.common.argtypes import positive_float
from zentrack.config.run_setup import RunSetup
from zentrack.fusion.scenario import builtin_spec, simulate


def sizes(text: str) -> list[int]:
    try:
        out = sorted({int(t) for t in text.split(",") if t.strip()})
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, got {text!r}") from None
    if not out or out[0] < 2:
        raise argparse.ArgumentTypeError("sizes must be at least 2")
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sizes", type=sizes, default=[10, 16, 24, 32, 48, 64], help="cluster sizes to try (default 10,...,64)")
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds per size (default 60)")
    p.add_argument("--ts", type=positive_float, default=0.1, help="sample period (default 0.1 s)")
    p.add_argument("--router", action="store_true", help="run the clusters through a Zenoh router")
    p.add_argument("--all", action="store_true", help="try every size even after one fails")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def run(args: argparse.Namespace) -> int:
    results = []
    for n in args.sizes:
        steps = int(round(args.duration / args.ts))
        scn = simulate(builtin_spec("exp2", nodes=n, steps=steps), runs=1, seed=0, ts=args.ts)
        setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "realtime", 0.5, "bench scale")
        print(f"N = {n}: {args.duration:.0f} s realtime ...", file=sys.stderr, flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            with Cluster(setup, Path(tmp) / "run", router=args.router) as cluster:
                cluster.start()
                cluster.wait(timeout=args.duration * 3 + 180)
                s = cluster.write_results()
        net = s["network"]
        late = sum(x["messages"]["late"] for x in s["nodes"])
        gaps = sum(len(x["gaps"]) for x in s["nodes"])
        r = {"nodes": n, "deadline_misses": net["deadline_misses"], "late_priors": late, "gaps": gaps,
             "latency_ms": net["latency_ms"], "estimates": net["estimates"], "expected_estimates": n * steps,
             "load_avg_1min": os.getloadavg()[0]}
        results.append(r)
        print(f"N = {n}: misses {r['deadline_misses']}, late {late}, latency p99 {fmt_num(net['latency_ms'].get('p99', float('nan')), 2)} ms",
              file=sys.stderr, flush=True)
        if r["deadline_misses"] and not args.all:
            break
    ok = [r["nodes"] for r in results if r["deadline_misses"] == 0 and r["estimates"] == r["expected_estimates"]]
    best = max(ok) if ok else None
    print(table(["N", "misses", "late priors", "estimates", "lat p50 ms", "lat p99 ms", "load"],
                [[r["nodes"], r["deadline_misses"], r["late_priors"], f"{r['estimates']}/{r['expected_estimates']}",
                  fmt_num(r["latency_ms"].get("p50", float("nan")), 2), fmt_num(r["latency_ms"].get("p99", float("nan")), 2),
                  fmt_num(r["load_avg_1min"], 1)] for r in results]))
    print(f"\nlargest N with zero deadline misses over {args.duration:.0f} s at {1 / args.ts:.0f} Hz: {best}")
    if args.json:
        write_json(args.json, {"command": "bench scale", "duration_s": args.duration, "ts": args.ts,
                               "router": args.router, "results": results, "largest_zero_miss_n": best})
    return 0
