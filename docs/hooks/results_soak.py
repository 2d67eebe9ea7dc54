"""Results of the long soaks (issue 54): a soak's ``report.json``, copied to ``docs/results/soak_*.json``, rendered
by the soak's own code: the verdict (one line per criterion, as ``zentrack soak`` prints it), and the faults by kind
(how many, the fault windows judged, the ratios of the trackers hit and of the network to the fault-free reference
at the same steps, the limits, and the steps until every live tracker published again), and every fault window."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from results_tables import Column, get, num, render_table

from zentrack.cluster.soak.accuracy import window_table
from zentrack.cluster.soak.criteria import verdict_lines
from zentrack.cluster.soak.summary import faults_by_kind, loss_lines

Renderer = Callable[[dict[str, Any], str], str]


def soak_verdict(data: dict[str, Any], where: str) -> str:
    """The verdict (one row per criterion, its words as the soak printed them) and the misses of both runs."""
    rows: list[dict[str, str]] = []
    for line in verdict_lines(get(data, "criteria", where)):
        if line.startswith(" ") and rows:  # (a criterion's further offenders)
            rows[-1]["detail"] += "; " + line.strip()
            continue
        word, _, rest = line.partition("  ")
        name, _, detail = rest.strip().partition(": ")
        rows.append({"criterion": f"`{name}`", "verdict": f"**{word}**" if word != "PASS" else word, "detail": detail})
    verdict = "passed" if get(data, "pass", where) else "FAILED"
    losses = "\n".join(f"- {line}" for line in loss_lines(get(data, "misses", where)))
    return (f"The soak **{verdict}**:\n\n" + render_table(rows, [
        Column("criterion", "criterion"), Column("verdict", "verdict"), Column("what it measured", "detail")], where)
        + "\n\nMisses and losses, per run:\n\n" + losses)


def soak_kinds(data: dict[str, Any], where: str) -> str:
    """Per fault kind: faults, windows judged, ratios (median / worst), limits, steps to all publishing."""
    accuracy = get(data, "criteria.accuracy_per_fault", where)
    recovery = faults_by_kind(data)
    rows = []
    for kind in sorted({w["kind"] for w in accuracy["windows"]} | set(recovery)):
        windows = [w for w in accuracy["windows"] if w["kind"] == kind]
        judged = [w for w in windows if w["judged"]]
        hit = [w["ratio_affected"] for w in judged]
        net = [w["ratio_network"] for w in judged]
        limits = accuracy["limits"].get(kind)
        steps = recovery.get(kind, {})
        rows.append({"kind": kind, "faults": len(windows), "judged": len(judged),
                     "hit": "–" if not hit else f"{np.median(hit):.2f} / {max(hit):.2f}",
                     "net": "–" if not net else f"{np.median(net):.2f} / {max(net):.2f}",
                     "limits": "–" if limits is None else f"{limits[0]:g} / {limits[1]:g}",
                     "steps": "–" if steps.get("median") is None else f"{steps['median']:g} / {steps['max']}"})
    return render_table(rows, [
        Column("fault kind", "kind"), Column("faults", "faults", num(0)), Column("windows judged", "judged", num(0)),
        Column("trackers hit: median / worst ratio", "hit"), Column("network: median / worst ratio", "net"),
        Column("limits (alone)", "limits"), Column("steps to all publishing: median / worst", "steps")], where)


def soak_windows(data: dict[str, Any], where: str) -> str:
    """Every fault window, as ``zentrack soak --rejudge`` prints it."""
    return "\n".join(window_table(get(data, "criteria.accuracy_per_fault", where)))


def split_starts(data: dict[str, Any], where: str) -> str:
    """``bench split``: per start and variant, node 2's window error beside the reference and both bounds."""
    rows = [{**r, "first": f"{r['first_estimate_after_restart']} / {r['steps_to_2x_node1']}",
             "window": f"{r['steps'][0]}-{r['steps'][1]}"} for r in get(data, "rows", where)]
    head = (f"An {get(data, 'nodes', where)}-tracker `patrol` ring, seed {get(data, 'seed', where)}; node 2 over the "
            "soak's window of its kill after its restart (from its restart to 40 steps after it).")
    return head + "\n\n" + render_table(rows, [
        Column("faults from step", "start", num(0)), Column("neighbours share", "variant"), Column("window", "window"),
        Column("node 2 RMSE (m)", "rmse_m", num(1)), Column("fault-free (m)", "reference_m", num(1)),
        Column("ratio", "ratio", num(2)), Column("bound ratio", "bound_ratio", num(2)),
        Column("RMSE / root of its reach bound", "over_bound", num(2)),
        Column("fault-free / root of the network's bound", "reference_over_bound", num(2)),
        Column("first estimate / to 2x node 1 (steps)", "first"), Column("NEES max", "max_nees", num(1))], where)


RENDERERS: dict[tuple[str, str], Renderer] = {
    ("split", "starts"): split_starts,
    **{(name, table): renderer for name in ("soak_hour_patrol", "soak_hour_patrol_rejudged", "soak_hour_patrol_bound", "soak_stack30",
                                                          "multitarget_soak_pmbm")
       for table, renderer in (("verdict", soak_verdict), ("kinds", soak_kinds), ("windows", soak_windows))},
}
