"""Impaired links between two services of the namespace harness: delay, jitter, loss and a rate limit.

``zentrack netns impair A B --delay-ms 30 --jitter-ms 10 --loss 0.05 [--rate-kbit N]`` impairs the path between
services A and B, each direction alike (as netem on both ends would); ``zentrack netns clear A B`` restores it.
Only A-B traffic is impaired: A's host route to B's address (and B's to A's, from the service's own address,
so connections already open carry on) sends it over a link of its own. Backends:

- **netem** (kernels with ``sch_netem``): a veth pair from A's namespace to B's, a netem qdisc on each end.
- **userspace** (no netem, as on the build machines): a TUN device in each namespace and a forwarder process
  per end (``python -m zentrack.cluster.engines.link_impair forward``, under ``ip netns exec``) that reads IP
  packets from its TUN and sends them as UDP datagrams over the bridge (its socket bound to ``eth0``, so the host
  route does not loop them back) to the other end, whose forwarder decides each packet's fate with
  :class:`LinkModel` before writing it into its TUN. Real packets are delayed or lost: TCP (Zenoh's links)
  retransmits and backs off as on such a link.

:class:`LinkModel`, per direction: Bernoulli loss per packet; a token-bucket rate (each packet leaves once
those before it are serialised; tail drop beyond :data:`QUEUE_LIMIT_S` of backlog); then the delay plus a
uniform jitter in ``[-J, +J]`` (netem's default distribution), **order preserved**: a packet is never
delivered before the one ahead of it (netem reorders under jitter; real paths seldom do, and reordering
would add TCP fast retransmits that are the harness's, not the network's). ``auto`` picks netem where the
kernel has it, else the userspace link.
"""
from __future__ import annotations

import argparse
import contextlib
import fcntl
import math
import os
import random
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import deque
from dataclasses import asdict, dataclass

#: the rate limiter drops a packet that would wait longer than this behind the ones queued before it
QUEUE_LIMIT_S = 0.5
#: the UDP port of the first userspace link's forwarders (the n-th link uses PORT_BASE + n)
PORT_BASE = 47100
BACKENDS = ("auto", "netem", "userspace")
_TUNSETIFF, _IFF_TUN, _IFF_NO_PI = 0x400454CA, 0x0001, 0x1000
_SO_BINDTODEVICE = getattr(socket, "SO_BINDTODEVICE", 25)
_IP_MTU_DISCOVER, _IP_PMTUDISC_DONT = 10, 0  # Linux's values (not exported by Python's socket module)


@dataclass(frozen=True)
class Impairment:
    """What a link does to every packet, each direction alike."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    loss: float = 0.0
    rate_kbit: float | None = None

    def validate(self) -> Impairment:
        """Raise ValueError naming the flag at fault."""
        for flag, value, top in (("--delay-ms", self.delay_ms, 10_000.0), ("--jitter-ms", self.jitter_ms, 10_000.0)):
            if not (math.isfinite(value) and 0 <= value <= top):
                raise ValueError(f"{flag} must be from 0 to {top:.0f}, got {value}")
        if self.jitter_ms > self.delay_ms:
            raise ValueError(f"--jitter-ms ({self.jitter_ms}) must not exceed --delay-ms ({self.delay_ms})")
        if not (math.isfinite(self.loss) and 0 <= self.loss < 1):
            raise ValueError(f"--loss is a probability from 0 to below 1, got {self.loss}")
        if self.rate_kbit is not None and not (math.isfinite(self.rate_kbit) and 8 <= self.rate_kbit <= 10_000_000):
            raise ValueError(f"--rate-kbit must be from 8 to 10000000, got {self.rate_kbit}")
        return self

    def to_arg(self) -> str:
        """The impairment as one command-line word (for the forwarder), read back by :meth:`from_arg`."""
        return ",".join("" if v is None else str(v) for v in asdict(self).values())

    @classmethod
    def from_arg(cls, word: str) -> Impairment:
        delay, jitter, loss, rate = (float(v) if v else None for v in word.split(","))
        return cls(delay or 0.0, jitter or 0.0, loss or 0.0, rate).validate()

    def netem_args(self) -> list[str]:
        args = ["delay", f"{self.delay_ms}ms", f"{self.jitter_ms}ms", "loss", f"{100 * self.loss}%"]
        return args + (["rate", f"{self.rate_kbit}kbit"] if self.rate_kbit else [])


class LinkModel:
    """One direction of an impaired link: each packet's fate, from the time it comes in and its size."""

    def __init__(self, imp: Impairment, rng: random.Random) -> None:
        self.imp, self.rng = imp, rng
        self.busy_until = -math.inf  # when the rate limiter has serialised every packet admitted so far
        self.last_delivery = -math.inf
        self.lost = self.overflow = self.passed = 0

    def admit(self, now: float, size: int) -> float | None:
        """When a packet of ``size`` bytes that comes in at ``now`` is delivered; None when it is lost."""
        imp = self.imp
        if imp.loss and self.rng.random() < imp.loss:
            self.lost += 1
            return None
        leave = now
        if imp.rate_kbit:
            start = max(now, self.busy_until)
            if start - now > QUEUE_LIMIT_S:
                self.overflow += 1
                return None
            self.busy_until = leave = start + size * 8 / (imp.rate_kbit * 1000)
        jitter = self.rng.uniform(-imp.jitter_ms, imp.jitter_ms) if imp.jitter_ms else 0.0
        deliver = max(leave + max(0.0, imp.delay_ms + jitter) / 1000, self.last_delivery)
        self.last_delivery = deliver
        self.passed += 1
        return deliver


