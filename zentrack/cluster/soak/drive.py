"""One run of the soak driven to its end (:func:`run_one`): the backend started, the fault schedule's events
applied at their times, every process's RSS and CPU sampled, and what the run left (its recorder, the faults
applied, the samples, the exit codes) handed back for judging. The faulty run and the fault-free reference
are driven the same way, the reference with no events."""
from __future__ import annotations

import logging
import time

import numpy as np

from zentrack.cluster.soak.backends import rss_mib
from zentrack.cluster.soak.criteria import RSS_SAMPLE_S
from zentrack.cluster.soak.fault_kinds import brings_back, service_name
from zentrack.cluster.soak.priority import Prioritizer
from zentrack.cluster.soak.usage import cpu_seconds
from zentrack.common.progress import Progress

log = logging.getLogger("zentrack.soak")


def run_one(backend, events, duration: float, priority: Prioritizer | None = None, label: str = "soak") -> dict:
    """Run to the end, applying ``events``; returns the recorder, fault log, RSS samples and exit codes.
    ``priority`` raises the trackers, the truth and the router (each new process: a restarted one too).
    A progress line (on a terminal) counts the run's seconds and names the last fault applied."""
    priority = priority or Prioritizer(0)
    bar = Progress(int(round(duration)), "s", label=label)
    try:
        return _run_to_the_end(backend, events, duration, priority, bar)
    finally:
        bar.close()


def _run_to_the_end(backend, events, duration: float, priority: Prioritizer, bar: Progress) -> dict:
    rec = backend.start()
    priority.apply(backend.pids())
    end_wait = time.time() + 120
    while not rec.have().any() and time.time() < end_wait:
        rec.drain(0.1)
    t0 = time.time()
    seen = np.flatnonzero(rec.have().any(axis=1))
    first_step, ts = (int(seen[0]) if seen.size else 0), rec.scn.ts
    pending = list(events)
    rss: dict[str, list[tuple[float, float, int]]]
    cpu: dict[str, list[tuple[float, float, int]]] = {}  # (t, CPU seconds, pid) of every process
    applied, rss, next_sample = [], {}, t0

    def truth_comes_back() -> bool:  # a truth a fault ended (a kill) is started again before the run is over
        return any(target == "truth" and brings_back(a, target) for _, a, target in pending)

    while (backend.truth_running() or truth_comes_back()) and time.time() - t0 < duration + 120:
        rec.drain(0.05)
        now = time.time() - t0
        while pending and pending[0][0] <= now:
            t, action, target = pending.pop(0)
            moved = backend.act(action, target)  # a drain: the trackers it moved, each recorded as hit
            priority.apply(backend.pids())  # a restarted process: raised before its imports are done
            # the run's step by the clock (the recorder hears nothing while the router is down)
            step = min(first_step + int(round((time.time() - t0) / ts)), rec.scn.steps - 1)
            applied += [{"t": round(now, 2), "action": action, "node": hit, "step": step}
                        for hit in ([target] if moved is None else moved)]
            log.info("soak: t=%.1f s (step %d) %s %s", now, step, action,
                     service_name(target) if moved is None else f"(trackers {moved})")
            bar.note = f"{action} {service_name(target)} at {now:.0f} s"
        bar.update(min(int(now), bar.total or 0), bar.note)
        if time.time() >= next_sample:
            for name, pid in backend.pids().items():
                value = rss_mib(pid)
                if value is not None:
                    rss.setdefault(name, []).append((round(now, 1), value, pid))
                used = cpu_seconds(pid)
                if used is not None:
                    cpu.setdefault(name, []).append((round(now, 1), used, pid))
            next_sample += RSS_SAMPLE_S
    settle = time.time() + 10
    while time.time() < settle and any(c is None for n, c in backend.exit_codes().items()
                                       if n.startswith(("node", "viewer"))):
        rec.drain(0.1)
    rec.drain(0.5)
    codes = backend.exit_codes()
    return {"recorder": rec, "faults": applied, "rss": rss, "cpu": cpu, "exit_codes": codes,
            "priority": priority.report()}
