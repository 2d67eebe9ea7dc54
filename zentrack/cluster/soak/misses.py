"""Every deadline miss of a soak's run explained (issue 36): which node, which step, how late, and what the process
was doing.

A run's ``summary.json`` counts a node's misses as the larger of what it reported and its steps without an
estimate. The trackers note each miss they see (``zentrack.transport.miss_notes``: the step, the kind, the phase,
how late, how late the process woke up, how long the late work took) on their next estimate, and the recorder
keeps them (``summary["miss_notes"]``). :func:`miss_report` puts those notes beside the steps without an estimate
that no note covers (a node not yet started, or estimates lost on the way), so that each missed step of a
fault-free reference run is accounted for; :func:`miss_lines` says it in a few lines.
"""
from __future__ import annotations

#: a miss note says the process was frozen or starved when it woke up at least this late (ms)
STARVED_MS = 50.0


def why(note: dict) -> str:
    """What the process was doing at a noted miss, in words."""
    woke = note["idle_ms"]
    if note["kind"] == "skipped":
        doing = f"woke {woke:.0f} ms late in {note['phase']} and skipped {note['steps']} step(s)"
    elif note["kind"] == "late_estimate":
        doing = f"published its estimate in {note['phase']} after a {note['work_ms']:.1f} ms update"
    else:
        doing = f"ended the step's fusion late ({note['work_ms']:.1f} ms of rounds)"
    if woke >= STARVED_MS and note["kind"] != "skipped":
        doing += f", having woken {woke:.0f} ms late"
    return doing + (" (frozen or starved of CPU)" if woke >= STARVED_MS else "")


def miss_report(summary: dict) -> dict:
    """The run's misses: ``deadline_misses`` (the summary's count), ``notes`` (each noted miss with ``why``),
    ``gaps`` (per node, the steps without an estimate no note covers, with the estimates lost in transport) and
    ``unexplained`` (missed steps neither a note nor a gap accounts for)."""
    notes = [dict(n, why=why(n)) for n in summary.get("miss_notes", [])]
    covered: dict[int, set[int]] = {}
    noted: dict[int, int] = {}  # misses the notes account for (a node counts an overrun and a skip of one step twice)
    for n in notes:
        covered.setdefault(n["node"], set()).update(range(n["step"], n["step"] + n["steps"]))
        noted[n["node"]] = noted.get(n["node"], 0) + n["steps"]
    gaps, unexplained = [], 0
    for node in summary["nodes"]:
        i, mine = node["node"], covered.get(node["node"], set())
        steps = [(a, b) for a, b in node.get("gaps", []) if not set(range(a, b + 1)) <= mine]
        if steps:
            gaps.append({"node": i, "steps": steps, "estimates_lost": node.get("estimates_lost", 0)})
        accounted = noted.get(i, 0) + sum(b - a + 1 for a, b in steps)
        unexplained += max(0, node["deadline_misses"] - accounted)
    return {"deadline_misses": summary["network"]["deadline_misses"], "notes": notes, "gaps": gaps,
            "unexplained": unexplained}


def miss_lines(report: dict, label: str) -> list[str]:
    """One line for the run's misses, then one per noted miss and per gap (at most ``limit`` of each)."""
    lines = [f"{label}: {report['deadline_misses']} deadline misses, {len(report['notes'])} noted by the trackers, "
             f"{len(report['gaps'])} node(s) with steps without an estimate, {report['unexplained']} unexplained"]
    for n in report["notes"][:20]:
        lines.append(f"    node {n['node']} step {n['step']}: {n['kind']} {n['late_ms']:.1f} ms past the deadline; "
                     f"it {n['why']}")
    for g in report["gaps"][:20]:
        spans = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in g["steps"][:6])
        lost = f" ({g['estimates_lost']} estimates published but lost on the way)" if g["estimates_lost"] else ""
        lines.append(f"    node {g['node']}: no estimate at steps {spans}{lost}")
    return lines
