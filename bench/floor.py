"""``zentrack bench floor``: the CPU a tracker process spends on its messaging alone, with no filtering maths:
the floor under issue 32's goal of 128 trackers on one 2-core host.

For each N in ``--sizes`` it starts, each as its own OS process (:mod:`~zentrack.bench.floor_node`), a Zenoh
router, a recorder, N *null trackers* (Zenoh clients of the router doing a tracker's messaging pattern: on each
164-byte measurement an 872-byte prior to both ring neighbours, their priors collected until a 50 ms deadline,
a 495-byte estimate) and a truth sending a measurement to every tracker at 10 Hz, for ``--duration`` seconds
after the truth starts. Over the steady state (:func:`~zentrack.bench.scale.steady_window`: 10 s after the start
to 5 s before the end) it measures:

- CPU milliseconds per step of every process (the time all its threads ran, to the nanosecond, from
  ``/proc/<pid>/task/*/schedstat``), per type: tracker mean and max, router, truth, recorder;
- the cores the bench's processes used, and the machine's *foreign* load (the cores busy by ``/proc/stat``
  minus the bench's), since the machine may be shared;
- the estimates the recorder received against N per step, those later than 100 ms after their measurement,
  and the latency p50 / p99 (measurement time to arrival at the recorder);
- each tracker's resident memory at the end of the window (:func:`~zentrack.bench.scale_probe.memory_mb`).

A real tracker costs this floor plus its maths; the floor times N plus the router says how many cores N
trackers need whatever the filter. ``--variant callback`` does the work in Zenoh's callbacks instead of a queue
to the main thread; ``--tracker-runtime min`` gives the trackers (never the router) one Zenoh thread doing all
the work (:data:`MIN_RUNTIME`).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from zentrack.bench.floor_node import PERIOD
from zentrack.bench.scale import cpu_per_step, cpu_seconds, process_type, steady_window
from zentrack.bench.scale_probe import memory_mb, memory_per_type
from zentrack.common.argtypes import float_in, int_in
from zentrack.common.ports import free_port
from zentrack.common.procs import die_with_parent, signal_group
from zentrack.common.report import fmt_num, table, write_json
from zentrack.transport.zruntime import RUNTIME_ENV

#: ``--tracker-runtime min``: Zenoh's runtimes of a tracker handed over to a single app thread (the router keeps
#: the project's: with this it forwarded nothing at N = 128)
MIN_RUNTIME = ("(app: (worker_threads: 1), acc: (handover: app), tx: (handover: app), rx: (handover: app), "
               "net: (handover: app))")
LATE_S = 0.1  # an estimate later than this after its measurement is late (the next measurement is due)
TCK = os.sysconf("SC_CLK_TCK")
_size = int_in(2, 512, "size")


def sizes(text: str) -> list[int]:
    """Comma-separated tracker counts, each from 2 to 512, ascending."""
    out = sorted({_size(t.strip()) for t in text.split(",") if t.strip()})
    if not out:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, got {text!r}")
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sizes", type=sizes, default=[16, 64, 128], metavar="N[,N...]",
                   help="tracker counts to run (default 16,64,128)")
    p.add_argument("--duration", type=float_in(6.0, 3600.0, "duration"), default=40.0,
                   help="seconds per size after the truth starts, 6 to 3600 (default 40)")
    p.add_argument("--variant", choices=["queue", "callback"], default="queue",
                   help="queue (default): callbacks enqueue, the main thread works, as zentrack's tracker; "
                        "callback: all the work in Zenoh's callbacks")
    p.add_argument("--tracker-runtime", choices=["default", "min"], default="default",
                   help="default: the project's ZENOH_RUNTIME; min: one Zenoh thread per tracker (trackers only)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def machine_busy_s() -> float:
    """CPU seconds the whole machine has been busy (all but idle and iowait, /proc/stat)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:9]]
    return (sum(v) - v[3] - v[4]) / TCK


