"""Argparse value types, all of them in one module: bounded whole numbers and finite numbers, each refusing a
bad value with one line that names the allowed range; the run flags bounded by the limits the scenario keys
obey (:mod:`zentrack.common.limits`, so a flag and the TOML key it overrides accept exactly the same values);
fractions, periods (or 0: off) and the gate's probability; host names; comma-separated name lists, registered
names and fusion-rule parameters (the shared names of filters and rules, and old spellings:
:mod:`zentrack.common.vocabulary`)."""
from __future__ import annotations

import argparse
import ipaddress
import re

import numpy as np

from zentrack.common.limits import MAX_NODE_STEPS, MAX_NODES, MAX_RUNS, MAX_SEED, MAX_STEPS, QBAR_RANGE, THETA_RANGE
from zentrack.common.suggest import did_you_mean, names_chosen_by, with_hint

MAX_COUNT = 1_000_000  # the largest count any flag takes (steps, runs, pings, ...)


def int_in(lo: int, hi: int, name: str = "whole number"):
    """An argparse type: a whole number from ``lo`` to ``hi``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be at least {lo} and at most {hi}, got {value}")
        return value

    parse.__name__ = name
    return parse


def float_in(lo: float, hi: float, name: str = "number"):
    """An argparse type: a finite number from ``lo`` to ``hi`` (``lo > 0``: a positive number)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (value > 0 and np.isfinite(value)) and lo > 0:
            raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be from {lo:g} to {hi:g}, got {text}")
        return value

    parse.__name__ = name
    return parse


def off_or_float_in(lo: float, hi: float, name: str = "period"):
    """An argparse type: 0 (off) or a finite number from ``lo`` to ``hi`` (a fault period in seconds: a tiny
    one would schedule billions of events, NaN none that ever ends)."""
    within = float_in(lo, hi, name)

    def parse(text: str) -> float:
        try:
            if float(text) == 0:
                return 0.0
            return within(text)
        except (ValueError, argparse.ArgumentTypeError):
            raise argparse.ArgumentTypeError(f"must be 0 (off) or from {lo:g} to {hi:g}, got {text}") from None

    parse.__name__ = name
    return parse


positive_int = int_in(1, MAX_COUNT, "positive_int")


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and np.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
    return value


def fraction(text: str) -> float:
    """An argparse type: a number strictly between 0 and 1 (``--deadline-frac``)."""
    value = positive_float(text)
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text}")
    return value


def period_float(text: str) -> float:
    """An argparse type: wall-clock seconds per step, 0.01 to 600 (``--period``)."""
    value = positive_float(text)
    if not 0.01 <= value <= 600:
        raise argparse.ArgumentTypeError(f"must be from 0.01 to 600 seconds, got {text}")
    return value


def gate_probability(text: str) -> float:
    """An argparse type: the gate's false-rejection probability, 0 (no gate) or 1e-12 to 0.5 (``--gate``)."""
    value = float_in(0.0, 0.5, "gate")(text)
    if value != 0 and value < 1e-12:
        raise argparse.ArgumentTypeError(f"must be 0 (no gate) or from 1e-12 to 0.5, got {text}")
    return value


# ------------------------------------------------------------ run flags, bounded like the scenario keys

steps_int = int_in(1, MAX_STEPS, "steps")
nodes_int = int_in(1, MAX_NODES, "nodes")
runs_int = int_in(1, MAX_RUNS, "runs")
seed_int = int_in(0, MAX_SEED, "seed")
qbar_float = float_in(*QBAR_RANGE, "qbar")
theta_float = float_in(*THETA_RANGE, "theta")


def check_node_steps(runs: int, steps: int, nodes: int, what: str = "--runs x --steps x --nodes") -> None:
    """Refuse a simulation whose arrays would not fit: at most :data:`MAX_NODE_STEPS` node-steps."""
    if runs * steps * nodes > MAX_NODE_STEPS:
        raise ValueError(f"{what}: {runs} run(s) x {steps} steps x {nodes} nodes is more than {MAX_NODE_STEPS} "
                         "node-steps; use fewer")


# ------------------------------------------------------------------------------------------------ names

_HOST_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def host_name(text: str) -> str:
    """An argparse type: an IP address or a DNS host name (dot-separated labels of letters, digits and ``-``,
    at most 253 characters; ``--host`` of ``zentrack certs``, written into a certificate)."""
    try:
        return str(ipaddress.ip_address(text))
    except ValueError:
        pass
    name = text[:-1] if text.endswith(".") else text
    if not name or len(name) > 253 or not all(_HOST_LABEL.fullmatch(label) for label in name.split(".")):
        raise argparse.ArgumentTypeError(f"expected an IP address or a host name (labels of letters, digits and "
                                         f"'-', separated by dots), got {text!r}")
    return name




def name_list(choices, what: str):
    """An argparse type: comma-separated names, each one of ``choices`` (``what`` names them in the error)."""

    def parse(text: str) -> list[str]:
        names = [t.strip() for t in text.split(",") if t.strip()]
        bad = [n for n in names if n not in choices]
        if bad or not names:
            hint = did_you_mean(bad[0], choices) if bad else ""
            raise argparse.ArgumentTypeError(f"unknown {what.removesuffix('s')}(s) {bad or text!r}; choose from {', '.join(choices)}{hint}")
        return names

    parse.__name__ = f"{what}_list"
    names_chosen_by(parse, lambda: choices)
    return parse


def registered(registry, extra: tuple[str, ...] = ()):
    """An argparse type: a name registered in ``registry`` (built-ins and plug-ins found so far) or in ``extra``;
    a mistyped one gets the nearest suggested."""

    def parse(text: str) -> str:
        if text not in registry and text not in extra:
            names = [*registry.names(), *extra]
            raise argparse.ArgumentTypeError(f"unknown {registry.kind} {text!r}; choose one of "
                                             f"{', '.join(names)}{did_you_mean(text, names)}")
        return text

    parse.__name__ = registry.kind
    names_chosen_by(parse, lambda: [*registry.names(), *extra])
    return parse


def fusion_param(text: str) -> tuple[str, object]:
    """``--fusion-param KEY=VALUE``: VALUE read as true/false, an int, a float, or else text (the fusion rule's
    registry checks it: :func:`fusion_params_with`)."""
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
        raise ValueError(f"--fusion-param: {with_hint(exc)}") from None
    return out
