"""The PMBM filter (``fusion/multitarget/pmbm.py``) as a centralized tracker over one simulated many-target run: the
``pmbm`` row of ``zentrack bench multitarget`` (issue 53).

It gets what the other methods get (:class:`~zentrack.fusion.multitarget.network.TrackerSettings`: the plant, the
point measurement model with each scan's noise, P_D and the clutter density, the gate) and, instead of two-point
initiation and M-of-N confirmation, a Poisson intensity of undetected targets spread evenly over what the sensors
watch (:class:`~zentrack.fusion.multitarget.pmbm.UniformIntensity`): :data:`~zentrack.fusion.multitarget.pmbm_tracker.INITIAL_DENSITY` at the start
and :data:`~zentrack.fusion.multitarget.pmbm_tracker.BIRTH_DENSITY` more a step, in units of the clutter density (as many undetected targets at the start as clutter
returns in a scan; a hundredth of that born a step), new tracks' velocity spread ``max_speed / 2`` per axis. Every
sensor's scan of a step is one update, in sensor order, one prediction between steps; the estimate of a step is the
best global hypothesis's tracks of existence at least 0.5. Point sensors only (bearing-only births need a range
spread along each ray): other networks are refused in one line.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import replace

from zentrack.fusion.multitarget.network import TrackerSettings, make_pmbm_tracker
from zentrack.truth.simulation.multitarget import MultiTargetData

from .multitarget_runs import MethodRun

#: why a network the PMBM does not take is left out
POINT_ONLY = "the PMBM tracker takes point sensors only (bearing-only births are not built)"


def takes(s: TrackerSettings | Sequence[TrackerSettings]) -> bool:
    """Whether the PMBM runs on a network of these settings (one for all, or every node's): point sensors only."""
    return all(x.measurement == "point" for x in ([s] if isinstance(s, TrackerSettings) else s))


def run_pmbm(data: MultiTargetData, s: TrackerSettings | Sequence[TrackerSettings],
             max_range: float = math.inf) -> MethodRun:
    """The PMBM filter on every sensor's scan of each step (``s``: every node's settings, or one for all; every
    sensor a point sensor, else ValueError; ``max_range``: the sensors' range, beyond which a scan misses nothing)."""
    settings = [s] * data.nodes if isinstance(s, TrackerSettings) else list(s)
    if not takes(settings):
        raise ValueError(POINT_ONLY)
    pmbm = make_pmbm_tracker(replace(settings[0], max_range=max_range)).pmbm
    out, seconds = [], 0.0
    for k in range(data.steps):
        scans = [data.scan(k, i) for i in range(data.nodes)]
        t0 = time.perf_counter()
        if k:
            pmbm.predict()
        for scan in scans:
            pmbm.update(scan)
        ids, _, est = pmbm.estimates()
        seconds += time.perf_counter() - t0
        out.append(([int(i) for i in ids], est.mean[:, :3].copy()))
    return MethodRun("pmbm", [out], seconds, data.steps * data.nodes)