class Floor:
    """The processes of one size: started by :meth:`start`, stopped (always) by :meth:`stop`."""

    def __init__(self, n: int, args: argparse.Namespace, folder: Path):
        self.n, self.args, self.folder = n, args, folder
        self.ready, self.port = folder / "ready", free_port()
        self.ready.mkdir()
        self.procs: dict[str, subprocess.Popen] = {}
        self.env = {k: v for k, v in os.environ.items() if k != RUNTIME_ENV}  # each child sets the project's
        self.tracker_env = dict(self.env, **({RUNTIME_ENV: MIN_RUNTIME} if args.tracker_runtime == "min" else {}))

    def spawn(self, name: str, role: str, *extra: str) -> None:
        cmd = [sys.executable, "-m", "zentrack.bench.floor_node", role, "--port", str(self.port),
               "--ready", str(self.ready), "--n", str(self.n), *extra]
        with open(self.folder / f"{name}.log", "w") as log:
            self.procs[name] = subprocess.Popen(
                cmd, env=self.tracker_env if role == "tracker" else self.env, stdin=subprocess.DEVNULL,
                stdout=log, stderr=subprocess.STDOUT, start_new_session=True, preexec_fn=die_with_parent)

    def check_alive(self) -> None:
        dead = [k for k, p in self.procs.items() if p.poll() is not None]
        if dead:
            log = (self.folder / f"{dead[0]}.log").read_text().strip().splitlines()
            raise RuntimeError(f"N = {self.n}: {', '.join(dead[:5])} exited early"
                               + (f" ({log[-1]})" if log else ""))

    def wait_ready(self, names: list[str], timeout: float) -> None:
        end = time.time() + timeout
        while not set(names) <= set(os.listdir(self.ready)):
            self.check_alive()
            if time.time() > end:
                missing = sorted(set(names) - set(os.listdir(self.ready)))
                raise RuntimeError(f"N = {self.n}: {len(missing)} processes not ready after {timeout:.0f} s "
                                   f"({', '.join(missing[:5])})")
            time.sleep(0.2)

    def sleep_until(self, t: float) -> None:
        while (rem := t - time.time()) > 0:
            self.check_alive()
            time.sleep(min(0.5, rem))

    def start(self) -> float:
        """Start every process, the truth last; the time of the truth's step 0 (its schedule's origin)."""
        self.spawn("router", "router")
        self.wait_ready(["router"], 30)
        self.spawn("recorder", "recorder", "--out", str(self.folder / "recorder.json"))
        for i in range(self.n):
            self.spawn(f"node-{i}", "tracker", "--index", str(i), "--variant", self.args.variant)
        self.wait_ready(["recorder"] + [f"node-{i}" for i in range(self.n)], 60 + self.n)
        self.spawn("truth", "truth")
        self.wait_ready(["truth"], 30)
        return float((self.ready / "truth").read_text().split()[1])

    def sample(self) -> dict:
        pids = {name: p.pid for name, p in self.procs.items()}
        cpu = {name: cpu_seconds(pid) for name, pid in pids.items()}
        return {"t": time.time(), "machine_s": machine_busy_s(), "cpu": {k: v for k, v in cpu.items() if v is not None}}

    def stop(self) -> None:
        """SIGTERM the truth, then the trackers, the recorder, the router (each group waited for up to 10 s),
        SIGKILL what is left."""
        order = [["truth"], [k for k in self.procs if k.startswith("node-")], ["recorder"], ["router"]]
        for names in order:
            group = [self.procs[k] for k in names if k in self.procs]
            for p in group:
                if p.poll() is None:
                    signal_group(p, 15)
            end = time.time() + 10
            for p in group:
                try:
                    p.wait(timeout=max(0.1, end - time.time()))
                except subprocess.TimeoutExpired:
                    signal_group(p, 9)
                    p.wait(timeout=5)


