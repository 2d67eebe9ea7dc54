"""One process of ``zentrack bench floor`` (:mod:`zentrack.bench.floor`): ``python -m zentrack.bench.floor_node
ROLE --port P ...`` with ROLE one of

- ``router``: a Zenoh router listening on ``tcp/127.0.0.1:P`` (multicast scouting off, the project's
  :func:`~zentrack.transport.zconfig.loopback_config`);
- ``tracker``: a *null tracker* ``--index I`` of ``--n N``: a tracker's messaging pattern with no filtering
  maths. A Zenoh client of the router; it subscribes ``floor/meas/<I>`` and its ring neighbours' priors
  ``floor/prior/<I±1>``; on a measurement it publishes an 872-byte prior, collects its neighbours' priors until
  the measurement's time + 50 ms, then publishes a 495-byte estimate (the sizes of a real tracker's messages).
  ``--variant queue`` (as the real tracker's inbox): the Zenoh callbacks only enqueue, the main thread does the
  work; ``--variant callback``: the work runs in the callbacks and the estimate goes out as soon as both priors
  are in (a step that never got them is published, late, on the next measurement);
- ``truth``: every 100 ms (absolute schedule) one 164-byte measurement to each ``floor/meas/<i>``;
- ``recorder``: subscribes ``floor/est/*`` and, on SIGTERM, writes ``--out`` as JSON: one row per estimate
  ``[step, tracker, t_meas, arrival time, priors counted]``.

Each process writes a file named after itself into ``--ready DIR`` once its subscriptions are declared (the
truth adds the time of its step 0), runs until SIGTERM (or SIGINT) and closes its Zenoh session on the way out.
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import threading
import time
from typing import Any

import msgpack
import numpy  # noqa: F401  - imported as a real tracker does (its resident memory belongs to the floor)
import zenoh

from zentrack.common.procs import StopFlag
from zentrack.transport.zruntime import ensure_runtime_threads
from zentrack.transport.zsession import loopback_config, open_retrying

PERIOD, DEADLINE = 0.1, 0.05  # the truth's sample period and a tracker's deadline after its measurement (s)
MEAS_BYTES, PRIOR_BYTES, EST_BYTES = 164, 872, 495
#: set by SIGTERM/SIGINT (its handler takes no lock: zentrack.common.procs.StopFlag)
STOP = StopFlag(handle_signals=False)
_PAD: dict[int, int] = {}


def padded(base: dict, size: int) -> bytes:
    """``base`` packed with msgpack plus a bytes field ``x`` that makes the message ``size`` bytes (the padding
    is found once per size; a later int of another width may shift it by a byte)."""
    n = _PAD.get(size)
    if n is None:
        n = max(0, size - len(msgpack.packb({**base, "x": b""})))
        while n > 0 and len(msgpack.packb({**base, "x": b"\0" * n})) > size:
            n -= 1
        _PAD[size] = n
    return msgpack.packb({**base, "x": b"\0" * n})


def ready(args: argparse.Namespace, name: str, *extra: object) -> None:
    """Say this process is ready: a file ``name`` in ``--ready`` holding its pid and ``extra`` (atomically)."""
    path = os.path.join(args.ready, name)
    with open(path + ".tmp", "w") as f:
        f.write(" ".join(map(repr, (os.getpid(), *extra))))
    os.replace(path + ".tmp", path)


def idle() -> None:
    """Wait for SIGTERM, waking every 0.5 s so the signal handler runs promptly."""
    while not STOP.wait(0.5):
        pass


def client(args: argparse.Namespace) -> zenoh.Session:
    return open_retrying(loopback_config("client", connect=[f"tcp/127.0.0.1:{args.port}"]), timeout=60.0)


def router(args: argparse.Namespace) -> None:
    ensure_runtime_threads()
    with zenoh.open(loopback_config("router", listen=[f"tcp/127.0.0.1:{args.port}"])):
        ready(args, "router")
        idle()


def truth(args: argparse.Namespace) -> None:
    with client(args) as s:
        drop = zenoh.CongestionControl.DROP
        pubs = [s.declare_publisher(f"floor/meas/{i}", congestion_control=drop) for i in range(args.n)]
        t0, k = time.time() + 0.2, 0
        ready(args, "truth", t0)  # step k is measured at t0 + k * PERIOD
        while not STOP.wait(max(0.0, t0 + k * PERIOD - time.time())):
            msg = padded({"k": k, "t": t0 + k * PERIOD}, MEAS_BYTES)
            for p in pubs:
                p.put(msg)
            k += 1


def recorder(args: argparse.Namespace) -> None:
    rows: list[tuple] = []

    def on_estimate(sample: zenoh.Sample) -> None:
        now = time.time()
        m = msgpack.unpackb(sample.payload.to_bytes())
        rows.append((m["k"], m["i"], m["t_meas"], now, m["n"]))

    with client(args) as s:
        sub = s.declare_subscriber("floor/est/*", zenoh.handlers.Callback(on_estimate, indirect=False))
        ready(args, "recorder")
        idle()
        sub.undeclare()
    with open(args.out, "w") as f:
        json.dump({"rows": list(rows)}, f)


def neighbours(args: argparse.Namespace) -> list[int]:
    return sorted({(args.index - 1) % args.n, (args.index + 1) % args.n} - {args.index})


def tracker_queue(args: argparse.Namespace) -> None:
    i = args.index
    q: queue.SimpleQueue = queue.SimpleQueue()
    meas_key = f"floor/meas/{i}"

    def on_sample(sample: zenoh.Sample) -> None:  # on Zenoh's thread: only enqueue, as zentrack's inbox does
        q.put((str(sample.key_expr), sample.payload.to_bytes()))

    with client(args) as s:
        subs = [s.declare_subscriber(key, zenoh.handlers.Callback(on_sample, indirect=False))
                for key in [meas_key] + [f"floor/prior/{j}" for j in neighbours(args)]]
        drop = zenoh.CongestionControl.DROP
        pub_prior = s.declare_publisher(f"floor/prior/{i}", congestion_control=drop, express=True)
        pub_est = s.declare_publisher(f"floor/est/{i}", congestion_control=drop)
        ready(args, f"node-{i}")
        priors: dict[int, int] = {}  # step -> neighbours' priors seen (one may come before our measurement)
        backlog: list[tuple[str, bytes]] = []  # a measurement that arrived while collecting
        while not STOP:
            try:
                key, data = backlog.pop(0) if backlog else q.get(timeout=0.5)
            except queue.Empty:
                continue
            m = msgpack.unpackb(data)
            if key != meas_key:  # a prior outside a collect window
                priors[m["k"]] = priors.get(m["k"], 0) + 1
                continue
            k, t_meas = m["k"], m["t"]
            pub_prior.put(padded({"k": k, "i": i}, PRIOR_BYTES))
            while (rem := t_meas + DEADLINE - time.time()) > 0:
                try:
                    key, data = q.get(timeout=rem)
                except queue.Empty:
                    break
                if key == meas_key:
                    backlog.append((key, data))
                    continue
                p = msgpack.unpackb(data)
                priors[p["k"]] = priors.get(p["k"], 0) + 1
            n = priors.pop(k, 0)
            for old in [x for x in priors if x < k - 5]:
                del priors[old]
            pub_est.put(padded({"k": k, "i": i, "t_meas": t_meas, "n": n}, EST_BYTES))
        for sub in subs:
            sub.undeclare()


def tracker_callback(args: argparse.Namespace) -> None:
    i, need = args.index, len(neighbours(args))
    lock = threading.Lock()
    st: dict[str, Any] = {"k": None, "t": None, "done": True}
    priors: dict[int, int] = {}
    pubs: dict[str, Any] = {}

    def publish_estimate() -> None:  # under lock
        k = st["k"]
        pubs["est"].put(padded({"k": k, "i": i, "t_meas": st["t"], "n": priors.pop(k, 0)}, EST_BYTES))
        st["done"] = True
        for old in [x for x in priors if x < k - 5]:
            del priors[old]

    def on_meas(sample: zenoh.Sample) -> None:
        m = msgpack.unpackb(sample.payload.to_bytes())
        with lock:
            if not st["done"]:
                publish_estimate()  # the previous step never got all its priors
            st.update(k=m["k"], t=m["t"], done=False)
            pubs["prior"].put(padded({"k": m["k"], "i": i}, PRIOR_BYTES))
            if priors.get(m["k"], 0) >= need:
                publish_estimate()

    def on_prior(sample: zenoh.Sample) -> None:
        p = msgpack.unpackb(sample.payload.to_bytes())
        with lock:
            priors[p["k"]] = priors.get(p["k"], 0) + 1
            if p["k"] == st["k"] and not st["done"] and priors[p["k"]] >= need:
                publish_estimate()

    with client(args) as s:
        drop = zenoh.CongestionControl.DROP
        pubs["prior"] = s.declare_publisher(f"floor/prior/{i}", congestion_control=drop, express=True)
        pubs["est"] = s.declare_publisher(f"floor/est/{i}", congestion_control=drop)
        subs = [s.declare_subscriber(f"floor/meas/{i}", zenoh.handlers.Callback(on_meas, indirect=False))]
        subs += [s.declare_subscriber(f"floor/prior/{j}", zenoh.handlers.Callback(on_prior, indirect=False))
                 for j in neighbours(args)]
        ready(args, f"node-{i}")
        idle()
        for sub in subs:
            sub.undeclare()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m zentrack.bench.floor_node")
    p.add_argument("role", choices=["router", "tracker", "truth", "recorder"])
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--ready", required=True, metavar="DIR", help="write a file named after this process here")
    p.add_argument("--n", type=int, default=1, help="trackers in the ring")
    p.add_argument("--index", type=int, default=0, help="this tracker's index")
    p.add_argument("--variant", choices=["queue", "callback"], default="queue")
    p.add_argument("--out", help="the recorder's JSON file")
    args = p.parse_args(argv)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: STOP.set())
    if args.role == "tracker":
        (tracker_queue if args.variant == "queue" else tracker_callback)(args)
    else:
        {"router": router, "truth": truth, "recorder": recorder}[args.role](args)


if __name__ == "__main__":
    main()
