"""``zentrack bench startup``: how long each zentrack process takes from its start to ready, and what it holds idle.

Each process type is started alone, as ``zentrack run`` starts it, connected to this benchmark's Zenoh session,
``--repeat`` times (the types take turns):

- ``tracker``: ``zentrack node --id 0 --node-config FILE`` (node 0's slice, as the orchestrator writes it);
  ready when its liveliness token ``zentrack/<run>/alive/0`` reaches this session: its session is open, its
  token declared, and it waits for ``ctl/start``;
- ``truth``: ``zentrack truth --scenario-file FILE --wait-for recorder``: ``alive/truth`` (it waits for its
  trackers);
- ``recorder``: ``zentrack record --scenario-file FILE --out DIR``: ``alive/recorder``;
- ``viewer``: ``zentrack viewer --scenario-file FILE --save FILE.rrd``: ``alive/viewer``;
- ``router``: ``zentrack router --listen ENDPOINT``: its log line ``router <zid>: ...`` (a router declares no
  token; the line follows the open that makes it listen).

Start-to-ready is the wall time from spawning the interpreter to that token (or line); then, ``--settle``
seconds later (idle: ready and waiting), the resident memory (VmRSS), the number of threads and the CPU time
used so far are read from ``/proc/<pid>``, and the process is stopped with SIGTERM. Median, min and max per type
are printed; ``--json`` writes every sample. The tracker's bare import (``import zentrack.cli.node_command``, the
``zentrack node`` command with :mod:`zentrack.node.process`, in a fresh interpreter) is timed too.

``--python`` measures another installation's processes (``PYTHON -m zentrack ...``, e.g. an older checkout's
virtual environment): the scenario file and node slice are written by that interpreter, so the figures before
and after a change come from the same command. ``--env KEY=VALUE`` sets a variable for the processes (e.g.
``ZENOH_RUNTIME``).

Measured on the 2-core machine (load about 1), ``zentrack bench startup --repeat 5 [--python OLD/.venv/bin/python]``,
before (commit a8f3f0c) and after the lean tracker, alternately, two invocations each; median [min, max] of the
first invocation, the second's median in parentheses:

=========  ===============================  ===============================  =====================================
process    start to ready s, before         after                            idle RSS MB, before -> after
=========  ===============================  ===============================  =====================================
tracker    0.735 [0.700, 0.753] (0.762)     0.347 [0.328, 0.352] (0.425)     113.5 (113.1) -> 71.8 (71.6)
truth      0.731 [0.703, 0.758] (0.768)     0.181 [0.169, 0.689] (0.232)     112.6 (112.5) -> 46.3 (46.3)
recorder   0.714 [0.672, 0.730] (0.755)     0.761 [0.745, 0.774] (0.861)     113.0 (112.9) -> 112.9 (112.9)
viewer     1.077 [1.027, 1.177] (1.082)     0.977 [0.937, 1.085] (1.064)     184.2 (184.0) -> 182.7 (182.7)
router     0.608 [0.606, 0.611] (0.610)     0.607 [0.604, 0.611] (0.658)     41.5 (41.5) -> 40.3 (40.3)
=========  ===============================  ===============================  =====================================

The tracker's bare import went from 0.752 s (0.755) to 0.279 s (0.375). Of its 71.8 MB, about 21 MB are
``scipy.linalg`` and ``scipy.special`` (with SciPy's array-API layer), which ``zentrack.node.process`` loads
before the tracker is ready because its first step needs them (the wire codec's positive-definiteness check,
the gate's chi-square quantile); without them the tracker is ready in 0.179 s [0.167, 0.182] at 50.5 MB.
``ZENOH_RUNTIME`` handing the rx/acc/net pools to the app pool cuts a tracker's threads from 10 to 5-7 but
not its memory (51.3 MB either way). The router's 0.6 s is Zenoh's own open in router mode (0.13-0.2 s of CPU).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import float_in, int_in
from zentrack.common.ports import free_port
from zentrack.common.procs import process_status, signal_group
from zentrack.common.report import fmt_num, table, write_json
from zentrack.config import catalogue
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import loopback_config, open_zenoh

KINDS = ("tracker", "truth", "recorder", "viewer", "router")
#: the issue's targets for an idle tracker
TARGETS = {"tracker": {"rss_mb": 60.0, "start_s": 0.4}}

#: run by the measured interpreter: the scenario file and node 0's slice, as `zentrack run` writes them
PREPARE = """
import argparse, sys
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.config.scenario_file import save_scenario
p = argparse.ArgumentParser()
add_scenario_arguments(p)
out = sys.argv[1]
setup = resolve_setup(p.parse_args(sys.argv[2:]))
save_scenario(out + "/scenario.npz", setup.scenario)
setup.node_config(0).save(out + "/node-0.json")
"""
#: the `zentrack node` command's module with the tracker's (an installation older than zentrack.cli.node_command:
#: zentrack.node.process, which then held the command line)
IMPORT_TIME = ("import time; t = time.perf_counter()\ntry:\n    import zentrack.cli.node_command\n"
               "except ModuleNotFoundError:\n    import zentrack.node.process\nprint(time.perf_counter() - t)")
ROUTER_READY = re.compile(r"zentrack\.router INFO router \S+: ")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeat", type=int_in(1, 100, "repeat"), default=5, help="starts per process type (default 5)")
    p.add_argument("--kinds", default=",".join(KINDS), metavar="LIST",
                   help=f"comma-separated process types (default {','.join(KINDS)})")
    p.add_argument("--python", metavar="PATH", default=sys.executable,
                   help="the interpreter whose zentrack is measured (default: this one)")
    p.add_argument("--scenario", default="exp2", type=catalogue.scenario_arg, help="the scenario the processes load (default exp2)")
    p.add_argument("--settle", type=float_in(0.0, 60.0, "seconds"), default=1.0,
                   help="seconds between ready and reading the idle memory (default 1)")
    p.add_argument("--timeout", type=float_in(1.0, 600.0, "seconds"), default=60.0,
                   help="give up on a process not ready after this many seconds (default 60)")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                   help="an environment variable for the measured processes (repeatable)")
    p.add_argument("--json", metavar="PATH", help="write every sample and the summary as JSON")


class Monitor:
    """This benchmark's Zenoh peer: the processes connect to it, and it notes when each liveliness token arrives."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.session = open_zenoh(loopback_config("peer", listen=[self.endpoint]), "the benchmark's session")
        self.seen: dict[str, float] = {}
        self.cond = threading.Condition()
        self.sub = self.session.liveliness().declare_subscriber("zentrack/*/alive/*", self._alive)

    def _alive(self, sample) -> None:
        now = time.perf_counter()
        key = str(sample.key_expr)
        with self.cond:
            self.seen.setdefault(key, now)
            self.cond.notify_all()

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


