"""What ``zentrack bench scale`` reads from the kernel beside CPU: memory per process, bytes per router link.

Memory: resident memory (``VmRSS`` of ``/proc/<pid>/status``) and proportional set size (``Pss`` of
``/proc/<pid>/smaps_rollup``: each shared page divided among the processes that map it, so the Pss of all
processes adds up to the memory they take together), per process type, mean and max over its processes.

Router links: the kernel's own TCP counters of every socket of the router's listening port (``ss -tinp``:
``bytes_sent``, ``bytes_received``, ``data_segs_out``, ``data_segs_in`` per socket, and the pid owning each end),
so each link is named by the process at its other end. Bytes are TCP payload (Zenoh's frames, without the
TCP/IP headers); a data segment is one write of one or more batched Zenoh messages (Zenoh sets TCP_NODELAY and
flushes a batch per write), so segments per second bound the messages per second from below. Zenoh 1.10's
Python wheel answers no transport statistics on its admin space (``?_stats=true`` gives none; the ``stats``
feature is not built in), hence the kernel's counters.
"""
from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

#: the counters of one ``ss -tin`` socket that the bench keeps
COUNTERS = ("bytes_sent", "bytes_received", "data_segs_out", "data_segs_in")
_ADDRESS = re.compile(r"^(?:\[?[0-9a-fA-F.:*%]+\]?):(\d+)$")
_PID = re.compile(r"pid=(\d+)")
_COUNTER = re.compile(r"\b(" + "|".join(COUNTERS) + r"):(\d+)")


def memory_mb(pid: int) -> dict[str, float] | None:
    """``{"rss_mb", "pss_mb"}`` of process ``pid`` now (MB = 10^6 bytes), None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        rollup = Path(f"/proc/{pid}/smaps_rollup").read_text()
    except OSError:
        return None
    rss = re.search(r"^VmRSS:\s+(\d+) kB", status, re.M)
    pss = re.search(r"^Pss:\s+(\d+) kB", rollup, re.M)
    if rss is None or pss is None:  # a zombie has no memory lines
        return None
    return {"rss_mb": int(rss.group(1)) * 1024 / 1e6, "pss_mb": int(pss.group(1)) * 1024 / 1e6}


def memory_per_type(samples: dict[str, dict[str, float]], kind_of: Callable[[str], str]) -> dict[str, dict[str, float]]:
    """Per process type (``kind_of(name)``): mean and max over its processes of RSS and Pss (MB)."""
    per: dict[str, list[dict[str, float]]] = {}
    for name, sample in samples.items():
        per.setdefault(kind_of(name), []).append(sample)
    out = {}
    for kind, group in sorted(per.items()):
        rss, pss = [s["rss_mb"] for s in group], [s["pss_mb"] for s in group]
        out[kind] = {"rss_mean_mb": sum(rss) / len(rss), "rss_max_mb": max(rss), "pss_mean_mb": sum(pss) / len(pss),
                     "pss_max_mb": max(pss), "processes": len(group)}
    return out


@dataclass(frozen=True)
class Socket:
    """One established TCP socket as ``ss -tinp`` shows it: its ports, its owner and its counters."""

    local_port: int
    peer_port: int
    pid: int | None
    counters: dict[str, int]


def parse_ss(text: str) -> list[Socket]:
    """The sockets of ``ss -tinpH state established`` output (a socket line, then its indented TCP-info line)."""
    sockets: list[Socket] = []
    head: list[str] | None = None
    for line in text.splitlines():
        if not line.strip():
            continue
        if not line[0].isspace():
            head = line.split()
            continue
        if head is None:
            continue
        ports = [int(m.group(1)) for t in head if (m := _ADDRESS.match(t))]
        pid = _PID.search(" ".join(head))
        if len(ports) >= 2:
            counters = {k: 0 for k in COUNTERS} | {k: int(v) for k, v in _COUNTER.findall(line)}
            sockets.append(Socket(ports[0], ports[1], int(pid.group(1)) if pid else None, counters))
        head = None
    return sockets


def router_sockets(port: int) -> list[Socket] | None:
    """Every established TCP socket with an end on ``port`` (both ends of each link), None without ``ss``."""
    ss = shutil.which("ss")
    if ss is None:
        return None
    done = subprocess.run([ss, "-tinpH", "state", "established", f"( sport = :{port} or dport = :{port} )"],
                          capture_output=True, text=True, timeout=10)
    return parse_ss(done.stdout) if done.returncode == 0 else None


def link_counters(sockets: list[Socket], port: int, names: dict[int, str]) -> dict[str, dict[str, int]]:
    """Per peer process (``names``: pid -> name; an unknown pid is ``pid <n>``): the router side's counters of
    its links to ``port``, summed (``bytes_received`` = from the peer to the router)."""
    owner = {s.local_port: s.pid for s in sockets if s.peer_port == port and s.local_port != port}
    out: dict[str, dict[str, int]] = {}
    for s in sockets:
        if s.local_port != port:
            continue
        pid = owner.get(s.peer_port)
        name = names.get(pid, f"pid {pid}") if pid is not None else f"port {s.peer_port}"
        total = out.setdefault(name, {k: 0 for k in COUNTERS})
        for k in COUNTERS:
            total[k] += s.counters[k]
    return out


def link_rates(before: dict[str, dict[str, int]], after: dict[str, dict[str, int]], seconds: float,
               kind_of: Callable[[str], str]) -> dict:
    """Bytes and TCP data segments per second on each router link over ``seconds`` (links present at both
    samples), per process type (mean and max over its links of both directions together) and in total."""
    links = {}
    for name in sorted(before.keys() & after.keys()):
        d = {k: max(0, after[name][k] - before[name][k]) / seconds for k in COUNTERS}
        links[name] = {"bytes_to_router_per_s": d["bytes_received"], "bytes_from_router_per_s": d["bytes_sent"],
                       "segments_to_router_per_s": d["data_segs_in"], "segments_from_router_per_s": d["data_segs_out"]}
    per: dict[str, list[float]] = {}
    for name, r in links.items():
        per.setdefault(kind_of(name), []).append(r["bytes_to_router_per_s"] + r["bytes_from_router_per_s"])
    to_router = sum(r["bytes_to_router_per_s"] for r in links.values())
    from_router = sum(r["bytes_from_router_per_s"] for r in links.values())
    return {"links": links, "seconds": seconds,
            "per_type": {k: {"mean_bytes_per_s": sum(v) / len(v), "max_bytes_per_s": max(v), "links": len(v)}
                         for k, v in sorted(per.items())},
            "total_bytes_per_s": to_router + from_router, "bytes_to_router_per_s": to_router,
            "bytes_from_router_per_s": from_router,
            "segments_per_s": sum(r["segments_to_router_per_s"] + r["segments_from_router_per_s"]
                                  for r in links.values())}
