"""``zentrack soak``: a realtime cluster under a seeded schedule of faults, judged against a fault-free run.

Faults: SIGKILL of a tracker followed by a restart (``--kill-every``), a ``--fault-s`` long SIGSTOP freeze
(``--freeze-every``), a ``--fault-s`` long link cut (``--cut-every``; the cluster then runs in network
namespaces, one per service, see ``zentrack netns``), a truth stall (SIGSTOP of the truth process for a
seeded 0.5-3 s, ``--truth-stall-every``), a truth kill and restart (``--truth-kill-every``) and a router kill
and restart (``--router-every``; router mode: ``--router``, or namespaces, which always run a router). The
same scenario and seed then run without faults. ``--engine compose`` runs both as docker compose projects on
a Docker engine instead (faults become ``docker kill``/``start``, ``pause``/``unpause`` and ``network
disconnect``/``connect``; see ``zentrack.cluster.docker``), judged by the same criteria.
Outputs in ``--out``: ``report.json`` (figures and pass/fail per criterion), ``error.png`` (position error of
every node over time, faults marked), ``summary.json`` and ``recording.rrd`` of the faulty run,
``reference/`` for the fault-free run. Exit status 1 when a criterion fails.

Criteria: surviving trackers never crash or publish NaN; every tracker's position RMSE <= 1.25x its
fault-free RMSE; a restarted tracker is within 2x the network median error in <= 20 steps; after every
fault ends, every live tracker publishes estimates again within 20 steps; RSS of every
long-lived process grows < 10 % between minute 2 (or mid-run for short soaks) and the end; summary and
recording complete; nothing left running.

A loaded host: ``--cpu-hog N`` runs both runs beside N busy loops (``zentrack.cluster.cpu_hog``); the trackers,
the truth and the router run at ``--realtime-nice`` (``zentrack.cluster.priority``) and every process starts lean
(``zentrack.cluster.lean_start``), so that a restarted tracker gets the CPU to start (docs/networks.md).
"""
from __future__ import annotations

import argparse
import logging
import os
import shutil
import signal
import sys
import time
from pathlib import Path

import numpy as np
import zenoh

from zentrack.cluster.certs import make_certificates
from zentrack.cluster.compose import render
from zentrack.cluster.cpu_hog import MAX_HOGS, CpuHog
from zentrack.cluster.docker import ComposeBackend, check_image
from zentrack.cluster.lean_start import prepare as prepare_lean_start
from zentrack.cluster.netns import SUBNET, Harness
from zentrack.cluster.orchestrator import Cluster
from zentrack.cluster.priority import REALTIME_NICE, Prioritizer
from zentrack.cluster.recorder import Recorder
from zentrack.cluster.report import write_json
from zentrack.common.argtypes import float_in, int_in, nodes_int, off_or_float_in, seed_int
from zentrack.common.procs import processes_of_runs, setup_logging
from zentrack.config import catalogue
from zentrack.config.run_setup import RunSetup, resolve_setup
from zentrack.config.scenario_config import load_scenario_config
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import build_config, loopback_config, open_retrying

log = logging.getLogger("zentrack.soak")