class Spawned:
    """A measured process: its stderr is read on a thread (kept, and searched for a ready line)."""

    def __init__(self, cmd: list[str], env: dict[str, str], ready_line: re.Pattern | None = None) -> None:
        self.lines: list[str] = []
        self.ready_at: float | None = None
        self.ready_line = ready_line
        self.event = threading.Event()
        self.t_spawn = time.perf_counter()
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     env=env, start_new_session=True)
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for raw in self.proc.stderr:
            line = raw.decode(errors="replace").rstrip()
            if self.ready_line is not None and self.ready_at is None and self.ready_line.search(line):
                self.ready_at = time.perf_counter()
                self.event.set()
            self.lines.append(line)
        self.event.set()  # the process closed its stderr: it is gone

    def stop(self) -> None:
        signal_group(self.proc, signal.SIGTERM)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            signal_group(self.proc, signal.SIGKILL)
            self.proc.wait(timeout=10)
        self.reader.join(timeout=5)

    def tail(self) -> str:
        return "\n".join(self.lines[-15:])


def command(kind: str, python: str, work: Path, endpoint: str, run: str) -> tuple[list[str], str | None]:
    """The command line of one ``kind`` process (as the orchestrator starts it) and the liveliness token that
    says it is ready (None: the router, ready by its log line)."""
    zentrack = [python, "-m", "zentrack"]
    net = ["--run", run, "--connect", endpoint]
    scenario = ["--scenario-file", str(work / "scenario.npz")]
    if kind == "tracker":
        return [*zentrack, "node", "--id", "0", "--node-config", str(work / "node-0.json"), "--out", str(work / "out"),
                "--lease-ms", "1000", *net], "0"
    if kind == "truth":
        return [*zentrack, "truth", *scenario, *net, "--wait-for", "recorder", "--wait-timeout", "3600"], "truth"
    if kind == "recorder":
        return [*zentrack, "record", *scenario, *net, "--out", str(work / "recorder"), "--timeout", "3600"], "recorder"
    if kind == "viewer":
        return [*zentrack, "viewer", *scenario, *net, "--save", str(work / "viewer.rrd")], "viewer"
    if kind == "router":
        return [*zentrack, "router", "--listen", f"tcp/127.0.0.1:{free_port()}"], None
    raise ValueError(f"unknown process type {kind!r}; choose from {', '.join(KINDS)}")


def measure_one(kind: str, python: str, work: Path, monitor: Monitor, env: dict[str, str], settle: float,
                timeout: float, serial: int) -> dict:
    """One start of ``kind``: seconds to ready, then (after ``settle``) its idle memory, threads and CPU time."""
    run = f"startup{os.getpid()}x{serial}"
    cmd, token = command(kind, python, work, monitor.endpoint, run)
    key = Keys(run).alive(token) if token is not None else None
    spawned = Spawned(cmd, env, None if key is not None else ROUTER_READY)
    try:
        end = time.perf_counter() + timeout
        ready = wait_ready(spawned, monitor, key, end)
        if ready is None:
            state = "exited" if spawned.proc.poll() is not None else f"not ready after {timeout:g} s"
            raise RuntimeError(f"{kind}: {state}: {' '.join(cmd)}\n{spawned.tail()}")
        time.sleep(settle)
        if spawned.proc.poll() is not None:
            raise RuntimeError(f"{kind}: exited while idle: {' '.join(cmd)}\n{spawned.tail()}")
        status = process_status(spawned.proc.pid)
    finally:
        spawned.stop()
    return {"start_s": ready - spawned.t_spawn, **status}


