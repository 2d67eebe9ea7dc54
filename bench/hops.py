"""``zentrack bench hops``: what each router on the path costs a message, for the multi-host topology.

One ping process and one echo process exchange 1.5 KB messages over Zenoh on this host, along three paths
measured back to back in one invocation:

- ``direct``: two peers linked to each other (the embedded default's topology);
- ``1 router``: two clients of one router (one host's trackers through their router);
- ``2 routers``: a client of router A and a client of router B, A and B linked (trackers on two hosts of
  ``zentrack compose --hosts``: with a full mesh of router links no message crosses more than two routers).

Each path's round trip p50/p99 is printed; the latency a router adds one way is half the difference between
neighbouring paths. All on loopback: a real network adds its own wire time per host-to-host link on top.
"""
from __future__ import annotations

import argparse
import queue
import subprocess
import sys
import time

import numpy as np
import zenoh

from zentrack.common.argtypes import positive_int
from zentrack.common.ports import free_port
from zentrack.common.report import fmt_num, table, write_json
from zentrack.transport.zsession import loopback_config, open_retrying


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pings", type=positive_int, default=2000, help="round trips per path (default 2000)")
    p.add_argument("--size", type=positive_int, default=1500, help="message size in bytes (default 1500)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def percentiles(x: np.ndarray) -> dict:
    p50, p90, p99 = np.percentile(x, [50, 90, 99])
    return {"count": int(x.size), "p50": float(p50), "p90": float(p90), "p99": float(p99), "max": float(x.max())}


def start_router(port: int, links: list[int]) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "zentrack", "router", "--listen", f"tcp/127.0.0.1:{port}"]
    for other in links:
        cmd += ["--connect", f"tcp/127.0.0.1:{other}"]
    return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def round_trips(conf: zenoh.Config, echo_cmd: list[str], pings: int, size: int, prefix: str) -> list[float]:
    """Round trips (ms) between a session opened with ``conf`` and an echo process started with ``echo_cmd``."""
    echo = subprocess.Popen(echo_cmd, stdin=subprocess.DEVNULL)
    try:
        with open_retrying(conf, 30.0) as session:
            replies: queue.Queue[float] = queue.Queue()
            sub = session.declare_subscriber(f"{prefix}/pong", lambda s: replies.put(time.perf_counter()))
            pub = session.declare_publisher(f"{prefix}/ping", express=True, congestion_control=zenoh.CongestionControl.BLOCK)
            end = time.time() + 30
            while not pub.matching_status.matching:  # type: ignore[attr-defined]  # the stub says bool
                if time.time() > end or echo.poll() is not None:
                    raise RuntimeError("the echo process did not come up")
                time.sleep(0.05)
            time.sleep(0.5)  # the pong subscriber's route settles through every router
            payload = bytes(size)
            rtts: list[float] = []
            lost = 0
            for i in range(pings + 50):
                t0 = time.perf_counter()
                pub.put(payload)
                try:
                    t1 = replies.get(timeout=5)
                except queue.Empty:
                    lost += 1
                    continue
                if i >= 50:  # warm-up
                    rtts.append((t1 - t0) * 1e3)
                time.sleep(0.001)
            sub.undeclare()
            if lost:
                raise RuntimeError(f"{lost} ping(s) got no answer within 5 s")
    finally:
        echo.terminate()
        echo.wait(timeout=10)
    return rtts


def measure(path: str, pings: int, size: int) -> dict:
    ports = [free_port() for _ in range(2)]
    prefix = f"zentrack-bench/hops{ports[0]}"
    pong = [sys.executable, "-m", "zentrack.bench.pong"]
    routers: list[subprocess.Popen] = []
    try:
        if path == "direct":
            conf = loopback_config("peer", listen=[f"tcp/127.0.0.1:{ports[0]}"])
            echo = [*pong, f"tcp/127.0.0.1:{ports[0]}", prefix, "peer"]
        elif path == "1 router":
            routers.append(start_router(ports[0], []))
            conf = loopback_config("client", connect=[f"tcp/127.0.0.1:{ports[0]}"])
            echo = [*pong, f"tcp/127.0.0.1:{ports[0]}", prefix, "client"]
        else:
            routers += [start_router(ports[0], []), start_router(ports[1], [ports[0]])]
            conf = loopback_config("client", connect=[f"tcp/127.0.0.1:{ports[0]}"])
            echo = [*pong, f"tcp/127.0.0.1:{ports[1]}", prefix, "client"]
        rtts = round_trips(conf, echo, pings, size, prefix)
    finally:
        for r in routers:
            r.terminate()
        for r in routers:
            r.wait(timeout=10)
    return {"path": path, "routers": {"direct": 0, "1 router": 1, "2 routers": 2}[path], "rtt_ms": percentiles(np.array(rtts))}


def run(args: argparse.Namespace) -> int:
    results = []
    for path in ("direct", "1 router", "2 routers"):
        print(f"{path}: {args.pings} round trips of {args.size} B ...", file=sys.stderr, flush=True)
        results.append(measure(path, args.pings, args.size))
    for prev, cur in zip(results, results[1:]):
        cur["one_way_added_ms"] = {q: (cur["rtt_ms"][q] - prev["rtt_ms"][q]) / 2 for q in ("p50", "p99")}
    print(table(["path", "routers", "RTT p50 ms", "RTT p90 ms", "RTT p99 ms", "one way added p50 ms", "p99 ms"],
                [[r["path"], r["routers"], fmt_num(r["rtt_ms"]["p50"], 3), fmt_num(r["rtt_ms"]["p90"], 3),
                  fmt_num(r["rtt_ms"]["p99"], 3),
                  fmt_num(r["one_way_added_ms"]["p50"], 3) if "one_way_added_ms" in r else "-",
                  fmt_num(r["one_way_added_ms"]["p99"], 3) if "one_way_added_ms" in r else "-"] for r in results]))
    print("(one way added: half the round-trip difference to the path with one router fewer; loopback only)")
    if args.json:
        write_json(args.json, {"command": "bench hops", "pings": args.pings, "size": args.size, "results": results})
    return 0