#: the longest soak run (s), and every fault period: 0 (off) or 1 s to that (a period of 1e-7 s or NaN would
#: never finish drawing the schedule)
MAX_SOAK_S = 86400.0
fault_period = off_or_float_in(1.0, MAX_SOAK_S, "fault_period")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float_in(10.0, MAX_SOAK_S, "duration"), default=600.0,
                   help=f"seconds of each run, 10 to {MAX_SOAK_S:g} (default 600)")
    p.add_argument("--nodes", type=nodes_int, help="trackers (default: the scenario's, 10 for exp2; ring layouts only)")
    p.add_argument("--scenario", default=catalogue.DEFAULT_SCENARIO, metavar="NAME|PATH", type=catalogue.scenario_arg,
                   help=catalogue.help_text() + "; its filter, fusion rule and sample period are used, --duration "
                        "sets the steps")
    p.add_argument("--kill-every", type=fault_period, default=30.0, help="SIGKILL + restart period, s (0: none)")
    p.add_argument("--freeze-every", type=fault_period, default=60.0, help="freeze period, s (0: none)")
    p.add_argument("--cut-every", type=fault_period, default=90.0, help="link-cut period, s (0: none; >0 needs root)")
    p.add_argument("--fault-s", type=float_in(0.1, 3600.0, "fault_s"), default=5.0,
                   help="length of a freeze or cut, 0.1 to 3600 s (default 5)")
    p.add_argument("--restart-after", type=float_in(0.0, 3600.0, "restart_after"), default=2.0,
                   help="seconds between a kill and the restart, 0 to 3600 (default 2)")
    p.add_argument("--truth-stall-every", type=fault_period, default=0.0,
                   help="SIGSTOP the truth process for a seeded 0.5-3 s this often, s (0: none)")
    p.add_argument("--truth-kill-every", type=fault_period, default=0.0, help="kill and restart the truth this often, s (0: none)")
    p.add_argument("--router-every", type=fault_period, default=0.0,
                   help="kill and restart the router this often, s (0: none; needs --router or namespaces)")
    p.add_argument("--router", action="store_true", help="loopback runs: every process connects through a router")
    p.add_argument("--secure", action="store_true",
                   help="loopback runs in secure mode: certificates made in <out>/certs, every process a mutual-TLS "
                        "client of a router that enforces access control (implies --router)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 file for every process of both runs, merged over zentrack's safe defaults "
                        "(mounted into the services with the netns and compose engines)")
    p.add_argument("--engine", choices=("auto", "loopback", "netns", "compose"), default="auto",
                   help="where the cluster runs: processes on loopback, network namespaces (root), or docker "
                        "compose on a Docker engine (containers; kills, pauses and network disconnects); "
                        "default auto: namespaces when --cut-every > 0, else loopback")
    p.add_argument("--image", default="zentrack:latest", help="--engine compose: the image to run (built before)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the scenario and of the fault schedule")
    p.add_argument("--cpu-hog", type=int_in(0, MAX_HOGS, "processes"), default=0, metavar="N",
                   help="run both runs beside N busy-loop processes at normal priority (a loaded host on purpose: "
                        "2 keep 2 cores busy); stopped with the soak, reported in report.json (default 0: none)")
    p.add_argument("--realtime-nice", type=int_in(-20, 0, "nice"), default=REALTIME_NICE, metavar="N",
                   help=f"the nice value of the trackers, the truth and the router in both runs, -20 to 0 (default {REALTIME_NICE}: above "
                        "ordinary work, so that a restarted tracker gets the CPU to start on a loaded host; needs "
                        "root or CAP_SYS_NICE, else reported and left; 0: unchanged)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")


#: fault kind -> (its undo, what it hits); a target of None means "a tracker chosen by the seed"
FAULTS = {"kill": "restart", "freeze": "thaw", "cut": "heal", "stall": "resume"}


#: where each service fault's series starts within its period: clear of the tracker faults, which start at
#: multiples of their periods, and of each other
SERVICE_PHASE_S = {"stall": 15.0, "kill": 10.0, "router": 20.0}


