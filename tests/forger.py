"""A forging process for the attack tests: well-formed, plausible-looking messages a plain Zenoh peer can send.

``flood VICTIM COUNT PAD_BYTES``: COUNT copies of node VICTIM's latest prior, each with PAD_BYTES of padding in
an extra field (ignored by the decoder) and its own t_pub, published as fast as Zenoh takes them.

``token NAME SECONDS``: hold the liveliness token ``alive/NAME`` (a tracker that does not exist) until the run's
``ctl/stop``, at most SECONDS.

``dup OFFSETS STEPS``: every time any node publishes its round-1 prior for step k, publish copies of it for
step k + 1 (so they arrive before the real one), one per offset of the comma-separated OFFSETS (metres along
x; e.g. ``50,1000,2000``: one biased copy inside the gate and two decoys), STEPS steps per node.

``garbage KEY RATE SECONDS``: publish undecodable bytes on ``zentrack/<run>/KEY`` (e.g. ``meas/0``) at RATE
messages per second for SECONDS.

``prior VICTIM OFFSET_M STEPS``: every time node VICTIM publishes its round-1 prior for step k, publish a copy
for step k + 1 (so it arrives before the real one) with the mean moved by OFFSET_M metres along x and the
same covariance, STEPS times. The forged message passes every wire check; only the receivers' gate and
duplicate rule stand between it and the fusion.

Writes a JSON report (messages forged, first and last forged step) and exits 0.
usage: python forger.py ENDPOINT RUN REPORT prior VICTIM OFFSET_M STEPS
       python forger.py ENDPOINT RUN REPORT flood VICTIM COUNT PAD_BYTES
       python forger.py ENDPOINT RUN REPORT token NAME SECONDS
       python forger.py ENDPOINT RUN REPORT ctl stop|start COUNT
       python forger.py ENDPOINT RUN REPORT dup OFFSETS STEPS
       python forger.py ENDPOINT RUN REPORT garbage KEY RATE SECONDS
With FORGER_SECURE=CERTS_DIR:ROLE in the environment the forger is a secure client holding ROLE's certificate.
"""
from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import zenoh

from zentrack.transport.codec import WireError
from zentrack.transport.messages import RoundMessage, Start, Stop
from zentrack.transport.secure import Identity
from zentrack.transport.zsession import build_config, loopback_config


def attacker_config(endpoint: str) -> zenoh.Config:
    """A plain peer on the run's port; with FORGER_SECURE=DIR:ROLE, a client holding that role's certificate
    (an insider: another node's stolen key) connecting to the secure router."""
    insider = os.environ.get("FORGER_SECURE")
    if insider:
        folder, role = insider.rsplit(":", 1)
        return build_config("client", connect=[endpoint], secure=Identity(Path(folder), role))
    return loopback_config("peer", listen=["tcp/127.0.0.1:0"], connect=[endpoint])


def forge_prior(payload: bytes, victim: int, offset: np.ndarray) -> tuple[int, bytes] | None:
    """The victim's round-1 prior for step k, re-issued for step k + 1 with its mean moved by ``offset``."""
    raw = msgpack.unpackb(payload, raw=False)
    if raw.get("round", 1) != 1 or raw.get("warm"):
        return None
    dims = {name: int(block["y"]["shape"][0]) for name, block in raw["blocks"].items()}
    msg = RoundMessage.decode(payload, victim, dims)
    k = msg.k
    blocks = {}
    for name, (matrix, vector) in msg.blocks.items():
        shift = np.zeros(vector.shape[0])
        shift[: offset.size] = offset
        blocks[name] = (matrix, vector + matrix @ shift)  # y' = Y (x + d)
    ts = msg.t / k if k else 0.1
    return k + 1, RoundMessage(k + 1, (k + 1) * ts, victim, 1, blocks, time.time()).encode()


def flood(endpoint: str, run: str, report: str, victim: int, count: int, pad: int) -> int:
    """Wait for one real prior of the victim, then publish ``count`` padded copies of it back to back."""
    latest: list[bytes] = []
    got = threading.Event()
    conf = attacker_config(endpoint)
    with zenoh.open(conf) as session:
        def on_prior(sample: zenoh.Sample) -> None:
            if not got.is_set():
                latest.append(sample.payload.to_bytes())
                got.set()

        sub = session.declare_subscriber(f"zentrack/{run}/prior/{victim}", on_prior)
        if not got.wait(timeout=60):
            return 1
        sub.undeclare()
        base = msgpack.unpackb(latest[0], raw=False)
        pub = session.declare_publisher(f"zentrack/{run}/prior/{victim}", congestion_control=zenoh.CongestionControl.BLOCK)
        t_start = time.time()
        padding = b"x" * pad
        for n in range(count):
            pub.put(msgpack.packb({**base, "t_pub": base["t_pub"] + n * 1e-6, "pad": padding}, use_bin_type=True))
        seconds = time.time() - t_start
        pub.undeclare()
    with open(report, "w") as f:
        json.dump({"sent": count, "bytes": count * (len(latest[0]) + pad), "seconds": seconds,
                   "step": int(base["k"])}, f)
    return 0


