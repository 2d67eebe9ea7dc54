"""``zentrack bench capacity --check-hosts H``: one realtime run of H hosts in network namespaces (a router
each, ``zentrack compose --hosts H`` without its viewer, :mod:`zentrack.cluster.engines.netns`), measured the way
``zentrack bench scale`` measures one host, for the capacity model to be set against.

Over the steady state (:func:`zentrack.bench.scale.steady_window` from the truth's first step): the CPU per
step of every service's process (user + system of all its threads, ``/proc/<pid>/stat``; ``ip netns exec``
execs the service, so the harness's pid is the service's), and the bytes per second on every link of every
router, from the kernel's counters of the router's sockets in its own namespace (``ip netns exec <ns> ss
-tinH state established dst <peer>``), each link named by the service at the address it goes to. A link
between two routers is read at the lower-numbered one (router h dials every router before it). Needs root;
the harness is always taken down, whatever happens.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from zentrack.bench.scale import cpu_seconds, process_type, steady_window
from zentrack.bench.scale_probe import COUNTERS, parse_ss
from zentrack.cluster.deployment.compose import host_of, render
from zentrack.cluster.engines.netns import Harness

#: the truth's log line at its first step (truth/process.py)
TRUTH_STARTED = "run of"
START_TIMEOUT_S = 180.0


def compose_without_viewer(nodes: int, steps: int, hosts: int) -> str:
    """``zentrack compose --hosts`` without its viewer (the recorder scores; nothing renders on 2 cores)."""
    doc = yaml.safe_load(render(nodes, steps=steps, hosts=hosts))
    del doc["services"]["viewer"]
    cmd = doc["services"]["truth"]["command"]
    at = cmd.index("viewer")
    del cmd[at - 1: at + 1]
    return yaml.safe_dump(doc, sort_keys=False)


def kind_of(service: str) -> str:
    return "router" if service.startswith("router") else process_type(service)


def link_peers(state: dict, nodes: int, hosts: int) -> dict[str, list[tuple[str, str]]]:
    """Per router service: the (peer service, address) of each link it holds that this check reads."""
    out: dict[str, list[tuple[str, str]]] = {f"router-{h}": [] for h in range(hosts)}
    for i in range(nodes):
        out[f"router-{host_of(i, nodes, hosts)}"].append((f"node-{i}", state["addrs"][f"node-{i}"]))
    out["router-0"] += [(s, state["addrs"][s]) for s in ("truth", "recorder")]
    for a in range(hosts):
        out[f"router-{a}"] += [(f"router-{b}", state["addrs"][f"router-{b}"]) for b in range(a + 1, hosts)]
    return out


def link_sample(harness: Harness, peers: dict[str, list[tuple[str, str]]]) -> dict[tuple[str, str], dict[str, float]]:
    """(router, peer) -> the router side's socket counters of its links to the peer's address, summed, and
    ``at``: when they were read (the middle of its ``ss`` call). The links are read one after another, each by a
    process of its own, which on a loaded host takes seconds: a link's rate is over its own two readings."""
    out = {}
    for router, links in peers.items():
        for peer, addr in links:
            start = time.monotonic()
            done = subprocess.run(["ip", "netns", "exec", harness.ns(router), "ss", "-tinH", "state", "established",
                                   "dst", addr], capture_output=True, text=True, timeout=10)
            total: dict[str, float] = {k: 0 for k in COUNTERS}
            for s in parse_ss(done.stdout):
                for k in COUNTERS:
                    total[k] += s.counters[k]
            out[(router, peer)] = {**total, "at": (start + time.monotonic()) / 2}
    return out


def cpu_sample(state: dict) -> dict[str, float]:
    out = {name: cpu_seconds(entry["pid"]) for name, entry in state["services"].items() if entry.get("pid")}
    return {k: v for k, v in out.items() if v is not None}


def wait_for_start(log: Path, truth: subprocess.Popen, timeout: float = START_TIMEOUT_S) -> float:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if log.exists() and TRUTH_STARTED in log.read_text(errors="replace"):
            return time.monotonic()
        if truth.poll() is not None:
            raise RuntimeError(f"the truth exited ({truth.returncode}) before its first step; see {log}")
        time.sleep(0.2)
    raise RuntimeError(f"the truth did not start within {timeout:.0f} s; see {log}")


