"""``zentrack bench scale``: the largest N for which a realtime cluster keeps every deadline and loses nothing.

For each N in ``--sizes`` (ascending) a realtime Experiment 2 cluster of N trackers on a ring runs for
``--duration`` seconds; the figures per N are the deadline misses, the estimates the recorder received
against those the nodes published and those the run should have had (lost = published but never received),
late priors, step latency p50/p99, the machine's load, and the CPU each process type spends per step (user +
system time of every thread, from ``/proc/<pid>/stat``, over the steady state: from 10 s after the start to
5 s before the end; the recorder is this process). A size passes with zero misses, zero lost and every
expected estimate; the answer is the largest size that passes (the search stops at the first failure unless
``--all``).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from zentrack.cluster.orchestrator import PEER_MESH_LIMIT, TOPOLOGIES, Cluster, uses_router
from zentrack.cluster.report import fmt_num, table, write_json
from zentrack.common.argtypes import positive_float
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.truth.simulation.simulate import simulate


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
    p.add_argument("--topology", choices=TOPOLOGIES, default="auto",
                   help=f"as for `zentrack run`: peers, router, or auto (default): peers up to {PEER_MESH_LIMIT} "
                        "trackers, a router above")
    p.add_argument("--router", action="store_true", help="the same as --topology router")
    p.add_argument("--out", metavar="DIR", help="keep each size's run folder here as DIR/n<N> (summary.json, logs; "
                                                "default: a temporary folder)")
    p.add_argument("--all", action="store_true", help="try every size even after one fails")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


#: seconds after the start and before the end left out of the CPU figures (start-up, shutdown)
WARMUP_S, TAIL_S = 10.0, 5.0


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of every thread of process ``pid`` so far (None once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime (fields 14, 15)


def process_type(name: str) -> str:
    return "tracker" if name.startswith("node") else name


def cpu_sample(cluster: Cluster) -> dict[str, float]:
    out = {name: cpu_seconds(p.pid) for name, p in cluster.procs.items() if p.poll() is None}
    out["recorder"] = cpu_seconds(os.getpid())
    return {k: v for k, v in out.items() if v is not None}


def cpu_per_step(before: dict[str, float], after: dict[str, float], steps: float) -> dict[str, dict[str, float]]:
    """Per process type: mean and max over its processes of CPU milliseconds per step, and the type's total."""
    per: dict[str, list[float]] = {}
    for name in before.keys() & after.keys():
        per.setdefault(process_type(name), []).append(1e3 * (after[name] - before[name]) / steps)
    return {kind: {"mean_ms": sum(v) / len(v), "max_ms": max(v), "total_ms": sum(v), "processes": len(v)}
            for kind, v in sorted(per.items())}


def measure(n: int, args: argparse.Namespace) -> dict:
    steps = int(round(args.duration / args.ts))
    scn = simulate(builtin_spec("exp2", nodes=n, steps=steps), runs=1, seed=0, ts=args.ts)
    setup = RunSetup.from_data(scn, mode="realtime", source="bench scale")
    cpu: dict[str, dict[str, float]] = {}
    router = uses_router(args.topology, args.router, n)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.out) / f"n{n}" if args.out else Path(tmp) / "run"
        with Cluster(setup, folder, router=router) as cluster:
            cluster.start()
            steady = args.duration - WARMUP_S - TAIL_S
            if steady > 1.0:
                cluster.pump(WARMUP_S)
                t0, before = time.monotonic(), cpu_sample(cluster)
                cluster.pump(steady)
                cpu = cpu_per_step(before, cpu_sample(cluster), (time.monotonic() - t0) / args.ts)
            cluster.wait(timeout=args.duration * 3 + 180)
            s = cluster.write_results()
    return figures(s, n, steps, router, cpu)


def figures(summary: dict, n: int, steps: int, router: bool, cpu: dict) -> dict:
    """One size's figures from its run's ``summary.json``: lost = published by the nodes and never recorded."""
    net = summary["network"]
    return {"nodes": n, "topology": "router" if router else "peers", "deadline_misses": net["deadline_misses"],
            "late_priors": sum(x["messages"]["late"] for x in summary["nodes"]),
            "gaps": sum(len(x["gaps"]) for x in summary["nodes"]), "latency_ms": net["latency_ms"],
            "estimates": net["estimates"], "published_estimates": sum(x["estimates_published"] for x in summary["nodes"]),
            "lost_estimates": net["estimates_lost"], "expected_estimates": n * steps,
            "cpu_ms_per_step": cpu, "load_avg_1min": os.getloadavg()[0]}


def passes(r: dict) -> bool:
    return r["deadline_misses"] == 0 and r["lost_estimates"] == 0 and r["estimates"] == r["expected_estimates"]


def run(args: argparse.Namespace) -> int:
    results = []
    for n in args.sizes:
        through = " through a router" if uses_router(args.topology, args.router, n) else " as peers"
        print(f"N = {n}: {args.duration:.0f} s realtime{through} ...",
              file=sys.stderr, flush=True)
        r = measure(n, args)
        r["passes"] = passes(r)
        results.append(r)
        tracker = r["cpu_ms_per_step"].get("tracker", {})
        print(f"N = {n}: misses {r['deadline_misses']}, lost {r['lost_estimates']}, estimates {r['estimates']}/"
              f"{r['expected_estimates']}, latency p99 {fmt_num(r['latency_ms'].get('p99', float('nan')), 2)} ms, "
              f"tracker CPU {fmt_num(tracker.get('mean_ms', float('nan')), 2)} ms/step", file=sys.stderr, flush=True)
        if not r["passes"] and not args.all:
            break
    ok = [r["nodes"] for r in results if r["passes"]]
    best = max(ok) if ok else None
    kinds = sorted({k for r in results for k in r["cpu_ms_per_step"]})
    print(table(["N", "topology", "misses", "lost", "estimates", "lat p50 ms", "lat p99 ms", "load"]
                + [f"{k} ms/step" for k in kinds],
                [[r["nodes"], r["topology"], r["deadline_misses"], r["lost_estimates"], f"{r['estimates']}/{r['expected_estimates']}",
                  fmt_num(r["latency_ms"].get("p50", float("nan")), 2), fmt_num(r["latency_ms"].get("p99", float("nan")), 2),
                  fmt_num(r["load_avg_1min"], 1)]
                 + [fmt_num(r["cpu_ms_per_step"][k]["mean_ms"], 2) if k in r["cpu_ms_per_step"] else "-" for k in kinds]
                 for r in results]))
    print("(CPU: mean per process of the type, user + system over the steady state; tracker = one tracker process)")
    print(f"\nlargest N with zero deadline misses and zero lost estimates over {args.duration:.0f} s at "
          f"{1 / args.ts:.0f} Hz: {best}")
    if args.json:
        write_json(args.json, {"command": "bench scale", "duration_s": args.duration, "ts": args.ts,
                               "topology": args.topology, "router": args.router, "results": results, "largest_passing_n": best})
    return 0