def schedule(args: argparse.Namespace) -> list[tuple[float, str, int | str]]:
    """Seeded fault events ``(seconds after start, action, target)``: a target is a tracker index, ``truth``
    or ``router``. A tracker is never under two faults at once, and gets 25 s to recover before the next one
    (the least busy trackers are chosen when none is free); service faults start at an offset within their
    period so that they do not coincide with the tracker faults."""
    rng = np.random.default_rng(args.seed + 7919)
    stall_rng = np.random.default_rng(args.seed + 104729)
    events: list[tuple[float, str, int | str]] = []
    busy: dict[int, list[tuple[float, float]]] = {i: [] for i in range(args.nodes)}
    kinds = [("kill", args.kill_every, lambda: args.restart_after, None, 0.0),
             ("freeze", args.freeze_every, lambda: args.fault_s, None, 0.0),
             ("cut", args.cut_every, lambda: args.fault_s, None, 0.0),
             ("stall", getattr(args, "truth_stall_every", 0.0), lambda: round(float(stall_rng.uniform(0.5, 3.0)), 2),
              "truth", SERVICE_PHASE_S["stall"]),
             ("kill", getattr(args, "truth_kill_every", 0.0), lambda: args.restart_after, "truth", SERVICE_PHASE_S["kill"]),
             ("kill", getattr(args, "router_every", 0.0), lambda: args.restart_after, "router", SERVICE_PHASE_S["router"])]
    for kind, every, length_of, target, phase in kinds:
        if every <= 0:
            continue
        t = every + phase
        while True:
            length = length_of()
            if t + length >= args.duration - 5:
                break
            hit: int | str
            if target is None:
                window = (t, t + length + 25)  # the fault, then time to recover
                overlaps = {i: sum(a < window[1] and window[0] < b for a, b in spans) for i, spans in busy.items()}
                least = min(overlaps.values())
                hit = int(rng.choice([i for i, n in overlaps.items() if n == least]))
                busy[hit].append(window)
            else:
                hit = target
            events += [(round(t, 2), kind, hit), (round(t + length, 2), FAULTS[kind], hit)]
            t += every
    return sorted(events, key=lambda e: (e[0], str(e[2])))


def service_name(target: int | str) -> str:
    return f"node-{target}" if isinstance(target, int) else target


class LoopbackBackend:
    def __init__(self, setup: RunSetup, out: Path, viewer: bool, router: bool = False, secure: str | None = None,
                 zenoh_config: str | None = None) -> None:
        self.cluster = Cluster(setup, out, viewer=[] if viewer else None, router=router, secure=secure,
                               zenoh_config=zenoh_config)

    def start(self) -> Recorder:
        self.cluster.start()
        assert self.cluster.recorder is not None  # start() opens it
        return self.cluster.recorder

    def act(self, action: str, target: int | str) -> None:
        c, name = self.cluster, service_name(target)
        if action == "kill":
            c.signal_process(name, signal.SIGKILL)
        elif action == "restart":
            c.restart_process(name)
        elif action in ("freeze", "stall", "thaw", "resume"):
            c.signal_process(name, signal.SIGSTOP if action in ("freeze", "stall") else signal.SIGCONT)
        else:
            raise ValueError("link cuts need namespace mode")

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.cluster.procs.items() if p.poll() is None}

    def truth_running(self) -> bool:
        return self.cluster.procs["truth"].poll() is None

    def exit_codes(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.cluster.procs.items()}

    def stop(self) -> None:
        self.cluster.stop()


class NetnsBackend:
    def __init__(self, setup: RunSetup, out: Path, viewer: bool, tag: str, scenario: str = "exp2", seed: int = 0,
                 zenoh_config: str | None = None) -> None:
        self.setup, self.out = setup, out
        self.harness = Harness(out / "netns", tag)
        self.compose = out / "compose.yml"
        self.compose.write_text(render(setup.scenario.nodes, scenario=scenario, steps=setup.scenario.steps, seed=seed,
                                       zenoh_config=beside(zenoh_config, out)))
        self.session: zenoh.Session | None = None

    def start(self) -> Recorder:
        self.harness.up(self.compose, str(Path(sys.executable).with_name("zentrack")))
        self.session = open_retrying(loopback_config("client", connect=[f"tcp/{SUBNET}.10:7447"]), 30.0)
        self.recorder = Recorder(self.session, Keys("compose"), self.setup.scenario)
        return self.recorder

    def act(self, action: str, target: int | str) -> None:
        service = service_name(target)
        if action == "kill":
            self.harness.signal(service, signal.SIGKILL)
        elif action == "restart":
            self.harness.restart(service)
        elif action in ("freeze", "stall", "thaw", "resume"):
            self.harness.signal(service, signal.SIGSTOP if action in ("freeze", "stall") else signal.SIGCONT)
        else:
            self.harness.set_link(service, action == "heal")

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.harness.procs.items() if p.poll() is None}

    def truth_running(self) -> bool:
        return self.harness.procs["truth"].poll() is None

    def exit_codes(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.harness.procs.items()}

    def stop(self) -> None:
        if self.session is not None:
            self.recorder.close()
            self.session.close()
            self.session = None
        self.harness.down()
        rec = self.out / "netns" / "volumes" / "recordings" / "recording.rrd"
        if rec.exists():
            rec.replace(self.out / "recording.rrd")


