"""``zentrack bench router-restart``: where the steps of a router restart go, over many restarts.

A realtime cluster on loopback whose every process is a client of a router (``zentrack run``'s router mode,
the soak's ``--router``): the router is killed (SIGKILL), restarted ``--down`` seconds later, and each restart
is timed in phases (:func:`restart_router`):

- ``listen_s``: from the restart command to the router's port accepting a connection (its own start-up: a
  Python process that imports zentrack and Zenoh);
- ``recorder_s``: from the restart to this process's session (the recorder, itself a client of the router)
  having a router again: Zenoh's re-dial of a lost ``--connect`` endpoint
  (:data:`~zentrack.transport.zconfig.CONNECT_RETRY`);
- per tracker (:func:`first_estimates`), the first estimate recorded after the restart: its step, how many
  steps after the restart command and after the router listened again, whether it was coasted (no measurement
  yet) or warm, and its publication time.

Steps are the run's: the wall time of step k is the truth's publication time of its measurement (the median
offset over the run), so "steps after the router listened" is the step of the first estimate less the
(fractional) step at which the port accepted. The worst tracker of each restart is its figure (every tracker
publishing again, the soak's ``publishing_after_fault``); the median and the worst over the restarts are
printed and, with ``--json``, written with every restart's phases. ``--cpu-hog N`` runs it beside N busy loops.
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from zentrack.cluster.run.cluster import Cluster
from zentrack.cluster.soak.command import soak_setup
from zentrack.cluster.soak.cpu_hog import CpuHog
from zentrack.cluster.soak.lean_start import prepare as prepare_lean_start
from zentrack.cluster.soak.priority import REALTIME_NICE, Prioritizer
from zentrack.common.argtypes import float_in, int_in
from zentrack.common.report import fmt_num, table, write_json
from zentrack.config import catalogue
from zentrack.config.run_setup import RunSetup


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--restarts", type=int_in(1, 1000, "restarts"), default=20, help="router restarts (default 20)")
    p.add_argument("--nodes", type=int_in(2, 64, "nodes"), default=8, help="trackers (default 8)")
    p.add_argument("--scenario", default="patrol", type=catalogue.scenario_arg,
                   help="the scenario (default patrol, the soak's)")
    p.add_argument("--down", type=float_in(0.1, 60.0, "seconds"), default=2.0,
                   help="seconds the router stays down (default 2, the soak's --restart-after)")
    p.add_argument("--between", type=float_in(1.0, 120.0, "seconds"), default=6.0,
                   help="seconds from a restart to the next kill (default 6)")
    p.add_argument("--realtime-nice", type=int_in(-20, 0, "nice"), default=REALTIME_NICE,
                   help=f"nice value of the trackers, the truth and the router, as the soak's (default {REALTIME_NICE}; 0: unchanged)")
    p.add_argument("--cpu-hog", type=int_in(0, 64, "busy loops"), default=0, help="busy loops beside the cluster (default 0)")
    p.add_argument("--out", metavar="DIR", help="the cluster's output folder (default: a temporary one)")
    p.add_argument("--json", metavar="PATH", help="write every restart's phases and the summary as JSON")


@dataclass
class Restart:
    """One router restart's wall times (``time.time()``): killed, restarted, listening again, the recorder's
    session linked to it again."""
    t_kill: float
    t_restart: float
    t_listen: float
    t_recorder: float


def listening(port: int) -> bool:
    """Whether something accepts a TCP connection on 127.0.0.1:``port``."""
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
        return True
    except OSError:
        return False


def has_router(cluster: Cluster) -> bool:
    """Whether the recorder's session is linked to a router."""
    assert cluster.session is not None
    return bool(list(cluster.session.info.routers_zid()))


def restart_router(cluster: Cluster, down_s: float, timeout: float = 30.0,
                   restarted: Callable[[], None] | None = None) -> Restart:
    """Kill the cluster's router, record for ``down_s``, start it again and record until its port accepts and the
    recorder's session has it again (each polled under ``timeout``); ``restarted`` is called right after the new
    router is spawned (e.g. to raise its priority)."""
    assert cluster.recorder is not None
    t_kill = time.time()
    cluster.signal_process("router", signal.SIGKILL)
    cluster.pump(down_s)
    t_restart = time.time()
    cluster.restart_process("router")
    if restarted is not None:
        restarted()
    end = t_restart + timeout
    while not listening(cluster.port):
        if time.time() > end:
            raise TimeoutError(f"the restarted router did not listen within {timeout:g} s")
        cluster.recorder.drain(0.01)
    t_listen = time.time()
    while not has_router(cluster):
        if time.time() > end:
            raise TimeoutError(f"the recorder did not reach the restarted router within {timeout:g} s")
        cluster.recorder.drain(0.01)
    return Restart(t_kill, t_restart, t_listen, time.time())


def step_clock(cluster: Cluster) -> Callable[[float], float]:
    """Wall time -> the run's (fractional) step: the truth publishes step k's measurement at the run's start plus
    k periods, so the offset is the median of ``t_meas_pub - k ts`` over every recorded estimate."""
    rec = cluster.recorder
    assert rec is not None
    ts = rec.scn.ts
    published = rec.times["t_meas_pub"]
    k = np.arange(published.shape[0])[:, None] * np.ones((1, published.shape[1]))
    offset = float(np.nanmedian(published - k * ts))
    return lambda t: (t - offset) / ts