class DelayLine:
    """Packets waiting for their delivery time (in order: :class:`LinkModel` never reorders)."""

    def __init__(self) -> None:
        self.queue: deque[tuple[float, bytes]] = deque()

    def push(self, when: float, packet: bytes) -> None:
        self.queue.append((when, packet))

    def due(self, now: float) -> list[bytes]:
        out = []
        while self.queue and self.queue[0][0] <= now:
            out.append(self.queue.popleft()[1])
        return out

    def next_time(self) -> float | None:
        return self.queue[0][0] if self.queue else None


# ---------------------------------------------------------------------- the userspace forwarder (one per end)
def open_tun(name: str) -> int:
    """Attach to the TUN device ``name`` (created beforehand with ``ip tuntap``); returns its descriptor."""
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, _TUNSETIFF, struct.pack("16sH", name.encode(), _IFF_TUN | _IFF_NO_PI))
    return fd


def forward(tun: str, local: str, peer: str, port: int, imp: Impairment, seed: int, dev: str = "eth0") -> None:
    """Move packets between TUN ``tun`` and the peer forwarder at ``peer:port``, impairing those that come in."""
    fd = open_tun(tun)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, _SO_BINDTODEVICE, dev.encode())
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sock.setsockopt(socket.IPPROTO_IP, _IP_MTU_DISCOVER, _IP_PMTUDISC_DONT)
    sock.bind((local, port))
    sock.setblocking(False)
    model, line = LinkModel(imp, random.Random(seed)), DelayLine()
    print(f"forwarding {tun} <-> {peer}:{port} ({asdict(imp)})", flush=True)
    while True:
        nxt = line.next_time()
        wait = 1.0 if nxt is None else max(0.0, nxt - time.monotonic())
        ready, _, _ = select.select([fd, sock.fileno()], [], [], wait)
        if fd in ready:
            for _ in range(256):
                try:
                    sock.sendto(os.read(fd, 65535), (peer, port))
                except BlockingIOError:
                    break
                except OSError:  # the peer's end is not there yet (ICMP refused): the packet is lost
                    continue
        if sock.fileno() in ready:
            for _ in range(256):
                try:
                    packet, (sender, _) = sock.recvfrom(65535)
                except BlockingIOError:
                    break
                except OSError:
                    continue
                when = model.admit(time.monotonic(), len(packet)) if sender == peer else None
                if when is not None:
                    line.push(when, packet)
        for packet in line.due(time.monotonic()):
            with contextlib.suppress(OSError):  # a TUN queue full: the packet is lost
                os.write(fd, packet)


# ---------------------------------------------------------------------- setting a link up and clearing it
def _run(*cmd: str) -> subprocess.CompletedProcess:
    return subprocess.run(list(cmd), capture_output=True, text=True, timeout=30)


def _must(*cmd: str) -> None:
    done = _run(*cmd)
    if done.returncode:
        raise ValueError(f"{' '.join(cmd)}: {' '.join((done.stderr or '').split()) or f'exit status {done.returncode}'}")


def pair_key(a: str, b: str) -> str:
    return "|".join(sorted((a, b)))


