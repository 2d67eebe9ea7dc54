"""The soak's faults: the seeded schedule of fault events (``schedule``), what undoes each kind of fault
(``FAULTS``), the name of a fault's target, and the windows the applied faults span (``fault_windows``, the
spans the error plot shades)."""
from __future__ import annotations

import argparse

import numpy as np

#: fault kind -> the action that undoes it
FAULTS = {"kill": "restart", "freeze": "thaw", "cut": "heal", "stall": "resume", "drain": "undrain"}
#: undo -> the fault it ends
UNDOES = {undo: kind for kind, undo in FAULTS.items()}


#: seconds a tracker has to recover after a fault before the schedule gives it another
RECOVERY_S = 25.0

#: how long a drained swarm node stays out of service by default (``--drain-s``): longer than swarm takes to
#: start its trackers on the other nodes (4-9 s measured on a 2-core host running three engines, docs/swarm.md)
DRAIN_S = 15.0

#: where each service fault's series starts within its period: clear of the tracker faults, which start at
#: multiples of their periods, and of each other
SERVICE_PHASE_S = {"stall": 15.0, "kill": 10.0, "router": 20.0, "drain": 7.5}
#: every fault ends at least this long before the soak does
END_MARGIN_S = 5.0
#: the longest soak :func:`least_duration` looks at
LONGEST_S = 86_400


def schedule(args: argparse.Namespace) -> list[tuple[float, str, int | str]]:
    """Seeded fault events ``(seconds after start, action, target)``: a target is a tracker index, ``truth``
    or ``router``, or ``swarm`` for a node drain (``--drain-every``, ``--drain-s`` long: the stack backend
    picks the node when it applies it, and the soak records it once per tracker it moved). A tracker is never
    under two faults at once, and gets :data:`RECOVERY_S` to recover before the next one
    (the least busy trackers are chosen when none is free); service faults start at an offset within their
    period so that they do not coincide with the tracker faults."""
    rng = np.random.default_rng(args.seed + 7919)
    stall_rng = np.random.default_rng(args.seed + 104729)
    events: list[tuple[float, str, int | str]] = []
    busy: dict[int, list[tuple[float, float]]] = {i: [] for i in range(args.nodes)}
    kinds = [("kill", args.kill_every, lambda: args.restart_after, None, 0.0),
             ("freeze", args.freeze_every, lambda: args.fault_s, None, 0.0),
             ("cut", args.cut_every, lambda: args.fault_s, None, 0.0),
             ("stall", getattr(args, "truth_stall_every", 0.0), lambda: round(float(stall_rng.uniform(0.5, 3.0)), 2),
              "truth", SERVICE_PHASE_S["stall"]),
             ("kill", getattr(args, "truth_kill_every", 0.0), lambda: args.restart_after, "truth", SERVICE_PHASE_S["kill"]),
             ("kill", getattr(args, "router_every", 0.0), lambda: args.restart_after, "router", SERVICE_PHASE_S["router"]),
             ("drain", getattr(args, "drain_every", 0.0), lambda: getattr(args, "drain_s", DRAIN_S), "swarm",
              SERVICE_PHASE_S["drain"])]
    for kind, every, length_of, target, phase in kinds:
        if every <= 0:
            continue
        t = every + phase
        while True:
            length = length_of()
            if t + length >= args.duration - END_MARGIN_S:
                break
            hit: int | str
            if target is None:
                window = (t, t + length + RECOVERY_S)  # the fault, then time to recover
                overlaps = {i: sum(a < window[1] and window[0] < b for a, b in spans) for i, spans in busy.items()}
                least = min(overlaps.values())
                hit = int(rng.choice([i for i, n in overlaps.items() if n == least]))
                busy[hit].append(window)
            else:
                hit = target
            events += [(round(t, 2), kind, hit), (round(t + length, 2), FAULTS[kind], hit)]
            t += every
    return sorted(events, key=lambda e: (e[0], str(e[2])))


def least_duration(args: argparse.Namespace) -> int | None:
    """The shortest whole ``--duration`` whose :func:`schedule` places a fault, with the other flags of ``args``
    (None: none up to a day, or no fault kind asked for)."""
    every = [getattr(args, name, 0.0) or 0.0 for name in ("kill_every", "freeze_every", "cut_every",
                                                          "truth_stall_every", "truth_kill_every", "router_every",
                                                          "drain_every")]
    if not any(e > 0 for e in every):
        return None
    start = int(min(e for e in every if e > 0))
    return next((d for d in range(start, LONGEST_S + 1)
                 if schedule(argparse.Namespace(**{**vars(args), "duration": float(d)}))), None)


def no_fault_message(args: argparse.Namespace) -> str:
    """Why a soak whose schedule places no fault is refused, and the least ``--duration`` that places one."""
    least = least_duration(args)
    if least is None:
        return "the fault schedule is empty: give a fault period (--kill-every, --freeze-every, --cut-every, ...)"
    return (f"--duration {args.duration:g} places no fault (each must end {END_MARGIN_S:g} s before the end): "
            f"the least duration that places one with these periods is {least} s")


def plan_lines(events: list[tuple[float, str, int | str]], args: argparse.Namespace, engine: str) -> list[str]:
    """``soak --plan``: the schedule :func:`schedule` made, one line per fault with its undo, and a last line
    saying that nothing was started."""
    lines = [f"soak plan: {args.scenario}, {args.nodes} trackers, {args.duration:g} s, engine {engine}, seed "
             f"{args.seed}; each run (faulty, then fault-free) lasts --duration"]
    undone: dict[tuple[float, str, int | str], tuple[float, str]] = {}  # a fault -> (when, how) it is undone
    began: dict[tuple[str, int | str], float] = {}
    for t, action, target in events:
        if action in FAULTS:
            began[(action, target)] = t
        elif action in UNDOES:
            undone[(began.pop((UNDOES[action], target)), UNDOES[action], target)] = (t, action)
    faults = [e for e in events if e[1] in FAULTS]
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
    for t, action, target in sorted(events, key=lambda e: e[0]):
        if not isinstance(target, int):
            continue
        if action in FAULTS:
            began[(action, target)] = t
        elif action in UNDOES and (UNDOES[action], target) in began:
            a = began.pop((UNDOES[action], target))
            if a < end + RECOVERY_S and t > start - RECOVERY_S:
                near.add(target)
    near.update(target for (_, target), a in began.items() if a < end + RECOVERY_S)
    return near


def service_name(target: int | str) -> str:
    """The process a fault hits: ``node-<i>`` for tracker i, else the service itself (``truth``, ``router``)."""
    return f"node-{target}" if isinstance(target, int) else target


def fault_windows(faults: list[dict], end_step: int) -> list[dict]:
    """Each applied fault (``{"action", "node", "step", "t"}`` events as the soak records them) paired with its
    undo: ``{"kind", "node", "start", "end", "undo"}`` in steps; a fault never undone (the run ended first)
    ends at ``end_step`` with ``undo`` None. In the order the faults started."""
    open_at: dict[tuple[str, int | str], dict] = {}
    windows: list[dict] = []
    for f in faults:
        action, target = f["action"], f["node"]
        if action in FAULTS:
            window = {"kind": action, "node": target, "start": f["step"], "end": end_step, "undo": None}
            open_at[(action, target)] = window
            windows.append(window)
        elif action in UNDOES and (UNDOES[action], target) in open_at:
            window = open_at.pop((UNDOES[action], target))
            window["end"], window["undo"] = f["step"], action
    return windows
