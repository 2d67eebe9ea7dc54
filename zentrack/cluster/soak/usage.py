"""RSS and CPU over time per process type of a soak's run (issue 36): what an hour-long soak reports.

The soak samples every process's resident memory and CPU time every 10 s (:func:`cpu_seconds` beside
``soak_backends.rss_mib``); :func:`usage_by_type` bins the samples by minute and process type (``node``, ``truth``,
``router``, ``viewer``): the mean RSS per process (MiB) and the cores the type used (CPU seconds per second, summed
over its processes, a restarted one counted from its new pid).
"""
from __future__ import annotations

import os
from pathlib import Path

#: samples are binned this many seconds wide
BIN_S = 60.0


def cpu_seconds(pid: int) -> float | None:
    """The CPU time (user + system, s) process ``pid`` has used; None when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def process_type(name: str) -> str:
    """``node-3`` -> ``node``; a service's name is its type."""
    return name.split("-")[0]


def usage_by_type(rss: dict[str, list], cpu: dict[str, list], bin_s: float = BIN_S) -> dict[str, dict]:
    """Per process type: ``t_s`` (each bin's start), ``rss_mib`` (mean RSS per process in the bin) and
    ``cpu_cores`` (CPU seconds per second of all its processes in the bin); samples are ``(t, value, pid)``."""
    out: dict[str, dict] = {}
    rss_bins: dict[str, dict[int, list[float]]] = {}
    cpu_bins: dict[str, dict[int, float]] = {}
    for name, samples in rss.items():
        for t, value, _ in samples:
            rss_bins.setdefault(process_type(name), {}).setdefault(int(t // bin_s), []).append(value)
    for name, samples in cpu.items():
        for (t0, c0, p0), (t1, c1, p1) in zip(samples, samples[1:]):
            if p0 == p1 and t1 > t0:  # the same process between the two samples
                bins = cpu_bins.setdefault(process_type(name), {})
                bins[int(t1 // bin_s)] = bins.get(int(t1 // bin_s), 0.0) + (c1 - c0)
    for kind in sorted(set(rss_bins) | set(cpu_bins)):
        keys = sorted(set(rss_bins.get(kind, {})) | set(cpu_bins.get(kind, {})))
        out[kind] = {"t_s": [k * bin_s for k in keys],
                     "rss_mib": [round(sum(v) / len(v), 1) if (v := rss_bins.get(kind, {}).get(k)) else None
                                 for k in keys],
                     "cpu_cores": [round(cpu_bins.get(kind, {}).get(k, 0.0) / bin_s, 3) for k in keys]}
    return out
