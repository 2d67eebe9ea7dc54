"""``zentrack node``: the command line of one tracker process (:mod:`zentrack.node.process`).

A tracker reads only its own slice, a :class:`~zentrack.config.node_config.NodeConfig`: the ``--node-config`` file
``zentrack run`` writes. Started by hand with ``--scenario`` or ``--scenario-file`` instead (the compose and
stack files, ``deploy/cluster.sh``), it has its slice cut here first, from the scenario spec (no run is
simulated) or a recorded file's static parts, and handed to :func:`zentrack.node.process.run`. That keeps the
scenario modules out of ``zentrack.node``'s import graph (``tests/test_layers.py``); a tracker started with
``--node-config`` loads none of them (``tests/test_lean_node.py``).
"""
from __future__ import annotations

import argparse

from zentrack.config.node_config import NodeConfig
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.node import process

#: the flags that name what a slice already holds: refused beside ``--node-config``
SLICE_FLAGS = ("scenario", "scenario_file", "filter_kind", "fusion", "rounds", "qbar", "theta", "timing_mode",
               "deadline_frac", "nodes", "steps", "seed", "latency_budget_ms")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_arguments(p)  # their own group, listed before the tracker's Zenoh group
    process.add_arguments(p)


def node_config(args: argparse.Namespace) -> NodeConfig:
    """This node's slice: the file the orchestrator wrote, or cut from the scenario the flags name (a spec is
    sliced without simulating it; a recorded file's static parts only)."""
    if args.node_config:
        given = [f for f in SLICE_FLAGS if getattr(args, f, None) is not None]
        if given:
            raise ValueError(f"--node-config holds the whole configuration; drop --{given[0].replace('_', '-')}")
        return process.node_config(args)
    setup = resolve_setup(args)
    if not 0 <= args.id < setup.nodes:
        raise ValueError(f"node id {args.id} is outside the scenario's nodes 0..{setup.nodes - 1}")
    return setup.node_config(args.id)


def run(args: argparse.Namespace) -> int:
    return process.run(args, node_config)
