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


def fusion_param(text: str) -> tuple[str, object]:
    """``--fusion-param KEY=VALUE``: VALUE read as true/false, an int, a float, or else text (the fusion rule's
    registry checks it: :func:`fusion_params_with`)."""
    import argparse

    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE (e.g. share_scans=true), got {text!r}")
    if value.lower() in ("true", "false"):
        return key.strip(), value.lower() == "true"
    for cast in (int, float):
        try:
            return key.strip(), cast(value)
        except ValueError:
            pass
    return key.strip(), value


def fusion_params_with(rule: str, params: dict, given: list[tuple[str, object]] | None) -> dict:
    """``params`` of fusion rule ``rule`` with the ``--fusion-param`` pairs ``given`` on top, every one checked
    by the rule's registry entry (ValueError naming the flag, the rule and its parameters)."""
    from zentrack.fusion.rules import RULE_REGISTRY

    out = dict(params)
    for key, value in given or []:
        out[key] = value
    try:
        RULE_REGISTRY.validate(rule, out)
    except ValueError as exc:
        raise ValueError(f"--fusion-param: {exc}") from None
    return out
