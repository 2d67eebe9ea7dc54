"""``zentrack bench viewer``: the viewer's CPU per step and memory over a long realtime run.

A realtime Experiment 2 cluster of N trackers runs for ``--minutes`` with the viewer recording to a file;
every ``--sample-s`` seconds the viewer process's resident memory (VmRSS) and CPU time are sampled from
/proc. Reported: CPU milliseconds per step, RSS at the end, and RSS growth over the last half of the run.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from zentrack.cluster.run.cluster import Cluster
from zentrack.common.argtypes import positive_float, positive_int
from zentrack.common.report import fmt_num, table, write_json
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.truth.simulation.simulate import simulate


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=positive_int, default=10, help="trackers (default 10)")
    p.add_argument("--minutes", type=positive_float, default=10.0, help="length of the run (default 10)")
    p.add_argument("--sample-s", type=positive_float, default=10.0, help="seconds between samples (default 10)")
    p.add_argument("--out", metavar="DIR", help="keep the run (recording included) here")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def proc_sample(pid: int) -> tuple[float, float]:
    """(RSS in MiB, CPU seconds) of a process."""
    rss = 0.0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024.0
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    import os

    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return rss, cpu


def run(args: argparse.Namespace) -> int:
    seconds = args.minutes * 60
    steps = int(seconds / 0.1)
    scn = simulate(builtin_spec("exp2", nodes=args.nodes, steps=steps), runs=1, seed=0)
    setup = RunSetup.from_data(scn, mode="realtime", source="bench viewer")
    samples = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp) / "run"
        with Cluster(setup, out, viewer=[]) as cluster:
            cluster.start()
            recorder = cluster.recorder
            assert recorder is not None  # start() opens it
            pid = cluster.procs["viewer"].pid
            t_start = time.time()
            next_sample = t_start
            truth = cluster.procs["truth"]
            while truth.poll() is None and time.time() - t_start < seconds + 120:
                recorder.drain(0.2)
                if time.time() >= next_sample and cluster.procs["viewer"].poll() is None:
                    rss_now, cpu_now = proc_sample(pid)
                    samples.append({"t": time.time() - t_start, "rss_mib": rss_now, "cpu_s": cpu_now})
                    print(f"  t={samples[-1]['t']:6.0f} s  viewer RSS {rss_now:7.1f} MiB  CPU {cpu_now:6.1f} s", file=sys.stderr, flush=True)
                    next_sample += args.sample_s
            cluster.wait(timeout=120)
            summary = cluster.write_results()
            size = (out / "recording.rrd").stat().st_size / 2**20
    t = np.array([s["t"] for s in samples])
    rss = np.array([s["rss_mib"] for s in samples])
    cpu = np.array([s["cpu_s"] for s in samples])
    half = t >= t[-1] / 2
    run_steps = summary["network"]["estimates"] / args.nodes
    cpu_per_step_ms = (cpu[-1] - cpu[half][0]) / max(1.0, (t[-1] - t[half][0]) / 0.1) * 1e3
    result = {
        "nodes": args.nodes, "minutes": args.minutes, "steps": run_steps,
        "cpu_ms_per_step": cpu_per_step_ms, "rss_end_mib": float(rss[-1]),
        "rss_growth_last_half_mib": float(rss[-1] - rss[half][0]), "rss_max_mib": float(rss.max()),
        "recording_mib": size, "samples": samples, "deadline_misses": summary["network"]["deadline_misses"],
    }
    print(table(["figure", "value"], [
        ["viewer CPU per step (ms)", fmt_num(cpu_per_step_ms, 2)],
        ["viewer RSS at the end (MiB)", fmt_num(rss[-1], 1)],
        [f"RSS growth over the last {args.minutes / 2:.1f} min (MiB)", fmt_num(result["rss_growth_last_half_mib"], 1)],
        ["recording size (MiB)", fmt_num(size, 1)],
        ["cluster deadline misses", str(result["deadline_misses"])],
    ]))
    if args.json:
        write_json(args.json, {"command": "bench viewer", **result})
    return 0
