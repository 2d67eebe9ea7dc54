"""``zentrack bench latency``: step latency of a realtime cluster beside the raw Zenoh round trip.

In one invocation: (1) a ping process and an echo process exchange 1.5 KB messages over Zenoh on loopback
(the raw round trip); (2) a realtime cluster of N trackers runs for ``--duration`` seconds; its step latency
(measurement published by truth -> posterior published by the node) and the nodes' own compute time per
step are collected. The figure of merit is step-latency p99 / (round-trip p99 + compute p99).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from zentrack.bench.hops import measure, percentiles
from zentrack.cluster.recording.estimates import Estimates
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.argtypes import positive_float, positive_int
from zentrack.common.report import fmt_num, table, write_json
from zentrack.common.run_summary import print_summary
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.defaults import DEFAULT_FILTER, DEFAULT_FUSION
from zentrack.truth.simulation.simulate import simulate


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=positive_int, default=10, help="trackers in the cluster (default 10)")
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds of realtime run (default 60)")
    p.add_argument("--ts", type=positive_float, default=0.1, help="sample period (default 0.1 s = 10 Hz)")
    p.add_argument("--pings", type=positive_int, default=2000, help="round trips to time (default 2000)")
    p.add_argument("--filter", default=DEFAULT_FILTER, help=f"local filter of the trackers (default {DEFAULT_FILTER})")
    p.add_argument("--fusion", default=DEFAULT_FUSION,
                   help=f"fusion rule by name (default {DEFAULT_FUSION}; e.g. ci3: three rounds per step)")
    p.add_argument("--out", metavar="DIR", help="keep the cluster's output here (default: a temporary folder)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def zenoh_round_trip(pings: int, size: int = 1500) -> dict:
    """Median/p99 round trip (ms) between this process and an echo process, two peers linked directly (the
    ``direct`` path of ``zentrack bench hops``)."""
    return measure("direct", pings, size)["rtt_ms"]


#: the share of the sample period a node has to publish its posterior (the scenario's deadline_frac)
DEADLINE_FRAC = 0.5


def cluster_latency(args: argparse.Namespace, out: Path) -> tuple[dict, dict]:
    steps = int(round(args.duration / args.ts))
    scn = simulate(builtin_spec("exp2", nodes=args.nodes, steps=steps), runs=1, seed=0, ts=args.ts)
    setup = RunSetup.from_data(scn, args.filter, mode="realtime", deadline_frac=DEADLINE_FRAC, source="bench latency",
                               fusion=args.fusion)
    setup.run_parameters()  # an unknown filter or rule is refused here, in one line
    with Cluster(setup, out) as cluster:
        cluster.start()
        cluster.wait(timeout=args.duration * 2 + 120)
        summary = cluster.write_results()
        rec = cluster.recorder
        assert rec is not None and isinstance(rec.part, Estimates)  # start() opens it; a single-target scenario
        lat = rec.latency[np.isfinite(rec.latency)] * 1e3
        upd = rec.update_us[np.isfinite(rec.update_us)] / 1e3
        since_start = publication_after_step_start(rec.times["t_meas_pub"], rec.times["t_pub"], args.ts) * 1e3
    return summary, {"step_latency_ms": percentiles(lat), "update_ms": percentiles(upd),
                     "published_after_step_start_ms": {**percentiles(since_start), "max": float(since_start.max()),
                                                       "deadline": DEADLINE_FRAC * args.ts * 1e3}}


def publication_after_step_start(t_meas_pub: np.ndarray, t_pub: np.ndarray, ts: float) -> np.ndarray:
    """How long after its step's nominal start ``t0 + k Ts`` each posterior was published (s), for every
    (step, node) that published one. ``t0`` is the median of truth's publication time minus ``k Ts``: truth
    publishes on schedule, so this is the schedule the deadline ``t0 + (k + frac) Ts`` is measured from."""
    k = np.arange(t_pub.shape[0])[:, None]
    t0 = float(np.nanmedian(t_meas_pub - k * ts))
    late = t_pub - (t0 + k * ts)
    return late[np.isfinite(late)]


def run(args: argparse.Namespace) -> int:
    print("raw Zenoh round trip (1.5 KB, two processes) ...", file=sys.stderr)
    rtt = zenoh_round_trip(args.pings)
    print(f"realtime cluster: {args.nodes} trackers, {args.duration:.0f} s at Ts = {args.ts} s ...", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp) / "cluster"
        summary, figs = cluster_latency(args, out)
    print_summary(summary)
    lat, upd = figs["step_latency_ms"], figs["update_ms"]
    budget = rtt["p99"] + upd["p99"]
    ratio = lat["p99"] / budget
    rows = [["raw Zenoh round trip", fmt_num(rtt["p50"], 3), fmt_num(rtt["p99"], 3)],
            ["node compute (update)", fmt_num(upd["p50"], 3), fmt_num(upd["p99"], 3)],
            ["step latency (meas -> est)", fmt_num(lat["p50"], 3), fmt_num(lat["p99"], 3)]]
    pub = figs["published_after_step_start_ms"]
    print()
    print(table(["ms", "p50", "p99"], rows))
    misses = summary["network"]["deadline_misses"]
    print(f"\nstep latency p99 / (round trip p99 + compute p99) = {ratio:.2f} (target <= 3); deadline misses {misses}")
    print(f"posterior published after its step's start: p99 {pub['p99']:.1f} ms, max {pub['max']:.1f} ms "
          f"(deadline {pub['deadline']:.0f} ms: headroom {pub['deadline'] - pub['max']:.1f} ms)")
    if args.json:
        write_json(args.json, {"command": "bench latency", "nodes": args.nodes, "duration_s": args.duration,
                               "ts": args.ts, "round_trip_ms": rtt, **figs, "ratio_p99": ratio,
                               "deadline_misses": misses, "fusion": args.fusion,
                               "steps_without_estimate": sum(n["steps_without_estimate"] for n in summary["nodes"]),
                               "summary_network": summary["network"]})
    return 0
