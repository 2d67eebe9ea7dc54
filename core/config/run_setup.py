"""Scenario and filter selection shared by ``zentrack truth``, ``node`` and ``run``.

A process takes ``--scenario NAME|PATH`` (a TOML scenario file, see ``deploy/scenarios/``) or
``--scenario-file PATH.npz`` (a recorded scenario); the filter and timing come from the TOML file and can be
overridden by flags (a ``.npz`` carries no filter settings: the flags' defaults apply).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from zentrack.common.argtypes import positive_float
from zentrack.config.arg_types import check_node_steps, nodes_int, qbar_float, seed_int, steps_int, theta_float
from zentrack.config.scenario_config import MODES, load_scenario_config
from zentrack.config.scenario_file import load_scenario
from zentrack.fusion.filters import LOCAL_FILTERS
from zentrack.fusion.scenario import ScenarioData, ring_sensor_positions, simulate


@dataclass
class RunSetup:
    scenario: ScenarioData
    filter_kind: str
    qbar: float
    theta: float | None
    mode: str
    deadline_frac: float
    source: str


def fraction(text: str) -> float:
    value = positive_float(text)
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text}")
    return value


def add_scenario_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("scenario")
    src = g.add_mutually_exclusive_group()
    src.add_argument("--scenario", default=None, metavar="NAME|PATH",
                     help="TOML scenario: a built-in name (exp1, exp2, exp2-point) or a path (default exp2)")
    src.add_argument("--scenario-file", metavar="PATH", help="replay a recorded scenario .npz")
    g.add_argument("--filter", dest="filter_kind", choices=LOCAL_FILTERS, help="local filter (default: the scenario's, else teskf)")
    g.add_argument("--qbar", type=qbar_float, help="injection bound qbar (default: the scenario's, else 1e-6)")
    g.add_argument("--theta", type=theta_float, help="inflation theta (default: trace balance)")
    g.add_argument("--timing", dest="timing_mode", choices=MODES, help="realtime or lockstep (default: the scenario's)")
    g.add_argument("--deadline-frac", type=fraction, help="fuse at t_k + frac * Ts (default: the scenario's, else 0.5)")
    g.add_argument("--nodes", type=nodes_int, help="number of trackers, 1 to 1000 (TOML ring scenarios are rebuilt for N)")
    g.add_argument("--steps", type=steps_int, help="number of steps, 1 to 1000000 (TOML scenarios)")
    g.add_argument("--seed", type=seed_int, help="seed of the simulated run (TOML scenarios)")


def resolve_setup(args: argparse.Namespace) -> RunSetup:
    """Load the scenario the flags name and apply the overrides (every process derives the same run)."""
    nodes, steps, seed = getattr(args, "nodes", None), getattr(args, "steps", None), getattr(args, "seed", None)
    if args.scenario_file:
        if nodes or steps or seed is not None:
            raise ValueError("--nodes/--steps/--seed come from the file when --scenario-file is given")
        scn = load_scenario(args.scenario_file)
        if scn.runs != 1:
            scn = scn.run(0)
        kind, qbar, theta, mode, frac, source = "teskf", 1e-6, None, "realtime", 0.5, args.scenario_file
    else:
        cfg = load_scenario_config(args.scenario or "exp2")
        spec = cfg.spec
        if nodes and nodes != spec.nodes:
            if spec.measurement == "linear":
                spec.sensors = np.zeros((nodes, 3))
            elif cfg.ring is not None:
                spec.sensors = ring_sensor_positions(nodes, *cfg.ring)
            else:
                raise ValueError(f"{cfg.source}: --nodes needs a ring layout; explicit sensors fix N = {spec.nodes}")
        if steps:
            spec.steps = steps
        if nodes or steps:
            check_node_steps(1, spec.steps, spec.nodes, f"{cfg.source}: --steps x --nodes")
        scn = simulate(spec, runs=1, seed=cfg.seed if seed is None else seed, ts=cfg.ts)
        kind, qbar, theta, mode, frac, source = cfg.filter_kind, cfg.qbar, cfg.theta, cfg.mode, cfg.deadline_frac, cfg.source
    return RunSetup(
        scenario=scn,
        filter_kind=args.filter_kind or kind,
        qbar=args.qbar or qbar,
        theta=args.theta or theta,
        mode=args.timing_mode or mode,
        deadline_frac=args.deadline_frac or frac,
        source=source,
    )
