"""The soak's faults: the seeded schedule of fault events (``schedule``), the plan ``--plan`` prints, and the
windows the applied faults span (``fault_windows``, the spans the error plot shades). What each kind of fault is
(its undo, flag, target, length, limits, colour, backend verbs) is its entry in the registry,
:mod:`zentrack.cluster.soak.fault_kinds`; everything here loops over it."""
from __future__ import annotations

import argparse

import numpy as np

from zentrack.cluster.soak.fault_kinds import (
    SENSOR,
    TRACKER,
    fault_actions,
    period,
    registered,
    sensor_takers,
    service_name,
    undo_actions,
)
from zentrack.transport.keys import sensor_name

#: seconds a tracker has to recover after a fault before the schedule gives it another
RECOVERY_S = 25.0

#: every fault ends at least this long before the soak does
END_MARGIN_S = 5.0
#: the longest soak :func:`least_duration` looks at
LONGEST_S = 86_400


def schedule(args: argparse.Namespace) -> list[tuple[float, str, int | str]]:
    """Seeded fault events ``(seconds after start, action, target)`` of every kind in the fault registry whose
    period is above 0, each kind's in turn: a target is a tracker index, a sensor's process (``sensor-<S>``, a
    sensor of its own: ``args.sensor_takers`` names the trackers that take each), ``truth`` or ``router``, or
    ``swarm`` for a node drain (``--drain-every``, ``--drain-s`` long: the stack backend picks the node when it
    applies it, and the soak records it once per tracker it moved). A tracker is never under two faults at once
    (a fault of a sensor it takes counts as its own), and gets :data:`RECOVERY_S` to recover before the next one
    (the least busy trackers are chosen when none is free); a sensor fault whose length is its sensor's (a clock
    step, until its trackers follow) picks among the sensors whose fault ends in time. Service and sensor faults
    start at an offset within their period (their kind's ``phase_s``) so that they do not coincide with the
    tracker faults."""
    rng = np.random.default_rng(args.seed + 7919)
    events: list[tuple[float, str, int | str]] = []
    busy: dict[int, list[tuple[float, float]]] = {i: [] for i in range(args.nodes)}
    takers = sensor_takers(args)

    def overlaps(trackers: list[int], window: tuple[float, float]) -> int:
        return sum(a < window[1] and window[0] < b for i in trackers for a, b in busy.get(i, []))

    end = args.duration - END_MARGIN_S
    for fault in registered():
        every = period(args, fault)
        if every <= 0:
            continue
        length_of = fault.length(args)
        t = every + fault.phase_s
        while True:
            hit: int | str
            if fault.target == SENSOR:  # each sensor's own length (a clock step's is its rate's)
                fits = {s: length_of(sensor_name(s)) for s in takers}
                fits = {s: length for s, length in fits.items() if t + length < end}
                if not fits:
                    break
                load = {s: overlaps(takers[s], (t, t + length + RECOVERY_S)) for s, length in fits.items()}
                least = min(load.values())
                sensor = int(rng.choice([s for s, n in load.items() if n == least]))
                length, hit = fits[sensor], sensor_name(sensor)
                for i in takers[sensor]:
                    busy.setdefault(i, []).append((t, t + length + RECOVERY_S))
                events += [(round(t, 2), fault.action, hit), (round(t + length, 2), fault.undo, hit)]
                t += every
                continue
            length = length_of(None)
            if t + length >= end:
                break
            if fault.target == TRACKER:
                window = (t, t + length + RECOVERY_S)  # the fault, then time to recover
                load = {i: overlaps([i], window) for i in busy}
                least = min(load.values())
                hit = int(rng.choice([i for i, n in load.items() if n == least]))
                busy[hit].append(window)
            else:
                hit = fault.target
            events += [(round(t, 2), fault.action, hit), (round(t + length, 2), fault.undo, hit)]
            t += every
    return sorted(events, key=lambda e: (e[0], str(e[2])))


