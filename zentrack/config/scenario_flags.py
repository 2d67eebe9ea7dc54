"""The flags that choose a run's scenario, filter, fusion rule and timing, shared by ``zentrack truth``, ``node``,
``sensor``, ``viewer``, ``record`` and ``run`` (:func:`~zentrack.config.run_setup.resolve_setup` applies them)."""
from __future__ import annotations

import argparse

from zentrack.common.argtypes import (
    float_in,
    fraction,
    fusion_param,
    gate_probability,
    int_in,
    nodes_int,
    period_float,
    qbar_float,
    seed_int,
    steps_int,
    theta_float,
)
from zentrack.common.vocabulary import fusion_name, live_filter
from zentrack.config import catalogue
from zentrack.config.node_config import MAX_LATENCY_BUDGET_MS, MODES
from zentrack.fusion.defaults import (
    DEFAULT_DEADLINE_FRAC,
    DEFAULT_FILTER,
    DEFAULT_FUSION,
    DEFAULT_GATE,
    DEFAULT_QBAR,
    MAX_ROUNDS,
    MULTITARGET_TRACKERS,
)
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.rules import RULE_REGISTRY


def add_scenario_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("scenario")
    src = g.add_mutually_exclusive_group()
    src.add_argument("--scenario", default=None, metavar="NAME|PATH", type=catalogue.scenario_arg,
                     help=catalogue.help_text())
    src.add_argument("--scenario-file", metavar="PATH", help="replay a recorded scenario .npz")
    g.add_argument("--filter", dest="filter_kind", type=live_filter(FILTER_REGISTRY),
                   help=f"local filter by name (default: the scenario's, else {DEFAULT_FILTER}; `zentrack sim --list-filters`)")
    g.add_argument("--fusion", type=fusion_name(RULE_REGISTRY),
                   help=f"fusion rule by name (default: the scenario's [fusion] rule, else {DEFAULT_FUSION})")
    g.add_argument("--rounds", type=int_in(1, MAX_ROUNDS, "rounds"),
                   help="fusion rounds per step, for rules that take a 'rounds' parameter (default: the scenario's)")
    g.add_argument("--fusion-param", action="append", type=fusion_param, metavar="KEY=VALUE",
                   help="a parameter of the fusion rule, repeatable (e.g. share_scans=true for ci; omega=10 for hcmci); "
                        "`zentrack sim --list-filters` lists every rule's")
    g.add_argument("--qbar", type=qbar_float, help=f"injection bound qbar (default: the scenario's, else {DEFAULT_QBAR:g})")
    g.add_argument("--theta", type=theta_float, help="inflation theta (default: trace balance)")
    g.add_argument("--timing", dest="timing_mode", choices=MODES, help="realtime or lockstep (default: the scenario's)")
    g.add_argument("--deadline-frac", type=fraction,
                   help=f"fuse at t_k + frac * Ts (default: the scenario's, else {DEFAULT_DEADLINE_FRAC:g})")
    g.add_argument("--period", type=period_float, metavar="SECONDS",
                   help="wall-clock seconds per step of a realtime run (default: the scenario's ts); the models keep "
                        "the scenario's ts, so e.g. --period 1 runs a ts = 10 s scenario ten times faster")
    g.add_argument("--gate", type=gate_probability, metavar="P",
                   help="each node's chi-square gate on its neighbours' priors wrongly rejects an honest one with "
                        f"probability at most P (default {DEFAULT_GATE:g}; 0 turns the gate off)")
    g.add_argument("--latency-budget-ms", type=float_in(0.0, MAX_LATENCY_BUDGET_MS, "milliseconds"), metavar="MS",
                   help="run each tracker's schedule this much behind the run's, so measurements and neighbours' "
                        "messages that take up to this much longer than on loopback still count (default 0; "
                        "docs/networks.md says how to choose it)")
    g.add_argument("--tracker", choices=MULTITARGET_TRACKERS,
                   help="many targets: each node's tracker, gnn (M-of-N confirmation) or pmbm (Poisson multi-Bernoulli "
                        "mixture, point sensors) (default: the scenario's [tracker] kind, else gnn)")
    g.add_argument("--share-scans", action=argparse.BooleanOptionalAction, default=None,
                   help="many targets, point sensors: each node also steps on its neighbours' scans (default: the "
                        "scenario's [tracker] share_scans, else on for pmbm and off for gnn)")
    g.add_argument("--nodes", type=nodes_int, help="number of trackers, 1 to 1000 (TOML ring scenarios are rebuilt for N)")
    g.add_argument("--steps", type=steps_int, help="number of steps, 1 to 1000000 (TOML scenarios)")
    g.add_argument("--seed", type=seed_int, help="seed of the simulated run (TOML scenarios)")