def beside(zenoh_config: str | None, folder: Path) -> str | None:
    """Copy a user's Zenoh file next to a run's compose file; its name as the compose file refers to it."""
    if not zenoh_config:
        return None
    shutil.copyfile(zenoh_config, folder / "zenoh.json5")
    return "zenoh.json5"


def rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def run_one(backend, events, duration: float, priority: Prioritizer | None = None) -> dict:
    """Run to the end, applying ``events``; returns the recorder, fault log, RSS samples and exit codes.
    ``priority`` raises the trackers, the truth and the router (each new process: a restarted one too)."""
    priority = priority or Prioritizer(0)
    rec = backend.start()
    priority.apply(backend.pids())
    end_wait = time.time() + 120
    while not np.isfinite(rec.mean).any() and time.time() < end_wait:
        rec.drain(0.1)
    t0 = time.time()
    seen = np.flatnonzero(np.isfinite(rec.mean).all(axis=-1).any(axis=1))
    first_step, ts = (int(seen[0]) if seen.size else 0), rec.scn.ts
    pending = list(events)
    rss: dict[str, list[tuple[float, float, int]]]
    applied, rss, next_sample = [], {}, t0

    def truth_comes_back() -> bool:
        return any(a == "restart" and target == "truth" for _, a, target in pending)

    while (backend.truth_running() or truth_comes_back()) and time.time() - t0 < duration + 120:
        rec.drain(0.05)
        now = time.time() - t0
        while pending and pending[0][0] <= now:
            t, action, target = pending.pop(0)
            backend.act(action, target)
            priority.apply(backend.pids())  # a restarted process: raised before its imports are done
            # the run's step by the clock (the recorder hears nothing while the router is down)
            step = min(first_step + int(round((time.time() - t0) / ts)), rec.scn.steps - 1)
            applied.append({"t": round(now, 2), "action": action, "node": target, "step": step})
            log.info("soak: t=%.1f s (step %d) %s %s", now, step, action, service_name(target))
        if time.time() >= next_sample:
            for name, pid in backend.pids().items():
                value = rss_mib(pid)
                if value is not None:
                    rss.setdefault(name, []).append((round(now, 1), value, pid))
            next_sample += 10.0
    settle = time.time() + 10
    while time.time() < settle and any(c is None for n, c in backend.exit_codes().items()
                                       if n.startswith(("node", "viewer"))):
        rec.drain(0.1)
    rec.drain(0.5)
    codes = backend.exit_codes()
    return {"recorder": rec, "faults": applied, "rss": rss, "exit_codes": codes, "priority": priority.report()}


def position_errors(rec: Recorder) -> np.ndarray:
    truth = rec.scn.truth[0]
    return np.linalg.norm(rec.mean[:, :, :3] - truth[:, None, :3], axis=-1)