def least_duration(args: argparse.Namespace) -> int | None:
    """The shortest whole ``--duration`` whose :func:`schedule` places a fault, with the other flags of ``args``
    (None: none up to a day, or no fault kind asked for)."""
    every = [period(args, fault) for fault in registered()]
    if not any(e > 0 for e in every):
        return None
    start = int(min(e for e in every if e > 0))
    return next((d for d in range(start, LONGEST_S + 1)
                 if schedule(argparse.Namespace(**{**vars(args), "duration": float(d)}))), None)


def no_fault_message(args: argparse.Namespace) -> str:
    """Why a soak whose schedule places no fault is refused, and the least ``--duration`` that places one."""
    least = least_duration(args)
    if least is None:
        flags = ", ".join(f.flag for f in registered()[:3])
        return f"the fault schedule is empty: give a fault period ({flags}, ...)"
    return (f"--duration {args.duration:g} places no fault (each must end {END_MARGIN_S:g} s before the end): "
            f"the least duration that places one with these periods is {least} s")


def plan_lines(events: list[tuple[float, str, int | str]], args: argparse.Namespace, engine: str) -> list[str]:
    """``soak --plan``: the schedule :func:`schedule` made, one line per fault with its undo, and a last line
    saying that nothing was started."""
    lines = [f"soak plan: {args.scenario}, {args.nodes} trackers, {args.duration:g} s, engine {engine}, seed "
             f"{args.seed}; each run (faulty, then fault-free) lasts --duration"]
    undone: dict[tuple[float, str, int | str], tuple[float, str]] = {}  # a fault -> (when, how) it is undone
    began: dict[tuple[str, int | str], float] = {}
    starts, undoes = fault_actions(), undo_actions()
    for t, action, target in events:
        if action in starts:
            began[(action, target)] = t
        elif action in undoes:
            undone[(began.pop((undoes[action], target)), undoes[action], target)] = (t, action)
    faults = [e for e in events if e[1] in starts]
    for t, kind, target in faults:
        undo = undone.get((t, kind, target))
        lines.append(f"  {t:8.1f} s  {kind:<6} {service_name(target):<8}" +
                     (f"  {undo[1]} at {undo[0]:.1f} s" if undo else "  never undone"))
    lines.append(f"{len(faults)} faults; nothing started (--plan)")
    return lines


def trackers_faulted_near(events: list[tuple[float, str, int | str]], start: float, end: float) -> set[int]:
    """The trackers a fault of the schedule ``events`` hits from :data:`RECOVERY_S` before ``start`` to
    :data:`RECOVERY_S` after ``end`` (a fault never undone lasts to the end): a node drain from ``start`` to
    ``end`` moves none of them, so that it too keeps a tracker from two faults at once."""
    near: set[int] = set()
    began: dict[tuple[str, int], float] = {}
    starts, undoes = fault_actions(), undo_actions()
    for t, action, target in sorted(events, key=lambda e: e[0]):
        if not isinstance(target, int):
            continue
        if action in starts:
            began[(action, target)] = t
        elif action in undoes and (undoes[action], target) in began:
            a = began.pop((undoes[action], target))
            if a < end + RECOVERY_S and t > start - RECOVERY_S:
                near.add(target)
    near.update(target for (_, target), a in began.items() if a < end + RECOVERY_S)
    return near


def fault_windows(faults: list[dict], end_step: int) -> list[dict]:
    """Each applied fault (``{"action", "node", "step", "t"}`` events as the soak records them; a sensor's also
    ``trackers``, those that take it) paired with its undo: ``{"kind", "node", "start", "end", "undo"}`` in steps
    (and ``trackers``); a fault never undone (the run ended first) ends at ``end_step`` with ``undo`` None. In the
    order the faults started."""
    open_at: dict[tuple[str, int | str], dict] = {}
    windows: list[dict] = []
    starts, undoes = fault_actions(), undo_actions()
    for f in faults:
        action, target = f["action"], f["node"]
        if action in starts:
            window = {"kind": action, "node": target, "start": f["step"], "end": end_step, "undo": None}
            if "trackers" in f:
                window["trackers"] = list(f["trackers"])
            open_at[(action, target)] = window
            windows.append(window)
        elif action in undoes and (undoes[action], target) in open_at:
            window = open_at.pop((undoes[action], target))
            window["end"], window["undo"] = f["step"], action
    return windows
