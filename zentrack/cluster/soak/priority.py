"""The CPU priority of a cluster's realtime processes (the trackers, the truth, the router, sensors of their own)
on a shared host.

A tracker sleeps most of each period, so ordinary work at the same priority hardly delays its steps; but a
restarted tracker is CPU-bound until it is ready (its imports), and beside busy processes it gets only its
share of the cores for that: on a 2-core host loaded to a dozen runnable tasks that is ~1/6 of a core, and
its ~0.2 s of CPU take 1-3 s. Raising the realtime processes above ordinary work makes that share several
times larger (``nice`` -10 weighs 9.3x a ``nice`` 0 process, -5 3.0x) while costing the others little (a
tracker uses a few per cent of a core).

Linux applies a process's ``nice`` only against the processes of its own session's **autogroup** when
``kernel.sched_autogroup_enabled`` is 1 and the process is in the root CPU cgroup (as here): a tracker
started in its own session (``start_new_session``) competes with every other session as a group, whatever
its ``nice``. So the group's nice is set too (``/proc/<pid>/autogroup``), for a process that leads its own
session only (never the soak's own). Lowering a nice value needs root or ``CAP_SYS_NICE``; without it the
processes keep their priority and the caller is told why.
"""
from __future__ import annotations

import os
from pathlib import Path

#: the nice value ``zentrack soak`` gives its trackers and truth by default (``--realtime-nice``)
REALTIME_NICE = -10


def raise_priority(pid: int, nice: int) -> str | None:
    """Give process ``pid`` (and its session's autogroup, if it leads that session) the nice value ``nice``;
    None when done, else why not (not permitted, or the process is gone)."""
    try:
        os.setpriority(os.PRIO_PROCESS, pid, nice)
        group = Path(f"/proc/{pid}/autogroup")
        if os.getsid(pid) == pid and os.getsid(pid) != os.getsid(0) and group.exists():
            group.write_text(str(nice))
    except PermissionError as exc:
        return f"not permitted ({exc.strerror}): needs root or CAP_SYS_NICE"
    except (ProcessLookupError, FileNotFoundError):
        return "the process is gone"
    except OSError as exc:
        return str(exc)
    return None


class Prioritizer:
    """Raise each realtime process of a run once (a restarted one gets a new pid, so it is raised again)."""

    def __init__(self, nice: int) -> None:
        self.nice = nice
        self.done: set[int] = set()
        self.raised = 0
        self.refused: dict[str, str] = {}  # service -> why its priority stayed

    def apply(self, pids: dict[str, int]) -> None:
        """``pids``: service name -> pid; the trackers (``node-*``), the truth, the router and the sensors of their
        own (``sensor-*``: a restarted one starts as slowly as a tracker, and its trackers wait for it) are
        raised (a restarted router starts as slowly as a tracker, and every message waits for it)."""
        if self.nice >= 0:
            return
        for name, pid in pids.items():
            if pid in self.done or not (name.startswith(("node-", "sensor-")) or name in ("truth", "router")):
                continue
            self.done.add(pid)
            why = raise_priority(pid, self.nice)
            if why is None:
                self.raised += 1
            else:
                self.refused[name] = why

    def report(self) -> dict:
        return {"nice": self.nice, "raised": self.raised, "refused": self.refused}