def wait_ready(spawned: Spawned, monitor: Monitor, key: str | None, end: float) -> float | None:
    """When the process became ready (perf_counter), or None if it exited or ``end`` passed first."""
    if key is None:
        while spawned.ready_at is None and spawned.proc.poll() is None and time.perf_counter() < end:
            spawned.event.wait(0.05)
        return spawned.ready_at
    with monitor.cond:
        while key not in monitor.seen and spawned.proc.poll() is None and time.perf_counter() < end:
            monitor.cond.wait(0.05)
        return monitor.seen.get(key)


def import_time(python: str, env: dict[str, str]) -> float:
    """Seconds a fresh interpreter takes to import the tracker's module."""
    out = subprocess.run([python, "-c", IMPORT_TIME], capture_output=True, text=True, env=env, timeout=120, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def prepare(python: str, work: Path, scenario: str, env: dict[str, str]) -> None:
    """The scenario file and node 0's slice, written by the measured installation itself."""
    proc = subprocess.run([python, "-c", PREPARE, str(work), "--scenario", scenario, "--steps", "100"],
                          capture_output=True, text=True, env=env, timeout=300)
    if proc.returncode != 0:
        raise RuntimeError(f"{python}: cannot write the scenario and node slice:\n{proc.stderr[-2000:]}")


def summarise(values: list[float]) -> dict:
    v = np.asarray(values, dtype=float)
    return {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()), "values": [float(x) for x in v]}


def kinds_list(text: str) -> list[str]:
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise ValueError(f"--kinds: unknown process type(s) {bad or text!r}; choose from {', '.join(KINDS)}")
    return kinds


def environment(pairs: list[str]) -> dict[str, str]:
    env = dict(os.environ)
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--env: expected KEY=VALUE, got {pair!r}")
        env[key] = value
    return env


def run(args: argparse.Namespace) -> int:
    kinds = kinds_list(args.kinds)
    python = shutil.which(args.python) or args.python
    if not os.access(python, os.X_OK):
        raise ValueError(f"--python {args.python}: not an executable")
    env = environment(args.env)
    samples: dict[str, list[dict]] = {k: [] for k in kinds}
    imports: list[float] = []
    load_before = os.getloadavg()
    work = Path(tempfile.mkdtemp(prefix="zentrack-startup-"))
    monitor = Monitor()
    try:
        print(f"preparing the scenario and node slice with {python} ...", file=sys.stderr, flush=True)
        prepare(python, work, args.scenario, env)
        serial = 0
        for rep in range(args.repeat):
            if "tracker" in kinds:
                imports.append(import_time(python, env))
            for kind in kinds:
                serial += 1
                sample = measure_one(kind, python, work, monitor, env, args.settle, args.timeout, serial)
                samples[kind].append(sample)
                print(f"  {rep + 1}/{args.repeat} {kind}: ready in {sample['start_s']:.3f} s, "
                      f"{sample['rss_mb']:.1f} MB, {sample['threads']} threads", file=sys.stderr, flush=True)
    finally:
        monitor.close()
        shutil.rmtree(work, ignore_errors=True)
    results = {kind: {field: summarise([s[field] for s in samples[kind]])
                      for field in ("start_s", "rss_mb", "threads", "cpu_s", "hwm_mb")} for kind in kinds}
    print_table(results, imports)
    if args.json:
        write_json(args.json, {"command": "bench startup", "python": python, "repeat": args.repeat,
                               "settle_s": args.settle, "scenario": args.scenario, "env": args.env,
                               "loadavg_before": list(load_before), "loadavg_after": list(os.getloadavg()),
                               "tracker_import_s": summarise(imports) if imports else None,
                               "targets": TARGETS, "results": results, "samples": samples})
    return 0


def print_table(results: dict, imports: list[float]) -> None:
    def cell(st: dict, digits: int, scale: Callable[[float], float] = float) -> str:
        return f"{fmt_num(scale(st['median']), digits)} [{fmt_num(scale(st['min']), digits)}, " \
               f"{fmt_num(scale(st['max']), digits)}]"

    rows = [[kind, cell(r["start_s"], 3), cell(r["rss_mb"], 1), cell(r["threads"], 0), cell(r["cpu_s"], 2)]
            for kind, r in results.items()]
    print(table(["process", "start to ready s", "idle RSS MB", "threads", "CPU s"], rows))
    print("(median [min, max]; RSS = VmRSS once ready and idle; CPU = user + system time by then)")
    if imports:
        st = summarise(imports)
        print(f"tracker imports (import zentrack.cli.node_command): {cell(st, 3)} s")
    for kind, target in TARGETS.items():
        if kind in results:
            r = results[kind]
            verdict = ", ".join(f"{name} {fmt_num(r[name]['median'], 3)} {'<=' if r[name]['median'] <= limit else '>'} "
                                f"{limit:g}" for name, limit in target.items())
            print(f"target for an idle {kind}: {verdict}")