def measured(before: dict, after: dict, links0: dict, links1: dict, seconds: float, ts: float) -> dict:
    """CPU ms per step per process type (mean over its processes; routers each) and bytes/s per link."""
    steps = seconds / ts
    cpu = {name: 1e3 * (after[name] - before[name]) / steps for name in before.keys() & after.keys()}
    per_kind: dict[str, list[float]] = {}
    for name, ms in cpu.items():
        per_kind.setdefault(kind_of(name), []).append(ms)
    rates = {}
    for (router, peer), c1 in links1.items():
        c0 = links0.get((router, peer), {k: 0 for k in COUNTERS})
        # over the link's own readings (a run of 20 s has a 5 s window: 0.5 s between when the first and the
        # second sampling reached a link was a 10 % error, run 29); the sampling's window without them
        span = c1["at"] - c0["at"] if "at" in c0 and "at" in c1 else seconds
        rates[(router, peer)] = {"from_router": max(0, c1["bytes_sent"] - c0["bytes_sent"]) / span,
                                 "to_router": max(0, c1["bytes_received"] - c0["bytes_received"]) / span}
    trackers = [v for (_, peer), v in rates.items() if peer.startswith("node")]
    links = {"tracker_up": float(np.mean([v["to_router"] for v in trackers])),
             "tracker_down": float(np.mean([v["from_router"] for v in trackers])),
             "truth_up": rates[("router-0", "truth")]["to_router"],
             "recorder_down": rates[("router-0", "recorder")]["from_router"]}
    for (router, peer), v in rates.items():
        if peer.startswith("router"):  # router (lower index) dialled by peer: sent = router -> peer
            links[f"{router}->{peer}"] = v["from_router"]
            links[f"{peer}->{router}"] = v["to_router"]
    routers = sorted((n for n in cpu if n.startswith("router")), key=lambda n: int(n.split("-")[1]))
    return {"seconds": seconds,
            "cpu_ms_per_step": {"tracker": float(np.mean(per_kind.get("tracker", [np.nan]))),
                                "tracker_max": float(np.max(per_kind.get("tracker", [np.nan]))),
                                "router": [cpu[n] for n in routers],
                                "truth": cpu.get("truth", float("nan")), "recorder": cpu.get("recorder", float("nan"))},
            "bytes_per_s": links,
            "tracker_links": {peer: v for (_, peer), v in sorted(rates.items()) if peer.startswith("node")}}


def run_check(nodes: int, hosts: int, duration: float, ts: float, folder: Path, tag: str = "cap") -> dict:
    """Run the H-host cluster once and measure it (module docstring); the harness is down when this returns."""
    steps = int(round(duration / ts))
    folder.mkdir(parents=True, exist_ok=True)
    compose = folder / "compose.yml"
    compose.write_text(compose_without_viewer(nodes, steps, hosts))
    harness = Harness(folder / "netns", tag=tag)
    try:
        state = harness.up(compose, str(Path(sys.executable).with_name("zentrack")))
        peers = link_peers(state, nodes, hosts)
        started = wait_for_start(harness.dir / "logs" / "truth.log", harness.procs["truth"])
        warmup, steady = steady_window(duration)
        time.sleep(max(0.0, started + warmup - time.monotonic()))
        t0, cpu0, links0 = time.monotonic(), cpu_sample(state), link_sample(harness, peers)
        time.sleep(steady)
        t1, cpu1, links1 = time.monotonic(), cpu_sample(state), link_sample(harness, peers)
        out = measured(cpu0, cpu1, links0, links1, t1 - t0, ts)
        recorder = harness.procs["recorder"]
        try:
            recorder.wait(timeout=duration + 60)
        except subprocess.TimeoutExpired:
            pass
        summary_file = harness.dir / "volumes" / "recordings" / "run" / "summary.json"
        if summary_file.exists():
            net = json.loads(summary_file.read_text())["network"]
            out["run"] = {k: net.get(k) for k in ("deadline_misses", "estimates", "estimates_lost", "latency_ms")}
            out["run"]["expected_estimates"] = nodes * steps
    finally:
        harness.down()
    return {"nodes": nodes, "hosts": hosts, "degree": 2, "duration_s": duration, "ts": ts, **out}