def plot(err: np.ndarray, faults: list[dict], ts: float, path: Path, title: str) -> None:
    from PIL import Image, ImageDraw

    w, h, pad = 1400, 700, 60
    img = Image.new("RGB", (w, h), "white")
    d = ImageDraw.Draw(img)
    k_steps, m = err.shape
    top = float(np.nanpercentile(err, 99)) * 1.2 if np.isfinite(err).any() else 1.0
    x = lambda k: pad + (w - 2 * pad) * k / max(k_steps - 1, 1)  # noqa: E731
    y = lambda e: h - pad - (h - 2 * pad) * min(e, top) / top  # noqa: E731
    d.rectangle([pad, pad, w - pad, h - pad], outline="black")
    colors = {"kill": (220, 0, 0), "freeze": (0, 90, 220), "cut": (240, 140, 0), "stall": (130, 0, 170)}
    for f in faults:
        if f["action"] in colors:
            k = f.get("step", f["t"] / ts)
            row = f["node"] % 4 if isinstance(f["node"], int) else 4
            d.line([x(k), pad, x(k), h - pad], fill=colors[f["action"]], width=1)
            d.text((x(k) + 2, pad + 2 + 12 * row), f"{f['action']} {f['node']}", fill=colors[f["action"]])
    for i in range(m):
        hue = i / max(m, 1)
        col = tuple(int(40 + 180 * max(0.0, min(1.0, abs((hue * 6 + o) % 6 - 3) - 1))) for o in (0, 4, 2))
        pts = [(x(k), y(err[k, i])) for k in range(k_steps) if np.isfinite(err[k, i])]
        for a, b in zip(pts, pts[1:]):
            if b[0] - a[0] < 3 * (w - 2 * pad) / max(k_steps, 1):
                d.line([a, b], fill=col, width=1)
    d.text((pad, 20), f"{title}: position error (m) per node over {k_steps} steps; red kill, blue freeze, orange cut, purple truth stall",
           fill="black")
    d.text((8, pad - 4), f"{top:.0f}", fill="black")
    d.text((8, h - pad - 8), "0", fill="black")
    img.save(path)


def evaluate(faulty: dict, reference: dict, duration: float, run_names: list[str],
             engine_leftovers: list[str] | None = None) -> dict:
    """Judge the faulty run against the reference by the criteria in the module docstring. ``engine_leftovers``:
    containers, networks or volumes a container engine still holds after the runs (each one fails
    ``nothing_left_running``)."""
    rec, ref = faulty["recorder"], reference["recorder"]
    summary, ref_summary = rec.summary(), ref.summary()
    err, ref_err = position_errors(rec), position_errors(ref)
    killed = {f["node"] for f in faulty["faults"] if f["action"] == "kill"}
    crit = {}
    survivors_ok = all(code in (0, None) for n, code in faulty["exit_codes"].items()
                       if not (n.startswith("node-") and int(n.split("-")[1]) in killed))
    have = np.isfinite(rec.mean).all(axis=-1)
    no_nan = bool(np.all(np.isfinite(rec.cov[have])))
    crit["no_crash_no_nan"] = {"pass": survivors_ok and no_nan, "exit_codes": faulty["exit_codes"], "nan_free": no_nan}
    ratios = []
    for i in range(rec.scn.nodes):
        a = np.sqrt(np.nanmean(err[:, i] ** 2)) if np.isfinite(err[:, i]).any() else np.inf
        b = np.sqrt(np.nanmean(ref_err[:, i] ** 2))
        ratios.append(float(a / b))
    crit["rmse_vs_reference"] = {"pass": bool(max(ratios) <= 1.25), "ratio_per_node": ratios, "limit": 1.25}
    recoveries = []
    for f in faulty["faults"]:
        if f["action"] != "restart" or not isinstance(f["node"], int):
            continue
        i = f["node"]
        after = f["step"]
        back = next((k for k in range(after, rec.scn.steps) if have[k, i]), None)
        steps_needed = None
        if back is not None:
            others = [j for j in range(rec.scn.nodes) if j != i]
            for k in range(back, min(back + 21, rec.scn.steps)):
                if have[k, i] and err[k, i] < 2 * np.nanmedian(err[k, others]):
                    steps_needed = k - back
                    break
        recoveries.append({"node": i, "t": f["t"], "first_step_back": back, "steps_to_2x_median": steps_needed,
                           "steps_to_publish": None if back is None else back - after})
    crit["restart_recovery"] = {"pass": all(r["steps_to_2x_median"] is not None for r in recoveries),
                                "restarts": recoveries, "limit_steps": 20}
    crit["fault_recovery"] = fault_recovery(faulty["faults"], have, rec.scn.steps)
    growth = {}
    start_t = min(120.0, duration / 2)
    for name, samples in faulty["rss"].items():
        pids = {s[2] for s in samples}
        if len(pids) != 1:
            continue  # restarted during the run: not long-lived
        base = [v for t, v, _ in samples if t >= start_t]
        if len(base) >= 2:
            growth[name] = base[-1] / base[0] - 1.0
    crit["rss_growth"] = {"pass": bool(growth) and max(growth.values()) < 0.10, "growth_per_process": growth,
                          "from_s": start_t, "limit": 0.10}
    complete = summary["network"]["estimates"] > 0.5 * rec.scn.steps * rec.scn.nodes
    crit["outputs_complete"] = {"pass": complete, "estimates": summary["network"]["estimates"]}
    left = processes_of_runs(run_names, exclude="soak") + list(engine_leftovers or [])
    crit["nothing_left_running"] = {"pass": not left, "processes": left}
    return {"criteria": crit, "summary": summary, "reference_summary": ref_summary}


