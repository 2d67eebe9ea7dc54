"""``zentrack bench profile``: where a tracker's CPU goes, part by part, live and in process (issue 55, item 1).

**Live** (default): a realtime cluster of the scenario (default ``exp2``, N trackers, through a router with
``--router``) runs for ``--duration`` seconds. Over its steady state (:func:`~zentrack.bench.scale.steady_window`)
py-spy samples ``--profiled`` tracker processes (``--nonblocking``: a sample never pauses a tracker) and the
kernel's per-thread CPU of every tracker is read before and after. It prints, in milliseconds of CPU per step of
one tracker:

- per part of a step (:data:`~zentrack.bench.profile_parts.PARTS`: decoding, admission and counters, the local
  filter, fusion, encoding, publishing, receiving, timers and wake-ups, logging), from the Python samples of the
  profiled trackers: their share of the samples times the CPU of the threads they were taken on;
- per thread kind (the Python main thread, Zenoh's threads): the kernel's CPU, and how much of it py-spy saw
  running Python; the rest is Zenoh's native work (reading, writing, batching) and the interpreter's own;
- the whole tracker, beside the deadline misses and lost estimates of the run (a profile of a run that missed its
  deadlines is a profile of a loaded host, and says so).

Garbage collection has no frame of its own in Python 3.11: its time falls in whatever frame allocated.

**In process** (``--form step``): py-spy runs ``zentrack bench step`` (N trackers in lockstep in one process, no
Zenoh) and the same parts are counted over its samples: the maths and codecs without the messaging.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING

from zentrack.bench.profile_parts import (
    cpu_by_kind,
    cpu_delta,
    parse_raw,
    parts,
    samples_per_thread,
    thread_cpu,
    thread_kind,
)
from zentrack.bench.scale import steady_window
from zentrack.common.argtypes import float_in, int_in
from zentrack.common.report import fmt_num, table, write_json

if TYPE_CHECKING:
    from zentrack.config.run_setup import RunSetup


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--form", choices=("live", "step"), default="live",
                   help="live (default): tracker processes of a realtime cluster; step: `bench step` in one process")
    p.add_argument("--scenario", default="exp2", help="catalogue scenario (default exp2; exp2-relays has relays)")
    p.add_argument("--nodes", type=int_in(2, 256, "nodes"),
                   help="trackers (default: the scenario's; a scenario with relays keeps its own)")
    p.add_argument("--duration", type=float_in(6.0, 3600.0, "seconds"), default=40.0,
                   help="seconds of the live run (default 40); its steady state is sampled")
    p.add_argument("--profiled", type=int_in(1, 16, "trackers"), default=2,
                   help="tracker processes py-spy samples (default 2)")
    p.add_argument("--rate", type=int_in(10, 1000, "samples per second"), default=1000,
                   help="py-spy samples per second (default 1000: a tracker's main thread runs about 2 %% of the "
                        "time)")
    p.add_argument("--router", action="store_true", help="live: every tracker a client of one router")
    p.add_argument("--floor", action="store_true",
                   help="live: then as many null trackers (`bench floor`: the messaging alone, through a router) "
                        "for as long, and the ratio of a tracker's CPU per step to a null tracker's")
    p.add_argument("--out", metavar="DIR", help="keep py-spy's raw stacks here, one file per profiled process "
                                                "(flamegraph.pl or speedscope read them)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def py_spy() -> str:
    """The py-spy executable (beside this interpreter first); a clear error when it is not installed."""
    beside = Path(sys.executable).with_name("py-spy")
    found = str(beside) if beside.exists() else shutil.which("py-spy")
    if found is None:
        raise ValueError("bench profile needs py-spy: pip install 'zentrack[bench]' (or pip install py-spy)")
    return found


def record_args(pid: int, seconds: float, rate: int, output: Path) -> list[str]:
    return [py_spy(), "record", "--pid", str(pid), "--duration", str(max(1, round(seconds))), "--rate", str(rate),
            "--format", "raw", "--threads", "--full-filenames", "--nonblocking", "--gil", "--output", str(output)]


def live(args: argparse.Namespace) -> dict:
    from zentrack.cluster.run.cluster import Cluster
    from zentrack.config.run_setup import scenario_setup

    def setup_of(steps: int | None) -> RunSetup:
        """The scenario as `zentrack run --scenario S [--nodes N] [--steps K]` resolves it (one target or many)."""
        return scenario_setup(args.scenario, nodes=args.nodes, steps=steps)

    setup = setup_of(int(round(args.duration / setup_of(None).ts)))
    ts, n = setup.ts, setup.nodes
    warmup, steady = steady_window(args.duration)
    with tempfile.TemporaryDirectory() as tmp:
        with Cluster(setup, Path(tmp) / "run", router=args.router) as cluster:
            cluster.start()
            cluster.pump(warmup)
            trackers = {name: p.pid for name, p in cluster.procs.items() if name.startswith("node") and p.poll() is None}
            profiled = dict(sorted(trackers.items())[:args.profiled])
            raw = Path(args.out) if args.out else Path(tmp)
            raw.mkdir(parents=True, exist_ok=True)
            outputs = {name: raw / f"{name}.txt" for name in profiled}
            before = {name: thread_cpu(pid) for name, pid in trackers.items()}
            t0 = time.monotonic()
            spies = [subprocess.Popen(record_args(pid, steady, args.rate, outputs[name]), stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE, text=True) for name, pid in profiled.items()]
            cluster.pump(steady)
            after = {name: thread_cpu(pid) for name, pid in trackers.items()}
            t1 = time.monotonic()
            errors = []
            for spy in spies:
                try:
                    _, err = spy.communicate(timeout=30)
                except subprocess.TimeoutExpired:
                    spy.kill()
                    _, err = spy.communicate()
                if spy.returncode != 0:
                    errors.append(err.strip().splitlines()[-1] if err.strip() else f"exit {spy.returncode}")
            if errors:
                raise RuntimeError(f"py-spy failed: {errors[0]}")
            cluster.wait(timeout=args.duration * 3 + 180)
            summary = cluster.write_results()
        steps_in_window = (t1 - t0) / ts
        threads: defaultdict[str, float] = defaultdict(float)
        for name, pid in trackers.items():
            for kind, seconds in cpu_by_kind(pid, before[name], after[name]).items():
                threads[kind] += seconds
        per_tracker_ms = {k: 1e3 * v / steps_in_window / len(trackers) for k, v in threads.items()}
        # each tracker's whole CPU per step, the sampled ones beside the others (what sampling costs its process)
        own_ms = {name: 1e3 * sum(cpu_delta(before[name], after[name]).values()) / steps_in_window for name in trackers}
        sampled = [own_ms[name] for name in profiled]
        unsampled = [ms for name, ms in own_ms.items() if name not in profiled]
        part_ms: defaultdict[str, float] = defaultdict(float)
        seen_ms: defaultdict[str, float] = defaultdict(float)
        for name, pid in profiled.items():
            samples = parse_raw(outputs[name].read_text())
            cpu = cpu_delta(before[name], after[name])
            kind_of = {tid: thread_kind(pid, tid, n_) for tid, (n_, _) in after[name].items()}
            counts = samples_per_thread(samples)
            for tid, count in counts.items():  # py-spy's samples of a thread, as CPU seconds of that thread
                seen_ms[kind_of.get(tid, "gone")] += 1e3 * min(count / args.rate, cpu.get(tid, 0.0))
            for tid in counts:
                thread_samples = [s for s in samples if s.tid == tid]
                scale = cpu.get(tid, 0.0) / max(1, counts[tid])  # CPU seconds per sample of this thread
                for part, count in parts(thread_samples).items():
                    part_ms[part] += 1e3 * count * min(scale, 1.0 / args.rate)
        k = len(profiled) * steps_in_window
        net = summary["network"]
        return {"form": "live", "scenario": args.scenario, "nodes": n, "router": args.router,
                "duration_s": args.duration, "window_s": t1 - t0, "profiled": sorted(profiled), "rate": args.rate,
                "tracker_ms_per_step": sum(per_tracker_ms.values()),
                "threads_ms_per_step": dict(sorted(per_tracker_ms.items(), key=lambda kv: -kv[1])),
                "python_seen_ms_per_step": {kind: v / k for kind, v in seen_ms.items()},
                "parts_ms_per_step": {part: v / k for part, v in sorted(part_ms.items(), key=lambda kv: -kv[1])},
                "sampled_tracker_ms_per_step": sum(sampled) / len(sampled),
                "unsampled_tracker_ms_per_step": sum(unsampled) / len(unsampled) if unsampled else None,
                "deadline_misses": net["deadline_misses"],
                "lost_estimates": net.get("estimates_lost"),  # (None: a many-target run's lists are not counted so)
                **load_of(setup)}


def load_of(setup: RunSetup) -> dict:
    """A many-target run's load, to put each cost per target and per return: the targets present per step and
    the returns per scan of one sensor (its targets' detections and clutter), over the run; nothing for one target."""
    if setup.multitarget is None:
        return {}
    data = setup.multitarget_data
    return {"targets_per_step": float(data.alive.sum(axis=1).mean()), "returns_per_scan": float(data.counts.mean())}


#: seconds of the trackers' own work the in-process form samples (rounds of `bench step`'s network)
IN_PROCESS_S = 3.0


def in_process(args: argparse.Namespace) -> dict:
    """py-spy on this process while `bench step`'s lockstep network runs in it: the samples inside the trackers'
    schedules (a frame of ``node/schedule.py``), not the in-memory bus that carries their messages."""
    from zentrack.bench.step import LockstepNetwork
    from zentrack.fusion.defaults import DEFAULT_FILTER

    nodes, steps = args.nodes or 10, 300
    with tempfile.TemporaryDirectory() as tmp:
        output = Path(tmp) / "step.txt"
        spy = subprocess.Popen([*record_args(os.getpid(), 3600, args.rate, output)], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
        time.sleep(1.0)  # attached
        busy = 0.0
        rounds = 0
        while busy < IN_PROCESS_S:  # rounds of the lockstep network until its trackers ran this long
            net = LockstepNetwork(nodes, steps, DEFAULT_FILTER)
            for k in range(steps):
                net.step(k)
            busy += net.busy
            rounds += 1
        spy.send_signal(signal.SIGINT)  # py-spy writes what it has on an interrupt
        _, err = spy.communicate(timeout=30)
        if not output.exists():
            raise RuntimeError(f"py-spy failed: {(err.strip().splitlines() or ['?'])[-1]}")
        samples = [s for s in parse_raw(output.read_text())
                   if any(file.replace(os.sep, "/").endswith("node/schedule.py") for _, file in s.frames)]
    counted = parts(samples)
    total = sum(counted.values())
    return {"form": "step", "scenario": "exp2", "nodes": nodes, "steps": steps, "rate": args.rate, "samples": total,
            "rounds": rounds, "node_step_us": busy / (rounds * nodes * steps) * 1e6,
            "parts_share": {part: c / total for part, c in counted.most_common()}}


def beside_floor(r: dict, args: argparse.Namespace) -> dict:
    """``bench floor`` at the same N right after the live run: the null tracker's CPU per step and the ratio."""
    from zentrack.bench.floor import measure

    floor = measure(r["nodes"], argparse.Namespace(duration=args.duration, variant="queue", tracker_runtime="default"))
    null_ms = floor["cpu_ms_per_step"]["tracker"]["mean_ms"]
    return {"null_tracker_ms_per_step": null_ms, "over_floor": r["tracker_ms_per_step"] / null_ms}


def print_live(r: dict) -> None:
    total = r["tracker_ms_per_step"]
    print(f"{r['scenario']}, {r['nodes']} trackers{' through a router' if r['router'] else ' as peers'}, "
          f"{r['window_s']:.0f} s sampled: a tracker costs {total:.3f} ms of CPU per step "
          f"(deadline misses {r['deadline_misses']}, lost estimates {r['lost_estimates']})")
    print(table(["thread", "ms/step", "of which Python (py-spy)"],
                [[kind, fmt_num(ms, 3), fmt_num(r["python_seen_ms_per_step"].get(kind, 0.0), 3)]
                 for kind, ms in r["threads_ms_per_step"].items()]))
    print()
    print(table(["part (Python, every thread)", "ms/step", "share of the tracker"],
                [[part, fmt_num(ms, 3), f"{100 * ms / total:.1f} %"] for part, ms in r["parts_ms_per_step"].items()]))
    if r["unsampled_tracker_ms_per_step"]:
        print(f"the sampled trackers {r['sampled_tracker_ms_per_step']:.3f} ms/step, the others "
              f"{r['unsampled_tracker_ms_per_step']:.3f}: sampling costs its process "
              f"{r['sampled_tracker_ms_per_step'] / r['unsampled_tracker_ms_per_step']:.2f} times")
    if "over_floor" in r:
        print(f"a null tracker (bench floor, the same N, right after): {r['null_tracker_ms_per_step']:.3f} ms/step; "
              f"the tracker costs {r['over_floor']:.2f} times the floor")
    if "targets_per_step" in r:
        main = r["threads_ms_per_step"].get("main (Python)", 0.0)
        targets, returns = r["targets_per_step"], r["returns_per_scan"]
        print(f"{targets:.1f} targets per step, {returns:.1f} returns per scan: a tracker {1e3 * total / targets:.0f} us "
              f"per target and {1e3 * total / returns:.0f} us per return per step (its main thread {1e3 * main / targets:.0f} "
              f"and {1e3 * main / returns:.0f} us)")
    python = sum(r["parts_ms_per_step"].values())
    print(f"Python seen {python:.3f} ms/step; native and unsampled {total - python:.3f} ms/step "
          f"({100 * (total - python) / total:.1f} %): Zenoh's own work, the interpreter's wake-ups")


def print_step(r: dict) -> None:
    print(f"`bench step`'s lockstep network in process, {r['nodes']} trackers, {r['steps']} steps: "
          f"{r['rounds']} rounds, {r['node_step_us']:.0f} us per node-step (py-spy attached), {r['samples']} samples inside the trackers:")
    print(table(["part", "share"], [[part, f"{100 * s:.1f} %"] for part, s in r["parts_share"].items()]))


def run(args: argparse.Namespace) -> int:
    py_spy()  # before anything starts: a missing py-spy is one line, exit 2
    if args.form == "step":
        r = in_process(args)
        print_step(r)
    else:
        r = live(args)
        if args.floor:
            r.update(beside_floor(r, args))
        print_live(r)
        if r["deadline_misses"] or r["lost_estimates"]:
            print("the run missed deadlines or lost estimates: this is the profile of a loaded host", file=sys.stderr)
    if args.json:
        write_json(args.json, {"command": "bench profile", **r})
    return 0
