"""Argparse types bounded by the scenario limits (:data:`~zentrack.config.scenario_config.BOUNDS`), so a flag
and the TOML key it overrides accept exactly the same values."""
from __future__ import annotations

from zentrack.common.argtypes import float_in, int_in
from zentrack.config.scenario_config import BOUNDS, MAX_NODE_STEPS, MAX_NODES, MAX_RUNS, MAX_SEED, MAX_STEPS

steps_int = int_in(1, MAX_STEPS, "steps")
nodes_int = int_in(1, MAX_NODES, "nodes")
runs_int = int_in(1, MAX_RUNS, "runs")
seed_int = int_in(0, MAX_SEED, "seed")
qbar_float = float_in(*BOUNDS["filter.qbar"], "qbar")
theta_float = float_in(*BOUNDS["filter.theta"], "theta")


def check_node_steps(runs: int, steps: int, nodes: int, what: str = "--runs x --steps x --nodes") -> None:
    """Refuse a simulation whose arrays would not fit: at most :data:`MAX_NODE_STEPS` node-steps."""
    if runs * steps * nodes > MAX_NODE_STEPS:
        raise ValueError(f"{what}: {runs} run(s) x {steps} steps x {nodes} nodes is more than {MAX_NODE_STEPS} "
                         "node-steps; use fewer")
