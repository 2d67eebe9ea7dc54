"""``zentrack bench scale``: the largest N for which a realtime cluster keeps every deadline and loses nothing,
and how its cost grows with N and with node degree.

For each degree in ``--degree`` (default: the scenario's own ring, degree 2) and each N in ``--sizes``
(ascending) a realtime Experiment 2 cluster of N trackers runs for ``--duration`` seconds; the figures per run
are the deadline misses, the estimates the recorder received against those the nodes published and those the
run should have had (lost = published but never received), late priors, step latency p50/p99, the machine's
load, and over the steady state (from 10 s after the start to 5 s before the end, :func:`steady_window`; the
recorder is this process):

- the CPU each process type spends per step (user + system time of every thread, from ``/proc/<pid>/stat``);
- the memory of each process type, RSS and Pss (:mod:`~zentrack.bench.scale_probe`), sampled at its end;
- through a router, the bytes and TCP data segments per second on each router link, from the kernel's socket
  counters (:mod:`~zentrack.bench.scale_probe`), and the messages per second each tracker accepted (its own
  counters: measurements, neighbours' round messages, relays, late ones).

A size passes with zero misses, zero lost and every expected estimate; the answer is the largest size that
passes (the search stops at the first failure of a degree unless ``--all``). ``--plot`` draws the costs
against N and against degree (:mod:`~zentrack.bench.scale_plot`).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from zentrack.bench.scale_graph import check_degree, degrees, with_degree
from zentrack.bench.scale_probe import link_counters, link_rates, memory_mb, memory_per_type, router_sockets
from zentrack.cluster.run.cluster import Cluster
from zentrack.cluster.run.options import PEER_MESH_LIMIT, TOPOLOGIES, uses_router
from zentrack.common.argtypes import positive_float
from zentrack.common.deprecation import DeprecatedFlag
from zentrack.common.report import fmt_num, table, write_json
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
    p.add_argument("--degree", type=degrees, metavar="D[,D...]",
                   help="neighbours per node: run every size on a ring lattice of each degree D (default: the "
                        "scenario's ring, degree 2); odd D links the node opposite too, so it needs even sizes")
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds per size (default 60)")
    p.add_argument("--ts", type=positive_float, default=0.1, help="sample period (default 0.1 s)")
    p.add_argument("--topology", choices=TOPOLOGIES, default="auto",
                   help=f"as for `zentrack run`: peers, router, or auto (default): peers up to {PEER_MESH_LIMIT} "
                        "trackers, a router above")
    p.add_argument("--router", action="store_true", help="the same as --topology router")
    p.add_argument("--out", metavar="DIR", help="keep each run's folder here as DIR/n<N> (DIR/n<N>d<D> with "
                                                "--degree; summary.json, logs; default: a temporary folder)")
    p.add_argument("--all", action="store_true", help="try every size even after one fails")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")
    p.add_argument("--plot", metavar="PATH.png",
                   help="draw CPU, latency p99, memory and router bytes/s against N and degree (PNG and SVG)")
    p.add_argument("--figure", dest="plot", metavar="PATH.png", action=DeprecatedFlag, use="--plot")


#: seconds after the start and before the end left out of the steady state (start-up, shutdown), for runs of
#: 30 s or more; a shorter run leaves out a third and a sixth of its duration
WARMUP_S, TAIL_S = 10.0, 5.0


def steady_window(duration: float) -> tuple[float, float]:
    """(seconds from the start to the steady state, its length) of a run of ``duration`` seconds."""
    warmup, tail = min(WARMUP_S, duration / 3), min(TAIL_S, duration / 6)
    return warmup, duration - warmup - tail


def cpu_seconds(pid: int) -> float | None:
    """CPU seconds every thread of process ``pid`` has run so far, to the nanosecond (the first field of
    ``/proc/<pid>/task/<tid>/schedstat``; the 10 ms clock ticks of ``/proc/<pid>/stat`` are more than a quiet
    process, such as a null floor's truth, uses in a short window); None once it is gone."""
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    total = 0
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                total += int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            continue
    return total / 1e9


def process_type(name: str) -> str:
    return "tracker" if name.startswith("node") else name


def pids(cluster: Cluster) -> dict[str, int]:
    """Every live process of the run by name, the recorder (this process) included."""
    return {**{name: p.pid for name, p in cluster.procs.items() if p.poll() is None}, "recorder": os.getpid()}


def cpu_sample(cluster: Cluster) -> dict[str, float]:
    out = {name: cpu_seconds(pid) for name, pid in pids(cluster).items()}
    return {k: v for k, v in out.items() if v is not None}


def memory_sample(cluster: Cluster) -> dict[str, dict[str, float]]:
    out = {name: memory_mb(pid) for name, pid in pids(cluster).items()}
    return {k: v for k, v in out.items() if v is not None}


def cpu_per_step(before: dict[str, float], after: dict[str, float], steps: float) -> dict[str, dict[str, float]]:
    """Per process type: mean and max over its processes of CPU milliseconds per step, and the type's total."""
    per: dict[str, list[float]] = {}
    for name in before.keys() & after.keys():
        per.setdefault(process_type(name), []).append(1e3 * (after[name] - before[name]) / steps)
    return {kind: {"mean_ms": sum(v) / len(v), "max_ms": max(v), "total_ms": sum(v), "processes": len(v)}
            for kind, v in sorted(per.items())}


def link_sample(cluster: Cluster) -> dict[str, dict[str, int]] | None:
    """The router side's socket counters per peer process (None without a router or without ``ss``)."""
    if "router" not in cluster.procs:
        return None
    sockets = router_sockets(cluster.port)
    return None if sockets is None else link_counters(sockets, cluster.port, {v: k for k, v in pids(cluster).items()})


#: the counters of a tracker's accepted messages (node/counters.py)
ACCEPTED = ("meas_rx", "prior_rx", "relays_rx", "late")


def accepted_messages(cluster: Cluster) -> dict[str, tuple[int, int]]:
    """Per tracker: (steps, messages accepted) as its last estimate carrying counters told the recorder."""
    recorder = cluster.recorder
    assert recorder is not None  # opened by start()
    return {f"node-{i}": (int(c.get("steps", 0)), sum(int(c.get(k, 0)) for k in ACCEPTED))
            for i, c in enumerate(recorder.counters.last) if c}


def messages_per_s(before: dict[str, tuple[int, int]], after: dict[str, tuple[int, int]], ts: float) -> dict[str, float]:
    """Messages per second each tracker accepted between the samples (per step of its own, at 1/ts steps/s)."""
    return {name: (after[name][1] - before[name][1]) / (after[name][0] - before[name][0]) / ts
            for name in sorted(before.keys() & after.keys()) if after[name][0] > before[name][0]}


def measure(n: int, degree: int | None, args: argparse.Namespace) -> dict:
    steps = int(round(args.duration / args.ts))
    spec = builtin_spec("exp2", nodes=n, steps=steps)
    scn = simulate(spec if degree is None else with_degree(spec, degree), runs=1, seed=0, ts=args.ts)
    setup = RunSetup.from_data(scn, mode="realtime", source="bench scale")
    cpu: dict[str, dict[str, float]] = {}
    memory: dict[str, dict[str, float]] = {}
    links: dict | None = None
    router = uses_router(args.topology, args.router, n)
    with tempfile.TemporaryDirectory() as tmp:
        name = f"n{n}" if degree is None else f"n{n}d{degree}"
        folder = Path(args.out) / name if args.out else Path(tmp) / "run"
        with Cluster(setup, folder, router=router) as cluster:
            cluster.start()
            warmup, steady = steady_window(args.duration)
            if steady > 1.0:
                cluster.pump(warmup)
                # the window opens once every tracker has told its counters (a tracker that started late on a
                # loaded host has none yet, and no message rate), within half the steady state
                waited, wait_end = time.monotonic(), time.monotonic() + steady / 2
                while len(accepted_messages(cluster)) < n and time.monotonic() < wait_end:
                    cluster.pump(0.2)
                t0, before = time.monotonic(), cpu_sample(cluster)
                links0, msgs0 = link_sample(cluster), accepted_messages(cluster)
                cluster.pump(steady - (t0 - waited))
                t1, after = time.monotonic(), cpu_sample(cluster)
                links1, msgs1 = link_sample(cluster), accepted_messages(cluster)
                cpu = cpu_per_step(before, after, (t1 - t0) / args.ts)
                memory = memory_per_type(memory_sample(cluster), process_type)
                if links0 is not None and links1 is not None:
                    links = link_rates(links0, links1, t1 - t0, process_type)
                    for node, rate in messages_per_s(msgs0, msgs1, args.ts).items():
                        if node in links["links"]:
                            links["links"][node]["messages_accepted_per_s"] = rate
            cluster.wait(timeout=args.duration * 3 + 180)
            s = cluster.write_results()
    return figures(s, n, steps, router, cpu, memory=memory, links=links, degree=int(scn.adjacency.sum(1).max()))


def figures(summary: dict, n: int, steps: int, router: bool, cpu: dict, memory: dict | None = None,
            links: dict | None = None, degree: int | None = None) -> dict:
    """One run's figures from its ``summary.json`` (lost = published by the nodes and never recorded) and the
    steady-state samples: CPU, memory per process type, router links (None: no router, or no ``ss``)."""
    net = summary["network"]
    return {"nodes": n, "degree": degree, "topology": "router" if router else "peers",
            "deadline_misses": net["deadline_misses"],
            "late_priors": sum(x["messages"]["late"] for x in summary["nodes"]),
            "gaps": sum(len(x["gaps"]) for x in summary["nodes"]), "latency_ms": net["latency_ms"],
            "estimates": net["estimates"], "published_estimates": sum(x["estimates_published"] for x in summary["nodes"]),
            "lost_estimates": net["estimates_lost"], "expected_estimates": n * steps,
            "cpu_ms_per_step": cpu, "memory_mb": memory or {}, "router_links": links,
            "load_avg_1min": os.getloadavg()[0]}


def passes(r: dict) -> bool:
    return r["deadline_misses"] == 0 and r["lost_estimates"] == 0 and r["estimates"] == r["expected_estimates"]


def links_line(r: dict) -> str:
    """One line: the router links' total bytes/s and each process type's mean and max per link."""
    links = r["router_links"]
    if links is None:
        return f"N = {r['nodes']}, degree {r['degree']}: no router links measured ({r['topology']})"
    kinds = ", ".join(f"{k} {v['mean_bytes_per_s'] / 1e3:.1f} kB/s" + (f" (max {v['max_bytes_per_s'] / 1e3:.1f})"
                                                                        if v["links"] > 1 else "")
                      for k, v in links["per_type"].items())
    rates = [x["messages_accepted_per_s"] for x in links["links"].values() if "messages_accepted_per_s" in x]
    accepted = f"; a tracker accepts {sum(rates) / len(rates):.0f} messages/s" if rates else ""
    return (f"N = {r['nodes']}, degree {r['degree']}: router links {links['total_bytes_per_s'] / 1e6:.3f} MB/s in "
            f"all ({links['bytes_to_router_per_s'] / 1e6:.3f} to the router, {links['bytes_from_router_per_s'] / 1e6:.3f}"
            f" from it, {links['segments_per_s']:.0f} TCP segments/s); per link {kinds}{accepted}")


def print_results(results: list[dict]) -> None:
    kinds = sorted({k for r in results for k in r["cpu_ms_per_step"]})
    mem_kinds = sorted({k for r in results for k in r["memory_mb"]})

    def cell(d: dict, key: str, digits: int) -> str:
        return fmt_num(d[key], digits) if d else "-"

    print(table(["N", "degree", "topology", "misses", "lost", "estimates", "lat p50 ms", "lat p99 ms", "load"]
                + [f"{k} ms/step" for k in kinds] + [f"{k} RSS MB" for k in mem_kinds] + ["router MB/s"],
                [[r["nodes"], r["degree"], r["topology"], r["deadline_misses"], r["lost_estimates"],
                  f"{r['estimates']}/{r['expected_estimates']}",
                  fmt_num(r["latency_ms"].get("p50", float("nan")), 2), fmt_num(r["latency_ms"].get("p99", float("nan")), 2),
                  fmt_num(r["load_avg_1min"], 1)]
                 + [cell(r["cpu_ms_per_step"].get(k, {}), "mean_ms", 2) for k in kinds]
                 + [cell(r["memory_mb"].get(k, {}), "rss_mean_mb", 0) for k in mem_kinds]
                 + [fmt_num(r["router_links"]["total_bytes_per_s"] / 1e6, 3) if r["router_links"] else "-"]
                 for r in results]))
    print("(CPU: mean per process of the type, user + system over the steady state; RSS: mean per process at its "
          "end, Pss in the JSON; tracker = one tracker process)")
    for r in results:
        print(links_line(r))


def run(args: argparse.Namespace) -> int:
    sweep = args.degree or [None]
    for d in args.degree or []:
        for n in args.sizes:
            check_degree(n, d)  # every pair before anything starts: a ValueError, one line, exit 2
    results = []
    for d in sweep:
        for n in args.sizes:
            through = " through a router" if uses_router(args.topology, args.router, n) else " as peers"
            graph = "" if d is None else f", degree {d}"
            print(f"N = {n}{graph}: {args.duration:.0f} s realtime{through} ...", file=sys.stderr, flush=True)
            r = {**measure(n, d, args), "degree_requested": d}  # None: the scenario's ring (degree 1 for N = 2)
            r["passes"] = passes(r)
            results.append(r)
            tracker = r["cpu_ms_per_step"].get("tracker", {})
            print(f"N = {n}{graph}: misses {r['deadline_misses']}, lost {r['lost_estimates']}, estimates "
                  f"{r['estimates']}/{r['expected_estimates']}, latency p99 "
                  f"{fmt_num(r['latency_ms'].get('p99', float('nan')), 2)} ms, tracker CPU "
                  f"{fmt_num(tracker.get('mean_ms', float('nan')), 2)} ms/step", file=sys.stderr, flush=True)
            if not r["passes"] and not args.all:
                break
    by_degree: dict[int | None, int | None] = {d: None for d in sweep}  # the sweep's degrees, in order
    for r in results:
        if r["passes"]:
            by_degree[r["degree_requested"]] = max(by_degree[r["degree_requested"]] or 0, r["nodes"])
    best = by_degree[sweep[0]]
    print_results(results)
    print(f"\nlargest N with zero deadline misses and zero lost estimates over {args.duration:.0f} s at "
          f"{1 / args.ts:.0f} Hz: {best}" + ("" if len(by_degree) < 2 else " (degree " + ", degree ".join(
              f"{d}: {n}" for d, n in by_degree.items()) + ")"))
    if args.json:
        write_json(args.json, {"command": "bench scale", "duration_s": args.duration, "ts": args.ts,
                               "topology": args.topology, "router": args.router, "degrees": args.degree,
                               "results": results, "largest_passing_n": best,
                               "largest_passing_n_by_degree": {str(d): n for d, n in by_degree.items() if d is not None}})
    if args.plot:
        from zentrack.bench.scale_plot import plot

        for path in plot(results, args.plot):
            print(f"figure: {path}")
    return 0
