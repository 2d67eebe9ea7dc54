"""What a test or the whole suite left behind on the host: processes, network namespaces and bridges, listening
ports. ``conftest.py`` checks after every slow test (what that test started) and once after the suite (what any
test started, on any xdist worker); what is found is named in the failure, and processes are killed.

Processes are told apart by marks in their environment, which every child inherits: ``ZENTRACK_TEST_SESSION``
is the pid of the pytest process that runs the test (an xdist worker), ``ZENTRACK_TEST_RUN`` the pid of the
pytest process the suite was started with (the same for every worker). Processes of other suites or of a
cluster the developer runs meanwhile carry neither, and are never flagged or killed.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from collections.abc import Callable

from zentrack.common.procs import process_running

#: command-line words of the processes the per-test check looks for (the suite-wide check takes any marked one)
WATCHED = ("zentrack", "rerun", "chromium")
#: names of the harness's and the swarm workers' namespaces and bridges (``zt<tag>-<service>``, ``zt<tag>br``)
NAMESPACE_PATTERN = re.compile(r"\bzt[a-z0-9]*(?:br|-[a-z0-9-]+)\b")


def _environ_has(pid: str, mark: bytes) -> bool:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            return mark in f.read().split(b"\0")
    except OSError:
        return False


def _descends_from(pid: int, ancestor: int) -> bool:
    for _ in range(64):
        try:
            with open(f"/proc/{pid}/stat") as f:
                pid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            return False
        if pid == ancestor:
            return True
        if pid <= 1:
            return False
    return False


def marked_processes(mark: str | None, watched: tuple[str, ...] | None = WATCHED,
                     ancestor: int | None = None) -> dict[int, str]:
    """pid -> command line of every running process (a zombie whose threads are gone is not) that carries
    ``mark`` (``NAME=VALUE``; None: any process) in its environment or descends from ``ancestor``; with
    ``watched``, only those whose command line holds one of its words. This process is never listed."""
    found, me = {}, os.getpid()
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == me:
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if not process_running(int(pid)) or watched is not None and not any(w in cmd for w in watched):
            continue
        if (mark is None or _environ_has(pid, mark.encode())
                or ancestor is not None and _descends_from(int(pid), ancestor)):
            found[int(pid)] = cmd[:160] or f"[pid {pid}]"
    return found


def namespaces_and_bridges() -> set[str]:
    names = set()
    for argv in (["ip", "netns", "list"], ["ip", "-o", "link"]):
        try:
            out = subprocess.run(argv, capture_output=True, text=True, timeout=10).stdout
        except (OSError, subprocess.TimeoutExpired):
            continue
        names |= set(NAMESPACE_PATTERN.findall(out))
    return names


def listening_ports() -> set[int]:
    """The TCP ports something listens on, on any address (``/proc/net/tcp`` and ``tcp6``, state 0A)."""
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table) as f:
                rows = f.read().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if len(fields) > 3 and fields[3] == "0A":
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def wait_gone(find: Callable[[], dict | set], timeout: float) -> dict | set:
    """Poll ``find()`` until it finds nothing or ``timeout`` seconds have passed; what it found last."""
    end = time.monotonic() + timeout
    while True:
        found = find()
        if not found or time.monotonic() > end:
            return found
        time.sleep(0.1)


def kill(pids) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
