"""A CPU hog: busy-loop processes at normal priority that keep a host's cores busy while a cluster runs.

``zentrack soak --cpu-hog N`` runs both of its runs beside N of them (a loaded host on purpose: each hog is
a plain ``while True: pass`` interpreter, as another user's work would be, neither niced nor pinned). The
hogs die with the soak (``PR_SET_PDEATHSIG``) and are stopped by pid when it ends; :meth:`CpuHog.stop`
returns what is reported: how many ran, their pids and the CPU seconds they took.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from zentrack.common.procs import die_with_parent

#: the most hog processes ``--cpu-hog`` takes
MAX_HOGS = 64

BUSY_LOOP = "while True: pass"


class CpuHog:
    """``count`` busy-loop processes, started by :meth:`start` and stopped by :meth:`stop`."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.procs: list[subprocess.Popen] = []
        self.started_at: float | None = None

    def start(self) -> None:
        self.started_at = time.time()
        for _ in range(self.count):
            self.procs.append(subprocess.Popen([sys.executable, "-c", BUSY_LOOP], stdin=subprocess.DEVNULL,
                                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                               start_new_session=True, preexec_fn=die_with_parent))

    def stop(self) -> dict:
        """Kill every hog (by its pid) and reap it; the report: count, pids, seconds run and CPU seconds."""
        cpu = 0.0
        for proc in self.procs:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
            _, _, usage = os.wait4(proc.pid, 0) if proc.returncode is None else (0, 0, None)
            if usage is not None:
                cpu += usage.ru_utime + usage.ru_stime
                proc.returncode = -signal.SIGKILL
        ran = 0.0 if self.started_at is None else time.time() - self.started_at
        report = {"processes": self.count, "pids": [p.pid for p in self.procs], "seconds": round(ran, 1),
                  "cpu_s": round(cpu, 1), "cores_busy": round(cpu / ran, 2) if ran > 0 else 0.0}
        self.procs = []
        return report

    def __enter__(self) -> CpuHog:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.procs:
            self.stop()
