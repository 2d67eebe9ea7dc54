"""Process helpers shared by every zentrack process and the tools that start them: one log format, a stop flag
set by SIGTERM/SIGINT, a frozen heap for long runs, children that die with their parent, whether a process still
runs, signals to a whole process group, and the processes of a run (and their memory, threads and CPU time) found through ``/proc``."""
from __future__ import annotations

import gc
import logging
import os
import signal
import subprocess
import sys
import time

#: how soon :meth:`StopFlag.wait` notices the flag (the longest sleep between two looks at it)
WAIT_SLICE_S = 0.05


class StopFlag:
    """Set by SIGTERM/SIGINT so the main loop can close the session and exit cleanly.

    The handler only assigns a bool: Python runs a handler between any two bytecodes of the main thread, a
    second signal's handler inside the first one too, so a handler that takes a lock (``threading.Event.set``
    takes its condition's) deadlocks when a signal arrives while that lock is held. A tracker whose
    orchestrator died hung so, in its second SIGTERM's handler, and outlived the run (docs/testing.md).
    """

    def __init__(self, handle_signals: bool = True) -> None:
        self._stopped = False
        if handle_signals:
            for sig in (signal.SIGTERM, signal.SIGINT):
                signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame: object) -> None:
        self._stopped = True

    def set(self) -> None:
        self._stopped = True

    def __bool__(self) -> bool:
        return self._stopped

    def wait(self, timeout: float | None = None) -> bool:
        """Sleep until the flag is set or ``timeout`` seconds have passed (None: no limit); the flag. The
        flag is looked at every :data:`WAIT_SLICE_S` at most."""
        end = None if timeout is None else time.monotonic() + max(0.0, timeout)
        while not self._stopped:
            left = WAIT_SLICE_S if end is None else end - time.monotonic()
            if left <= 0:
                break
            time.sleep(min(left, WAIT_SLICE_S))
        return self._stopped


def setup_logging() -> None:
    """One log format for every process (stderr; the orchestrator sends it to <out>/logs/<name>.log)."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s", stream=sys.stderr)


def processes_of_runs(runs: list[str], exclude: str | None = None) -> list[str]:
    """Command lines (first 200 characters) of processes started with ``--run <name>`` for one of ``runs``
    (this process and any whose command line contains ``exclude`` are left out)."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            cmd = open(f"/proc/{pid}/cmdline", "rb").read().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if any(f"--run {r} " in cmd + " " for r in runs) and not (exclude and exclude in cmd):
            found.append(cmd[:200])
    return found


def process_status(pid: int) -> dict[str, float]:
    """Resident memory (``rss_mb``, VmRSS in MiB), its peak (``hwm_mb``, VmHWM), the number of threads and the CPU
    time used so far (``cpu_s``, user + system) of process ``pid``, from ``/proc``; OSError if it is gone."""
    with open(f"/proc/{pid}/status") as f:
        fields = dict(line.split(":", 1) for line in f if ":" in line)
    with open(f"/proc/{pid}/stat") as f:
        stat = f.read().rsplit(")", 1)[1].split()  # after the command name, which may hold spaces
    ticks = os.sysconf("SC_CLK_TCK")
    return {"rss_mb": int(fields["VmRSS"].split()[0]) / 1024, "hwm_mb": int(fields["VmHWM"].split()[0]) / 1024,
            "threads": int(fields["Threads"]), "cpu_s": (int(stat[11]) + int(stat[12])) / ticks}


def freeze_heap() -> None:
    """Move everything allocated so far (imported modules, scenario arrays) out of the garbage collector's
    reach, so a full collection in a long-running process takes microseconds, not tens of milliseconds."""
    gc.collect()
    gc.freeze()


def without_openssl() -> None:
    """Keep OpenSSL's ``libcrypto`` (3.4 MB resident) out of a process that needs no cryptography of Python's.

    NumPy's random module imports ``secrets`` (for unseeded generators), which imports ``hashlib``, which loads
    OpenSSL through ``_hashlib``. A tracker seeds its generators and Zenoh does its own TLS (in Rust): with
    ``_hashlib`` marked absent, ``hashlib`` uses CPython's built-in hash functions instead (its documented
    fallback), and ``libcrypto`` is never mapped. Call it before anything imports ``numpy.random``."""
    if "_hashlib" not in sys.modules:
        sys.modules["_hashlib"] = None  # type: ignore[assignment]  # (an absent module, as the import system reads it)


def release_free_memory() -> bool:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim``): after a burst (a flood of large
    messages through Zenoh's buffers) the allocator otherwise keeps the peak. False where there is no such call."""
    try:
        import ctypes

        return bool(ctypes.CDLL(None).malloc_trim(0))
    except (OSError, AttributeError):
        return False


def die_with_parent() -> None:
    """In a child between fork and exec (``preexec_fn``): ask Linux to send SIGTERM when the parent dies, even
    by SIGKILL (``PR_SET_PDEATHSIG``). Best effort: a no-op where there is no such call."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def process_running(pid: int) -> bool:
    """Whether any thread of process ``pid`` still runs. A zombie whose threads have all exited counts as gone
    (its sockets and files are closed; it only waits for its parent to reap it), but a thread-group leader
    shows the zombie state while its other threads are still exiting and holding the process's files and
    ports (a multithreaded server killed by a signal), so every thread in ``/proc/<pid>/task`` is read."""
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return False
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X"):
                    return True
        except (OSError, IndexError):
            continue
    return False


def signal_group(proc: subprocess.Popen, sig: int) -> None:
    """Send ``sig`` to the process group ``proc`` leads (started with ``start_new_session=True``); a group that
    is already gone is not an error."""
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass
