"""The ring lattices of ``zentrack bench scale --degree``: Experiment 2's sensor ring with D neighbours per node.

The catalogue's exp2 ring links each node to the two next to it (``fusion.graphs.ring_adjacency``). For a sweep
over node degree the bench links node i to the D nearest nodes along the ring instead (a circulant graph,
Watts and Strogatz 1998's ring lattice): i ± 1, ..., i ± D/2 for even D; for odd D also the node opposite,
i + N/2 (so odd D needs even N). Every degree of a sweep goes through the scenario spec's explicit graph
(Metropolis weights), the default ring's degree 2 included, so the runs of a sweep differ in the degree only.
"""
from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from zentrack.truth.simulation.scenario_spec import ScenarioSpec


def degrees(text: str) -> list[int]:
    """``--degree D[,D...]``: the sorted distinct degrees, each at least 2 (a degree-1 lattice is not connected)."""
    try:
        out = sorted({int(t) for t in text.split(",") if t.strip()})
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, got {text!r}") from None
    if not out or out[0] < 2:
        raise argparse.ArgumentTypeError(f"degrees must be at least 2 (a ring needs two neighbours), got {text!r}")
    return out


def check_degree(n: int, degree: int) -> None:
    """ValueError naming the pair when ``n`` nodes cannot each have ``degree`` distinct neighbours on a ring."""
    if degree > n - 1:
        raise ValueError(f"--degree {degree} needs at least {degree + 1} nodes (--sizes has {n})")
    if degree % 2 and n % 2:
        raise ValueError(f"--degree {degree} (odd) links each node to the one opposite: it needs an even size, "
                         f"--sizes has {n}")


def ring_lattice_adjacency(n: int, degree: int) -> np.ndarray:
    """``(n, n)`` bool adjacency of the ring lattice: each node linked to ``degree`` nodes (module docstring)."""
    check_degree(n, degree)
    adj = np.zeros((n, n), dtype=bool)
    for i in range(n):
        for hop in range(1, degree // 2 + 1):
            adj[i, (i + hop) % n] = adj[i, (i - hop) % n] = True
        if degree % 2:
            adj[i, (i + n // 2) % n] = True
    return adj


def with_degree(spec: ScenarioSpec, degree: int) -> ScenarioSpec:
    """``spec`` with its communication graph replaced by the ring lattice of ``degree`` (checked by the spec)."""
    return dataclasses.replace(spec, graph="explicit", adjacency=ring_lattice_adjacency(spec.nodes, degree),
                               consensus_weights="metropolis")