def first_estimates(cluster: Cluster, restart: Restart, step_of: Callable[[float], float]) -> list[dict]:
    """Per tracker, the first estimate recorded from the restart's step on: its step, the steps from the restart
    command and from the router listening again, its flags, its publication time after the restart (None: none)."""
    rec = cluster.recorder
    assert rec is not None
    have = rec.have()
    s_restart, s_listen = step_of(restart.t_restart), step_of(restart.t_listen)
    out = []
    for i in range(have.shape[1]):
        k = next((k for k in range(int(np.ceil(s_restart)), have.shape[0]) if have[k, i]), None)
        entry: dict = {"node": i, "step": k}
        if k is not None:
            entry.update(from_restart=round(k - s_restart, 2), from_listen=round(k - s_listen, 2),
                         coasted=bool(rec.flags["coasted"][k, i]), warm=bool(rec.flags["warm"][k, i]),
                         t_pub_s=round(float(rec.times["t_pub"][k, i]) - restart.t_restart, 3))
        out.append(entry)
    return out


def judged(restart: Restart, trackers: list[dict]) -> dict:
    """One restart's phases (seconds after the restart command) and its worst tracker (None: one never came back)."""
    back = [t for t in trackers if t["step"] is not None]
    whole = len(back) == len(trackers)
    return {"listen_s": round(restart.t_listen - restart.t_restart, 3),
            "recorder_s": round(restart.t_recorder - restart.t_restart, 3),
            "down_s": round(restart.t_restart - restart.t_kill, 3),
            "worst_from_restart": max(t["from_restart"] for t in back) if whole else None,
            "worst_from_listen": max(t["from_listen"] for t in back) if whole else None,
            "trackers": trackers, "times": asdict(restart)}


def summary(restarts: list[dict]) -> dict:
    """Median and worst over the restarts of each figure (a restart some tracker never came back from: None)."""
    out: dict = {"restarts": len(restarts)}
    for key in ("worst_from_restart", "worst_from_listen", "listen_s", "recorder_s"):
        values = [r[key] for r in restarts]
        ok = [v for v in values if v is not None]
        out[key] = {"median": float(np.median(ok)) if ok else None, "max": max(ok) if len(ok) == len(values) else None}
    return out


def setup_for(args: argparse.Namespace) -> RunSetup:
    """The soak's run of ``--scenario`` with ``--nodes`` trackers, long enough for every restart."""
    duration = 30.0 + args.restarts * (args.down + args.between + 2.0)
    return soak_setup(argparse.Namespace(scenario=args.scenario, duration=duration, nodes=args.nodes, seed=0))


def measure(args: argparse.Namespace, out: Path) -> list[dict]:
    """Run the cluster, restart its router ``args.restarts`` times, and judge each restart."""
    priority = Prioritizer(args.realtime_nice)
    done: list[Restart] = []
    with Cluster(setup_for(args), out, router=True) as cluster:
        cluster.start()
        priority.apply({n: p.pid for n, p in cluster.procs.items()})
        rec = cluster.recorder
        assert rec is not None
        end = time.time() + 120
        while not rec.have().any():
            if time.time() > end:
                raise TimeoutError("no estimate within 120 s of the start")
            rec.drain(0.1)
        cluster.pump(5.0)
        for n in range(args.restarts):
            r = restart_router(cluster, args.down,
                               restarted=lambda: priority.apply({"router": cluster.procs["router"].pid}))
            cluster.pump(args.between)
            done.append(r)
            print(f"restart {n + 1}/{args.restarts}: listening {r.t_listen - r.t_restart:.2f} s, recorder linked "
                  f"{r.t_recorder - r.t_restart:.2f} s after the restart", flush=True)
        step_of = step_clock(cluster)
        results = [judged(r, first_estimates(cluster, r, step_of)) for r in done]
        cluster.stop()
    return results


def run(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="router-restart-"))
    prepare_lean_start()  # as the soak starts its processes
    load_before = os.getloadavg()
    with CpuHog(args.cpu_hog):
        results = measure(args, out)
    load_after = os.getloadavg()
    figures = summary(results)
    rows = [[str(i + 1), fmt_num(r["listen_s"], 2), fmt_num(r["recorder_s"], 2),
             fmt_num(r["worst_from_restart"], 1), fmt_num(r["worst_from_listen"], 1)] for i, r in enumerate(results)]
    print(table(["restart", "listening s", "recorder linked s", "steps: restart cmd", "steps: listening"], rows))
    for key, what in (("worst_from_restart", "from the restart command"), ("worst_from_listen", "from listening")):
        f = figures[key]
        print(f"every tracker publishing again, steps {what}: median {fmt_num(f['median'], 1)}, max {fmt_num(f['max'], 1)}")
    print(f"load average {load_before[0]:.1f} before, {load_after[0]:.1f} after")
    if args.json:
        write_json(args.json, {"args": {k: v for k, v in vars(args).items() if k != "func"}, "summary": figures,
                               "load_average": {"before": load_before, "after": load_after}, "restarts": results})
    return 0