def fault_recovery(faults: list[dict], have: np.ndarray, steps: int, limit: int = 20) -> dict:
    """After each fault ends (restart, thaw, heal, resume), the steps until every live tracker publishes an
    estimate again. A tracker still under another fault at that moment (its own, or a truth or router fault,
    which hits every tracker) is left out of that event: the end of that other fault judges it."""
    nodes = have.shape[1]
    active: dict[int | str, set[str]] = {}  # target -> the faults it is under
    events = []
    for f in faults:
        target, action = f["node"], f["action"]
        if action in FAULTS:
            active.setdefault(target, set()).add(action)
            continue
        kind = next(k for k, undo in FAULTS.items() if undo == action)
        active.get(target, set()).discard(kind)
        services_down = any(v for k, v in active.items() if isinstance(k, str))
        end = f["step"]
        per_node = {}
        for i in range(nodes):
            if active.get(i) or services_down:
                continue
            back = next((k for k in range(end, steps) if have[k, i]), None)
            per_node[i] = None if back is None else back - end
        worst = None if any(v is None for v in per_node.values()) else max((v for v in per_node.values() if v is not None), default=0)
        events.append({"t": f["t"], "after": f"{action} {service_name(target)}", "step": end,
                       "steps_to_all_estimating": worst, "per_node": per_node,
                       "pass": worst is not None and worst <= limit})
    ends = [e for e in events if e["steps_to_all_estimating"] is not None]
    return {"pass": all(e["pass"] for e in events), "limit_steps": limit, "events": events,
            "worst_steps": max((e["steps_to_all_estimating"] for e in ends), default=None)}


def soak_setup(args: argparse.Namespace) -> RunSetup:
    """The soaked run: ``--scenario`` (its filter, fusion rule and sample period) in realtime, ``--duration``
    seconds long, with ``--nodes`` trackers (ring layouts only; default: the scenario's) and ``--seed``."""
    ts = load_scenario_config(args.scenario).ts
    steps = max(1, int(round(args.duration / ts)))
    flags = argparse.Namespace(scenario=args.scenario, scenario_file=None, filter_kind=None, fusion=None, rounds=None,
                               qbar=None, theta=None, timing_mode="realtime", deadline_frac=None, nodes=args.nodes,
                               steps=steps, seed=args.seed)
    setup = resolve_setup(flags)
    setup.source = "soak"
    return setup


