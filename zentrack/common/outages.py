"""Stretches of a run in which a tracker was cut off, from what the recorder received: the verdict's partitions.

A node behind a partition (its host cut from the truth's, a router down) publishes nothing the recorder hears,
or estimates that only coast (no measurement of its own came). When the link heals it comes back. Such a
node did its job as far as the network let it: the recorder does not fail it, and the closing line says what
happened instead of a bare "run OK". A node that never came back (dead, frozen, still cut at the end) is not
an outage but a failure (:func:`~zentrack.common.run_summary.run_failures`).
"""
from __future__ import annotations

import numpy as np

#: the shortest stretch reported: a step or two without an estimate is noise on a loaded host, not a partition
OUTAGE_MIN_STEPS = 5
#: a node that coasts on more of its steps than this fraction coasts by design (a relay without a sensor, a
#: target out of its range): its coasting is not reported as stretches
DESIGNED_COAST_FRAC = 0.5


def runs_of(mask: np.ndarray) -> list[list[int]]:
    """Runs of True in ``mask`` as ``[first, last]`` pairs."""
    out, start = [], None
    for k, on in enumerate(mask):
        if on and start is None:
            start = k
        if not on and start is not None:
            out.append([start, k - 1])
            start = None
    if start is not None:
        out.append([start, len(mask) - 1])
    return out


def node_outages(have: np.ndarray, coasted: np.ndarray, min_steps: int = OUTAGE_MIN_STEPS) -> dict:
    """One node's stretches of ``min_steps`` steps or more after its first estimate: ``outages`` (no estimate
    received, then estimates again: the node came back), ``coasted_stretches`` (estimates that only predicted, unless the node coasts by
    design) and ``missing_at_end`` (steps of a last stretch without an estimate that reaches the run's end)."""
    steps = len(have)
    # a stretch from step 0 is a late start (the node joined late), not a cut
    missing = [r for r in runs_of(~have) if r[1] - r[0] + 1 >= min_steps and r[0] > 0]
    at_end = missing[-1][1] - missing[-1][0] + 1 if missing and missing[-1][1] == steps - 1 else 0
    coasting = have & coasted
    by_design = have.any() and coasting.sum() > DESIGNED_COAST_FRAC * have.sum()
    return {"outages": missing[:-1] if at_end else missing,
            "coasted_stretches": [] if by_design else [r for r in runs_of(coasting) if r[1] - r[0] + 1 >= min_steps],
            "missing_at_end": int(at_end)}


def steps_in(stretches: list[list[int]]) -> int:
    return int(sum(b - a + 1 for a, b in stretches))


def _steps_text(stretches: list[list[int]]) -> str:
    shown = ", ".join(f"{a}-{b}" for a, b in stretches[:4]) + (", ..." if len(stretches) > 4 else "")
    return f"steps {shown} ({steps_in(stretches)} steps)"


def _grouped(summary: dict, field: str) -> list[tuple[list[int], list[list[int]]]]:
    """Nodes with the same stretches under ``field``, together: [(nodes, stretches)]."""
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    for n in summary.get("nodes", []):
        stretches = n.get(field) or []
        if stretches:
            groups.setdefault(repr(stretches), ([], stretches))[0].append(n["node"])
    return list(groups.values())


def _nodes_text(nodes: list[int]) -> str:
    return f"node {nodes[0]}" if len(nodes) == 1 else "nodes " + ", ".join(str(i) for i in nodes)


def partition_notes(summary: dict) -> list[str]:
    """What the closing line says about a run's outages, one phrase per group of nodes with the same stretches:
    estimates missing, then back; coasted stretches. Empty for a run without any."""
    notes = [f"{_nodes_text(nodes)} sent no estimate through {_steps_text(s)} and came back"
             for nodes, s in _grouped(summary, "outages")]
    notes += [f"{_nodes_text(nodes)} coasted through {_steps_text(s)}" for nodes, s in _grouped(summary, "coasted_stretches")]
    return notes
