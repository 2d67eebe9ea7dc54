"""Reading a scenario file's TOML values with precise errors: the bounds of every number a scenario holds, the
error type, and :class:`ScenarioReader`, which fetches ``section.key`` checked against a kind, choices and bounds.

Every error names the file, the key (``section.key``) and what is allowed, in one line. The section parsers
(:mod:`zentrack.config.scenario_sections`, :mod:`zentrack.config.scenario_parse`) read through it; the public
names are re-exported by :mod:`zentrack.config.scenario_config`.
"""
from __future__ import annotations

import math
from typing import Any, NoReturn

import numpy as np

from zentrack.common.limits import QBAR_RANGE, THETA_RANGE
from zentrack.common.suggest import did_you_mean
from zentrack.config.scenario_schema import OPEN_SECTIONS, SCHEMA
from zentrack.transport.wire import MAX_RETURNS

MODES = ("realtime", "lockstep")

# Bounds of every number a scenario can hold (TOML keys, the matching flags and .npz files): generous for any
# real tracker, tight enough that no value reaches a MemoryError, an overflow or a degenerate covariance. The
# counts (MAX_STEPS, MAX_NODES, MAX_RUNS, MAX_NODE_STEPS, MAX_SEED) and the filter's ranges, which flags share,
# are zentrack.common.limits'.
TS_RANGE = (1e-3, 3600.0)  # sample period, seconds
BOUNDS: dict[str, tuple[float, float]] = {
    # key: (low, high); both inclusive
    "plant.sigma_w": (1e-6, 1e4),  # process noise std (m/s^2-ish): Q = sigma_w^2 I
    "plant.alpha": (-1e4, 1e4),
    "plant.beta": (-1e4, 1e4),
    "plant.q": (1e-12, 1e8),  # process noise variance (exp1: Q = q I; cv3d-cd: diffusion intensity, m^2/s^3)
    "plant.em_steps": (1, 1000),  # cv3d-cd: Euler-Maruyama steps per scan period
    "plant.d_amp": (-1e6, 1e6),
    "plant.d_freq": (-1e6, 1e6),
    "sensors.radius": (1e-3, 1e7),  # metres
    "sensors.height": (-1e7, 1e7),
    "sensors.positions": (-1e7, 1e7),
    "measurement.noise_std": (1e-6, 1e6),  # radians for bearings (at most pi), metres or units otherwise
    "measurement.matrix": (-1e6, 1e6),
    "initial.x0": (-1e9, 1e9),
    "initial.p0_diag": (1e-12, 1e12),
    "initial.lumped_var": (1e-12, 1e12),
    "filter.qbar": QBAR_RANGE,
    "filter.theta": THETA_RANGE,
    "graph.self_weight": (1e-6, 1.0),
    "graph.link_prob": (1e-3, 1.0),
    "sensors.velocities": (-1e5, 1e5),  # m/s of moving sensor platforms
    "sensors.accelerations": (-1e3, 1e3),  # m/s^2
    "manoeuvre.times": (0.0, 1e9),  # seconds
    "plant.a_m": (-1e3, 1e3),  # ship-turn: acceleration along the track, m/s^2
    "plant.k_psi": (-1.0, 1.0),  # ship-turn: turn rate, rad/s
    "plant.power": (0.0, 1e9),  # ship-power: W
    "plant.eta": (1e-6, 1e6),  # ship-power: drag coefficient, kg/m
    "plant.mass": (1.0, 1e9),  # ship-power: kg
    "sensors.orbits": (-1e9, 1e9),
    "sensors.t_mid": (0.0, 1e7),  # s after the orbits' epoch
    "manoeuvre.accelerations": (-1e3, 1e3),  # m/s^2
    "clutter.detection_prob": (0.0, 1.0),
    "clutter.count": (0, MAX_RETURNS - 1),  # clutter returns per scan (fixed); the target's may come on top
    "clutter.density": (0.0, 1e6),  # returns per rad^2 (poisson)
}


class ScenarioConfigError(ValueError):
    """A scenario file is missing or invalid; the message names the file, the key and the allowed values."""


class ScenarioReader:
    """Checked access to one parsed TOML document (``label`` names it in every error)."""

    def __init__(self, label: str, doc: dict) -> None:
        self.label = label
        self.doc = doc

    def fail(self, key: str, msg: str) -> NoReturn:
        raise ScenarioConfigError(f"{self.label}: {key}: {msg}")

    def section(self, name: str) -> dict:
        sec = self.doc.get(name)
        if not isinstance(sec, dict):
            self.fail(name, "missing section [" + name + "]")
        return sec

    def get(self, section: str, key: str, kind: str, default: Any = None, choices: tuple = (), required: bool = True,
            bounds: tuple[float, float] | None = None):
        """The value of ``section.key`` checked against ``kind``, ``choices`` and ``bounds`` (default: the
        key's entry in :data:`BOUNDS`)."""
        full = f"{section}.{key}"
        value = self._get(section, key, kind, default, choices, required)
        lo, hi = bounds or BOUNDS.get(full) or (None, None)
        if lo is not None and value is not None and kind not in ("str", "int"):
            arr = np.asarray(value, dtype=float)
            if arr.size and not (np.all(arr >= lo) and np.all(arr <= hi)):
                self.fail(full, f"must be from {lo:g} to {hi:g}, got {short(value)}")
        return value

    def _get(self, section: str, key: str, kind: str, default: Any, choices: tuple, required: bool):
        base = section.split(".", 1)[0]  # (a ``[sensing.<kind>]`` table holds [sensing]'s keys)
        if base in SCHEMA and base not in OPEN_SECTIONS and key not in SCHEMA[base]:
            raise AssertionError(f"{section}.{key} is read but not in the scenario schema (scenario_schema.SCHEMA)")
        sec = self.section(section)
        full = f"{section}.{key}"
        if key not in sec:
            if required and default is None:
                self.fail(full, "missing" + (f" (allowed: {', '.join(map(str, choices))})" if choices else ""))
            return default
        v = sec[key]
        if kind == "str":
            if not isinstance(v, str):
                self.fail(full, f"must be a string, got {v!r}")
            if choices and v not in choices:
                self.fail(full, f"{v!r} is not allowed; choose one of {', '.join(choices)}{did_you_mean(v, choices)}")
            return v
        if kind == "bool":
            if not isinstance(v, bool):
                self.fail(full, f"must be true or false, got {v!r}")
            return v
        if kind == "int":
            if not isinstance(v, int) or isinstance(v, bool):
                self.fail(full, f"must be a whole number, got {v!r}")
            return v
        if kind in ("float", "positive"):
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                self.fail(full, f"must be a finite number, got {v!r}")
            if kind == "positive" and v <= 0:
                self.fail(full, f"must be positive, got {v!r}")
            return float(v)
        if kind == "vector":
            if not isinstance(v, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
                self.fail(full, f"must be a list of numbers, got {v!r}")
            a = np.array(v, dtype=float)
            if not np.all(np.isfinite(a)):
                self.fail(full, "must be finite")
            return a
        if kind == "matrix":
            if not isinstance(v, list) or not v or not all(isinstance(r, list) for r in v):
                self.fail(full, f"must be a list of rows, got {v!r}")
            try:
                a = np.array(v, dtype=float)
            except (TypeError, ValueError):
                self.fail(full, "rows must be lists of numbers of equal length")
            if a.ndim != 2 or not np.all(np.isfinite(a)):
                self.fail(full, "must be a finite matrix with rows of equal length")
            return a
        raise AssertionError(kind)


def short(value: Any) -> str:
    """``value``'s repr cut to 60 characters, for error messages."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."