def run(args: argparse.Namespace) -> int:
    setup_logging()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    setup = soak_setup(args)
    scn = setup.scenario
    args.nodes = scn.nodes  # the fault schedule picks among the scenario's trackers
    engine = args.engine if args.engine != "auto" else ("netns" if args.cut_every > 0 else "loopback")
    if args.cut_every > 0 and engine == "loopback":
        raise ValueError("--cut-every needs --engine netns or compose (loopback processes have no link to cut)")
    if engine == "netns" and os.geteuid() != 0:
        raise ValueError("network namespaces need root: run as root, or pass --cut-every 0 (or --engine compose)")
    if args.secure and engine != "loopback":
        raise ValueError("--secure: the secure soak runs on the loopback engine (--cut-every 0, no --engine netns/compose)")
    secure = None
    if args.secure:
        secure = str((out / "certs").resolve())
        make_certificates(secure, scn.nodes)
        args.router = True
    if args.router_every > 0 and engine == "loopback" and not args.router:
        raise ValueError("--router-every needs a router: pass --router (or --engine netns or compose)")
    if engine == "compose":
        check_image(args.image)
    zenoh_file = None
    if args.zenoh_config:
        zenoh_file = str(Path(args.zenoh_config).resolve())
        build_config("peer", file=zenoh_file)  # a bad file is one clear error before anything starts
    events = schedule(args)
    results, runs, leftovers = {}, [], []
    lean_start = prepare_lean_start()  # what a restarted tracker spends starting (docs/networks.md, loaded hosts)
    hog = CpuHog(getattr(args, "cpu_hog", 0))
    hog.start()  # both runs beside it: the reference is judged on the same loaded host
    for label, evts, folder in (("faulty", events, out), ("reference", [], out / "reference")):
        folder.mkdir(parents=True, exist_ok=True)
        tag = "s" if label == "faulty" else "r"
        backend: LoopbackBackend | NetnsBackend | ComposeBackend
        if engine == "compose":
            backend = ComposeBackend(setup, folder, tag, args.image, args.seed, args.scenario,
                                     zenoh_config=beside(zenoh_file, folder))
        elif engine == "netns":
            backend = NetnsBackend(setup, folder, viewer=label == "faulty", tag=tag, scenario=args.scenario,
                                   seed=args.seed, zenoh_config=zenoh_file)
        else:
            backend = LoopbackBackend(setup, folder, viewer=label == "faulty", router=args.router, secure=secure,
                                      zenoh_config=zenoh_file)
        log.info("soak: %s run, %d trackers, %.0f s, %d fault events, %s", label, args.nodes, args.duration,
                 len(evts), engine)
        try:
            results[label] = run_one(backend, evts, args.duration, Prioritizer(getattr(args, "realtime_nice", 0)))
        except BaseException:
            hog.stop()
            raise
        finally:
            backend.stop()
        if isinstance(backend, ComposeBackend):
            runs.append(backend.run)
            leftovers += backend.leftovers()
        else:
            runs.append("compose" if isinstance(backend, NetnsBackend) else backend.cluster.run_name)
        write_json(folder / "summary.json", results[label]["recorder"].summary())
        results[label]["recorder"].save_estimates(folder / "estimates.npz")
    hog_report = hog.stop()
    report = evaluate(results["faulty"], results["reference"], args.duration, runs, leftovers)
    report.update({"duration_s": args.duration, "nodes": args.nodes, "seed": args.seed, "secure": bool(args.secure),
                   "mode": {"netns": "namespaces"}.get(engine, engine), "faults": results["faulty"]["faults"], "schedule": events,
                   "rss": results["faulty"]["rss"], "cpu_hog": hog_report,
                   "lean_start": lean_start, "priority": {k: results[k]["priority"] for k in results}})
    rrd = out / "recording.rrd"
    report["criteria"]["outputs_complete"]["recording_bytes"] = rrd.stat().st_size if rrd.exists() else 0
    if not rrd.exists():
        report["criteria"]["outputs_complete"]["pass"] = False
    passed = all(c["pass"] for c in report["criteria"].values())
    report["pass"] = passed
    plot(position_errors(results["faulty"]["recorder"]), results["faulty"]["faults"], scn.ts, out / "error.png", "soak")
    write_json(out / "report.json", report)
    for name, c in report["criteria"].items():
        print(f"{'PASS' if c['pass'] else 'FAIL'}  {name}")
    print(f"soak {'passed' if passed else 'FAILED'}: report {out / 'report.json'}, plot {out / 'error.png'}")
    return 0 if passed else 1