def estimates(rows: list, n: int, origin: float, t0: float, t1: float) -> dict:
    """Estimates of the steps measured within [t0, t1) (step k at ``origin + k * PERIOD``): expected (n per
    step), received (each tracker's step once), late (> 100 ms after the measurement), latency p50 and p99."""
    lo, hi = int(np.ceil((t0 - origin) / PERIOD)), int(np.ceil((t1 - origin) / PERIOD))
    inside = {(k, i): arrival - t for k, i, t, arrival, _ in rows if lo <= k < hi}
    lat = 1e3 * np.array(list(inside.values()))
    return {"steps": hi - lo, "expected": n * (hi - lo), "received": len(inside),
            "late_gt_100ms": int((lat > 1e3 * LATE_S).sum()),
            "latency_ms_p50": float(np.percentile(lat, 50)) if lat.size else None,
            "latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else None}


def measure(n: int, args: argparse.Namespace) -> dict:
    warmup, steady = steady_window(args.duration)
    with tempfile.TemporaryDirectory(prefix=f"zentrack-floor-{n}-") as tmp:
        floor = Floor(n, args, Path(tmp))
        t_launch = time.time()
        try:
            t_start = floor.start()
            startup = t_start - t_launch
            floor.sleep_until(t_start + warmup)
            s0 = floor.sample()
            floor.sleep_until(t_start + warmup + steady)
            s1 = floor.sample()
            memory = {k: m for k, p in floor.procs.items() if (m := memory_mb(p.pid)) is not None}
            load = os.getloadavg()[0]
            floor.sleep_until(t_start + args.duration)
        finally:
            floor.stop()
        rows = json.loads((Path(tmp) / "recorder.json").read_text())["rows"]
    win = s1["t"] - s0["t"]
    cpu = cpu_per_step(s0["cpu"], s1["cpu"], win / PERIOD)
    bench = sum(s1["cpu"][k] - s0["cpu"][k] for k in s0["cpu"].keys() & s1["cpu"].keys()) / win
    machine = (s1["machine_s"] - s0["machine_s"]) / win
    return {"n": n, "startup_s": startup, "window_s": win, "cpu_ms_per_step": cpu,
            "tracker_cores": cpu["tracker"]["total_ms"] / 1e3 / PERIOD, "bench_cores_busy": bench,
            "machine_cores_busy": machine, "foreign_cores_busy": machine - bench, "load_avg_1min": load,
            "estimates": estimates(rows, n, t_start, s0["t"], s1["t"]), "memory_mb": memory_per_type(memory, process_type)}


def print_results(results: list[dict]) -> None:
    def ms(r: dict, kind: str, key: str = "mean_ms") -> str:
        return fmt_num(r["cpu_ms_per_step"].get(kind, {}).get(key, float("nan")), 2)

    rows = []
    for r in results:
        e = r["estimates"]
        rows.append([r["n"], ms(r, "tracker"), ms(r, "tracker", "max_ms"), ms(r, "router"), ms(r, "truth"),
                     ms(r, "recorder"), fmt_num(r["bench_cores_busy"], 2), fmt_num(r["foreign_cores_busy"], 2),
                     f"{e['received']}/{e['expected']}", e["late_gt_100ms"], fmt_num(e["latency_ms_p50"], 1),
                     fmt_num(e["latency_ms_p99"], 1), fmt_num(r["memory_mb"]["tracker"]["rss_mean_mb"], 1)])
    print(table(["N", "tracker ms/step", "tracker max", "router", "truth", "recorder", "bench cores",
                 "foreign cores", "received/expected", "late", "lat p50 ms", "lat p99 ms", "tracker RSS MB"], rows))
    print("(CPU: user + system ms per 100 ms step over the steady state, tracker = one null-tracker process; "
          "foreign cores: the machine's busy cores not used by the bench; late: > 100 ms after the measurement)")


def run(args: argparse.Namespace) -> int:
    results, failed = [], []
    for n in args.sizes:
        print(f"N = {n}: {args.duration:.0f} s, variant {args.variant}, tracker runtime {args.tracker_runtime} ...",
              file=sys.stderr, flush=True)
        try:
            r = measure(n, args)
        except (RuntimeError, OSError, ValueError) as exc:  # a process died or never came up: say so, go on
            print(f"N = {n}: failed: {exc}", file=sys.stderr, flush=True)
            failed.append({"n": n, "error": str(exc)})
            continue
        results.append(r)
        print(f"N = {n}: tracker {fmt_num(r['cpu_ms_per_step']['tracker']['mean_ms'], 2)} ms/step, router "
              f"{fmt_num(r['cpu_ms_per_step']['router']['mean_ms'], 2)} ms/step, estimates "
              f"{r['estimates']['received']}/{r['estimates']['expected']}", file=sys.stderr, flush=True)
    if results:
        print_results(results)
    if args.json:
        write_json(args.json, {"command": "bench floor", "duration_s": args.duration, "period_s": PERIOD,
                               "variant": args.variant, "tracker_runtime": args.tracker_runtime,
                               "zenoh_runtime_trackers": MIN_RUNTIME if args.tracker_runtime == "min" else None,
                               "cpus": os.cpu_count(), "results": results, "failed": failed})
    return 1 if failed else 0