def duplicates(endpoint: str, run: str, report: str, offsets_m: list[float], steps: int) -> int:
    """Every node's round-1 prior re-issued early for the next step, once per offset (module docstring)."""
    forged: dict[int, list[int]] = {}
    done = threading.Event()
    lock = threading.Lock()
    with zenoh.open(attacker_config(endpoint)) as session:
        pubs: dict[int, zenoh.Publisher] = {}
        mine: set[bytes] = set()

        def on_prior(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            victim = int(str(sample.key_expr).rsplit("/", 1)[1])
            with lock:
                if done.is_set() or payload in mine or len(forged.get(victim, [])) >= steps:
                    return
                outs = []
                for off in offsets_m:
                    try:
                        out = forge_prior(payload, victim, np.array([off]))
                    except WireError:
                        return
                    if out is None:
                        return
                    outs.append(out)
                if victim not in pubs:
                    pubs[victim] = session.declare_publisher(f"zentrack/{run}/prior/{victim}")
                for _, raw in outs:
                    mine.add(raw)
                    pubs[victim].put(raw)
                forged.setdefault(victim, []).append(outs[0][0])
                if len(forged) >= 2 and all(len(v) >= steps for v in forged.values()):
                    done.set()

        sub = session.declare_subscriber(f"zentrack/{run}/prior/*", on_prior)
        finished = done.wait(timeout=max(60.0, steps * 0.5))
        sub.undeclare()
        for pub in pubs.values():
            pub.undeclare()
    with open(report, "w") as f:
        json.dump({"forged": {str(j): len(v) for j, v in forged.items()}, "copies": len(offsets_m),
                   "first_step": min((v[0] for v in forged.values()), default=None),
                   "last_step": max((v[-1] for v in forged.values()), default=None), "finished": finished}, f)
    return 0 if finished else 1


def garbage(endpoint: str, run: str, report: str, key: str, rate: float, seconds: float) -> int:
    """Undecodable bytes on one key at ``rate`` messages per second for ``seconds``."""
    rng = np.random.default_rng(7)
    sent = 0
    with zenoh.open(attacker_config(endpoint)) as session:
        pub = session.declare_publisher(f"zentrack/{run}/{key}")
        start = time.time()
        while time.time() - start < seconds:
            pub.put(rng.bytes(64))
            sent += 1
            lag = start + sent / rate - time.time()
            if lag > 0:
                time.sleep(lag)
        pub.undeclare()
    with open(report, "w") as f:
        json.dump({"sent": sent, "seconds": seconds, "key": key}, f)
    return 0


def main() -> int:
    endpoint, run, report, kind = sys.argv[1:5]
    if kind == "dup":
        return duplicates(endpoint, run, report, [float(x) for x in sys.argv[5].split(",")], int(sys.argv[6]))
    if kind == "garbage":
        return garbage(endpoint, run, report, sys.argv[5], float(sys.argv[6]), float(sys.argv[7]))
    if kind == "ctl":  # ctl stop|start: forge the truth's control message every 0.1 s, COUNT times
        what, count = sys.argv[5], int(sys.argv[6])
        with zenoh.open(attacker_config(endpoint)) as session:
            pub = session.declare_publisher(f"zentrack/{run}/ctl/{what}", congestion_control=zenoh.CongestionControl.BLOCK)
            for _ in range(count):
                payload = Stop(10**6).encode() if what == "stop" else Start(
                    time.time() - 120.0, 0.1, 10**6, "realtime", (0, 1, 2, 3, 4, 5), 0.5, np.zeros(12)).encode()
                pub.put(payload)
                time.sleep(0.1)
            pub.undeclare()
        with open(report, "w") as f:
            json.dump({"ctl": what, "sent": count}, f)
        return 0
    if kind == "token":  # held until the run's ctl/stop (at most SECONDS): the whole run sees it, if anyone does
        conf = attacker_config(endpoint)
        stopped = threading.Event()
        with zenoh.open(conf) as session:
            sub = session.declare_subscriber(f"zentrack/{run}/ctl/stop", lambda _: stopped.set())
            token = session.liveliness().declare_token(f"zentrack/{run}/alive/{sys.argv[5]}")
            saw_stop = stopped.wait(float(sys.argv[6]))
            token.undeclare()
            sub.undeclare()
        with open(report, "w") as f:
            json.dump({"token": sys.argv[5], "held_until_stop": saw_stop}, f)
        return 0
    if kind == "flood":
        return flood(endpoint, run, report, int(sys.argv[5]), int(sys.argv[6]), int(sys.argv[7]))
    if kind != "prior":
        print(f"forger: unknown attack {kind!r}", file=sys.stderr)
        return 2
    victim, offset_m, steps = int(sys.argv[5]), float(sys.argv[6]), int(sys.argv[7])
    offset = np.array([offset_m])
    forged: list[int] = []
    done = threading.Event()
    conf = attacker_config(endpoint)
    with zenoh.open(conf) as session:
        pub = session.declare_publisher(f"zentrack/{run}/prior/{victim}", congestion_control=zenoh.CongestionControl.BLOCK)

        mine: set[bytes] = set()  # our own forgeries come back to our subscriber: never forge from them

        def on_prior(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            if done.is_set() or payload in mine:
                return
            try:
                out = forge_prior(payload, victim, offset)
            except WireError:
                return
            if out is None:
                return
            mine.add(out[1])
            pub.put(out[1])
            forged.append(out[0])
            if len(forged) >= steps:
                done.set()

        sub = session.declare_subscriber(f"zentrack/{run}/prior/{victim}", on_prior)
        finished = done.wait(timeout=max(60.0, steps * 2.0))
        sub.undeclare()
        pub.undeclare()
    with open(report, "w") as f:
        json.dump({"forged": len(forged), "first_step": forged[0] if forged else None,
                   "last_step": forged[-1] if forged else None, "finished": finished}, f)
    return 0 if finished else 1


if __name__ == "__main__":
    sys.exit(main())