def setup_link(tag: str, index: int, ends: dict[str, tuple[str, str]], imp: Impairment, backend: str,
               logdir: str) -> dict:
    """Impair the path between two services; ``ends`` maps each service to (namespace, address). Returns what
    was made (devices, routes, forwarder pids), for :func:`clear_link`. Raises ValueError (after removing
    what it made) when the chosen backend cannot be set up."""
    if backend not in BACKENDS:
        raise ValueError(f"--impair-backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    made: dict = {"backend": backend, "impairment": asdict(imp), "ends": {s: list(e) for s, e in ends.items()},
                  "devices": [], "pids": []}
    (a, (ns_a, addr_a)), (b, (ns_b, addr_b)) = ends.items()
    try:
        if backend in ("auto", "netem"):
            veth_a, veth_b = f"zt{tag}n{index}a", f"zt{tag}n{index}b"
            _must("ip", "-n", ns_a, "link", "add", veth_a, "type", "veth", "peer", "name", veth_b, "netns", ns_b)
            made["devices"] = [[ns_a, veth_a], [ns_b, veth_b]]
            netem = [_run("ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root", "netem",
                          *imp.netem_args()) for ns, dev in made["devices"]]
            if all(done.returncode == 0 for done in netem):
                made["backend"] = "netem"
                _route(made, veth_a, veth_b)
                return made
            _delete_devices(made)
            if backend == "netem":
                why = next(" ".join(d.stderr.split()) for d in netem if d.returncode)
                raise ValueError(f"--impair-backend netem: the kernel's netem qdisc is not available ({why}); "
                                 f"use --impair-backend userspace")
        made["backend"] = "userspace"
        tun = f"zt{tag}i{index}"
        port = PORT_BASE + index
        for ns in (ns_a, ns_b):
            _must("ip", "-n", ns, "tuntap", "add", "mode", "tun", "name", tun)
            made["devices"].append([ns, tun])
            _must("ip", "-n", ns, "link", "set", tun, "up")
            for conf in ("all", "eth0", tun):  # the UDP datagrams come in on eth0 from an address routed via the TUN
                _run("ip", "netns", "exec", ns, "sysctl", "-qw", f"net.ipv4.conf.{conf}.rp_filter=0")
        for j, (ns, local, peer) in enumerate(((ns_a, addr_a, addr_b), (ns_b, addr_b, addr_a))):
            log = open(os.path.join(logdir, f"impair-{a}-{b}-{j}.log"), "ab")
            proc = subprocess.Popen(
                ["ip", "netns", "exec", ns, sys.executable, "-m", "zentrack.cluster.engines.link_impair", "forward",
                 tun, local, peer, str(port), imp.to_arg(), str(index * 2 + j)],
                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
            log.close()
            made["pids"].append(proc.pid)
        _wait_carrier(made, logdir)
        _route(made, tun, tun)
        return made
    except BaseException:
        clear_link(made)
        raise


def _wait_carrier(made: dict, logdir: str, timeout: float = 10.0) -> None:
    """Wait until both forwarders hold their TUN (the device has a carrier then)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for pid in made["pids"]:
            if os.waitpid(pid, os.WNOHANG)[0]:
                raise ValueError(f"a forwarder of the userspace link exited at once (its log: {logdir}/impair-*.log)")
        states = [_run("ip", "-n", ns, "-o", "link", "show", dev).stdout for ns, dev in made["devices"]]
        if all("NO-CARRIER" not in s and "LOWER_UP" in s for s in states):
            return
        time.sleep(0.05)
    raise ValueError(f"the userspace link's forwarders did not attach to their TUN devices within {timeout:.0f} s")


def _route(made: dict, dev_a: str, dev_b: str) -> None:
    """Each end's host route to the other's address over the impaired link, from its own address."""
    (ns_a, addr_a), (ns_b, addr_b) = made["ends"].values()
    for ns, dev, dst, src in ((ns_a, dev_a, addr_b, addr_a), (ns_b, dev_b, addr_a, addr_b)):
        _must("ip", "-n", ns, "route", "replace", f"{dst}/32", "dev", dev, "src", src)
    made["routes"] = [[ns_a, addr_b], [ns_b, addr_a]]


def _delete_devices(made: dict) -> None:
    for ns, dev in made.get("devices", []):
        _run("ip", "-n", ns, "link", "del", dev)
    made["devices"] = []


def clear_link(made: dict) -> None:
    """Undo :func:`setup_link`: routes first (traffic goes straight over the bridge again), then the forwarders
    and the devices. Whatever is gone already (a namespace removed) is skipped."""
    for ns, dst in made.get("routes", []):
        _run("ip", "-n", ns, "route", "del", f"{dst}/32")
    for pid in made.get("pids", []):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):  # reaped here when this process started it
            os.waitpid(pid, 0)
    _delete_devices(made)


def add_impair_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--delay-ms", type=float, default=0.0, help="impair: one-way delay of each direction (ms)")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="impair: uniform jitter +- this (ms), order kept")
    p.add_argument("--loss", type=float, default=0.0, help="impair: probability a packet is lost (0 to <1)")
    p.add_argument("--rate-kbit", type=float, default=None, help="impair: rate limit of each direction (kbit/s)")
    p.add_argument("--impair-backend", default="auto", choices=BACKENDS,
                   help="netem (kernel qdisc), userspace (TUN + forwarder) or auto: netem where the kernel has it")


def impairment_from_args(args: argparse.Namespace) -> Impairment:
    return Impairment(args.delay_ms, args.jitter_ms, args.loss, args.rate_kbit).validate()


if __name__ == "__main__" and len(sys.argv) == 8 and sys.argv[1] == "forward":
    _tun, _local, _peer, _port, _imp, _seed = sys.argv[2:]
    forward(_tun, _local, _peer, int(_port), Impairment.from_arg(_imp), int(_seed))
