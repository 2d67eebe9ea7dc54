"""``[sensor_timing]``: sensors of their own (issue 52), each its own process with its own rate, phase, clock and
latency, instead of the truth's measurement of every step.

Sensor s is the scenario's sensor s (its position and noise) sampling on its own timing
(:class:`~zentrack.truth.simulation.sensor_stream.SensorStreamSpec`). The per-sensor keys
(:data:`SENSOR_KEYS`) take one value for every sensor or a list of one per sensor; ``lag_ms`` is how far the
trackers' schedule runs behind the run's, ``clock`` whether a tracker is told each sensor's clock offset
(``configured``: its neighbours' clocks taken as synchronised) or estimates it, and its neighbours', from the
stream (``estimated``, the default: ``node/diffusion/neighbour_clocks.py``), and ``takes`` which sensors each
tracker takes (default: tracker i takes sensor i; a sensor may feed several trackers).

A sensor applies the scenario's P_D (``[sensing]`` of many targets, ``[clutter]`` of one), times its own
``detection_prob``, its noise and the scenario's clutter. What cannot run asynchronously yet is refused in one
line (:func:`asynchronous_refusal`): lockstep, rules that exchange or relay scans, fuse posteriors or run more than
one round, plants a tracker cannot predict over any interval, bearing-only many-target sensors (their trackers
exchange scans), relay nodes and moving sensors. Every other error names the file and the key
(:class:`~zentrack.config.scenario_reader.ScenarioReader`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NoReturn

from zentrack.common.suggest import did_you_mean
from zentrack.config.node_config import DETECTION_CLOCKS, MAX_LATENCY_BUDGET_MS
from zentrack.fusion.models import INTERVAL_PLANTS
from zentrack.truth.simulation.sensor_stream import LATENCY_KINDS, Latency, SensorStreamSpec

SECTION = "sensor_timing"
#: the keys that take one value for every sensor or one per sensor, and their defaults (None: see below)
SENSOR_KEYS: dict[str, Any] = {
    "rate_hz": None,  # the run's rate, 1 / ts
    "phase_s": 0.0,
    "offset_s": 0.0,
    "drift_ppm": 0.0,
    "latency": "fixed",
    "latency_low_ms": 0.0,
    "latency_high_ms": None,  # uniform: required; exponential: the cap, default MAX_LATENCY_MS
    "latency_mean_ms": None,  # exponential: required
    "reorder": 0.0,
    "detection_prob": 1.0,
}
#: how a tracker knows a sensor's clock and its neighbours'
CLOCKS = DETECTION_CLOCKS
#: the longest latency a sensor may have (ms; the stream's own limit)
MAX_LATENCY_MS = 60_000.0
#: the bounds of the numeric per-sensor keys (inclusive; rate_hz above 0, detection_prob above 0)
KEY_BOUNDS = {"rate_hz": (0.0, 1000.0), "offset_s": (-3600.0, 3600.0), "drift_ppm": (-1e4, 1e4),
              "latency_low_ms": (0.0, MAX_LATENCY_MS), "latency_high_ms": (0.0, MAX_LATENCY_MS),
              "latency_mean_ms": (0.0, MAX_LATENCY_MS), "reorder": (0.0, 1.0), "detection_prob": (0.0, 1.0)}
#: which latency kinds take which latency key
LATENCY_TAKES = {"latency_high_ms": ("uniform", "exponential"), "latency_mean_ms": ("exponential",)}


@dataclass(frozen=True)
class SensorTiming:
    """A scenario's ``[sensor_timing]``: the values as the file gives them (``values``: per-sensor key -> one
    value or a list), resolved for ``sensors`` sensors (``streams``) and the trackers (``takes``)."""

    values: Mapping[str, Any]
    lag_ms: float
    clock: str
    takes_given: tuple[tuple[int, ...], ...] | None
    streams: tuple[SensorStreamSpec, ...]
    takes: tuple[tuple[int, ...], ...]
    ts: float
    source: str = field(default="", compare=False)

    @property
    def sensors(self) -> int:
        return len(self.streams)

    def stream(self, sensor: int) -> SensorStreamSpec:
        return self.streams[sensor]

    def detections(self, node: int) -> dict[str, Any]:
        """Tracker ``node``'s ``NodeConfig.detections``: the lag, the clock (its neighbours' too) and, per sensor it
        takes, its rate, its clock offset (``configured``; else None: estimated) and its least latency."""
        return {"lag_ms": float(self.lag_ms), "clock": self.clock, "sensors": [
            {"sensor": s, "rate_hz": float(self.streams[s].rate_hz),
             "offset_s": float(self.streams[s].offset_s) if self.clock == "configured" else None,
             "min_latency_s": float(self.streams[s].latency.low_s)} for s in self.takes[node]]}

    def resized(self, sensors: int) -> SensorTiming:
        """The same section for ``sensors`` sensors and trackers (``--nodes``): ValueError naming the source and
        the key when a list or ``takes`` fixes another count."""
        if sensors == self.sensors:
            return self

        def fail(key: str, msg: str) -> NoReturn:
            raise ValueError(f"{self.source}: {key}: {msg} (--nodes {sensors})")

        return resolve(self.values, self.lag_ms, self.clock, self.takes_given, sensors, self.ts, fail, self.source)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def per_sensor(values: Mapping[str, Any], key: str, sensors: int, fail: Callable[[str, str], NoReturn]) -> list:
    """Key ``key``'s value for each of ``sensors`` sensors: one value for all, or a list of one per sensor."""
    full = f"{SECTION}.{key}"
    value = values.get(key, SENSOR_KEYS[key])
    if isinstance(value, list):
        if len(value) != sensors:
            fail(full, f"lists {len(value)} value(s); give one value for every sensor or one per sensor ({sensors})")
        return list(value)
    return [value] * sensors


def _check_value(key: str, value: Any, sensor: int, fail: Callable[[str, str], NoReturn]) -> Any:
    full, which = f"{SECTION}.{key}", f" (sensor {sensor})"
    if key == "latency":
        if not isinstance(value, str) or value not in LATENCY_KINDS:
            fail(full, f"{value!r}{which} is not allowed; choose one of {', '.join(LATENCY_KINDS)}"
                       f"{did_you_mean(str(value), LATENCY_KINDS)}")
        return value
    if value is None:
        return None
    if not _is_number(value):
        fail(full, f"must be a finite number or a list of them, got {value!r}{which}")
    lo, hi = KEY_BOUNDS.get(key, (-math.inf, math.inf))
    if not lo <= value <= hi or (key in ("rate_hz", "detection_prob") and value <= 0):
        opening = "above" if key in ("rate_hz", "detection_prob") else "from"
        fail(full, f"must be {opening} {lo:g} to {hi:g}, got {value!r}{which}")
    return float(value)


def resolve(values: Mapping[str, Any], lag_ms: float, clock: str, takes: tuple[tuple[int, ...], ...] | None,
            sensors: int, ts: float, fail: Callable[[str, str], NoReturn], source: str = "") -> SensorTiming:
    """The section's values for ``sensors`` sensors (and as many trackers), each checked (``fail(key, why)``)."""
    cols = {key: [_check_value(key, v, s, fail) for s, v in enumerate(per_sensor(values, key, sensors, fail))]
            for key in SENSOR_KEYS}
    for key, kinds in LATENCY_TAKES.items():
        if key in values and not any(kind in kinds for kind in cols["latency"]):
            fail(f"{SECTION}.{key}", f"no sensor's latency takes it (only {' and '.join(kinds)} latencies do)")
    streams = []
    for s in range(sensors):
        rate = cols["rate_hz"][s] if cols["rate_hz"][s] is not None else 1.0 / ts
        phase = cols["phase_s"][s]
        if not 0 <= phase < 1.0 / rate:
            fail(f"{SECTION}.phase_s", f"must be from 0 to below one period of sensor {s} ({1.0 / rate:g} s), "
                                       f"got {phase!r}")
        kind, low, high, mean = (cols["latency"][s], cols["latency_low_ms"][s], cols["latency_high_ms"][s],
                                 cols["latency_mean_ms"][s])
        if kind == "uniform" and high is None:
            fail(f"{SECTION}.latency_high_ms", f"missing: sensor {s}'s uniform latency needs its upper end")
        if kind == "exponential" and mean is None:
            fail(f"{SECTION}.latency_mean_ms", f"missing: sensor {s}'s exponential latency needs its mean")
        if kind == "exponential" and high is None:
            high = MAX_LATENCY_MS
        if kind != "fixed" and high < low:
            fail(f"{SECTION}.latency_high_ms", f"must be at least latency_low_ms ({low:g}) for sensor {s}, got {high:g}")
        latency = Latency(kind, low / 1e3, (high if kind != "fixed" else low) / 1e3,
                          (mean or 0.0) / 1e3 if kind == "exponential" else 0.0)
        try:
            streams.append(SensorStreamSpec(s, rate, phase, cols["offset_s"][s], cols["drift_ppm"][s], latency,
                                            cols["reorder"][s], cols["detection_prob"][s]))
        except ValueError as exc:  # (every bound is checked above; what is left names the sensor)
            fail(SECTION, str(exc))
    resolved: tuple[tuple[int, ...], ...]
    if takes is None:
        resolved = tuple((i,) for i in range(sensors))
    else:
        if len(takes) != sensors:
            fail(f"{SECTION}.takes", f"lists {len(takes)} tracker(s); give one list of sensor ids per tracker "
                                     f"({sensors})")
        for i, row in enumerate(takes):
            if not row or len(set(row)) != len(row) or any(not 0 <= s < sensors for s in row):
                fail(f"{SECTION}.takes", f"tracker {i} must take at least one sensor, distinct ids from 0 to "
                                         f"{sensors - 1}, got {list(row)}")
        resolved = takes
    return SensorTiming(dict(values), lag_ms, clock, takes, tuple(streams), resolved, ts, source)


def sensor_timing_section(label: str, table: Any, sensors: int, ts: float,
                          fail: Callable[[str, str], NoReturn]) -> SensorTiming:
    """``[sensor_timing]`` of the file ``label`` for its ``sensors`` sensors (``fail(key, why)`` raises)."""
    if not isinstance(table, dict):
        fail(SECTION, "must be a table")
    if "lag_ms" not in table:
        fail(f"{SECTION}.lag_ms", "missing: how far (ms) the trackers' schedule runs behind the run's, so that "
                                  "late detections still count")
    lag = table["lag_ms"]
    if not (_is_number(lag) and 0 <= lag <= MAX_LATENCY_BUDGET_MS):
        fail(f"{SECTION}.lag_ms", f"must be from 0 to {MAX_LATENCY_BUDGET_MS:g} ms, got {lag!r}")
    clock = table.get("clock", "estimated")
    if clock not in CLOCKS:
        fail(f"{SECTION}.clock", f"{clock!r} is not allowed; choose one of {', '.join(CLOCKS)}"
                                 f"{did_you_mean(str(clock), CLOCKS)}")
    takes = table.get("takes")
    if takes is not None:
        if not isinstance(takes, list) or not all(
                isinstance(row, list) and all(type(s) is int for s in row) for row in takes):
            fail(f"{SECTION}.takes", f"must be one list of sensor ids per tracker, got {takes!r}")
        takes = tuple(tuple(row) for row in takes)
    values = {key: table[key] for key in SENSOR_KEYS if key in table}
    return resolve(values, float(lag), clock, takes, sensors, ts, fail, label)


def asynchronous_refusal(mode: str, fusion: str, fusion_params: Mapping[str, Any], spec: Any,
                         multitarget: Any = None) -> str | None:
    """Why a run with sensors of their own cannot run this way (one line), or None. ``spec``: the
    :class:`~zentrack.truth.simulation.scenario_spec.ScenarioSpec`; ``multitarget``: a many-target scenario's
    :class:`~zentrack.truth.simulation.multitarget.MultiTargetSpec` (None: one target)."""
    from zentrack.fusion.rules import make_rule

    if mode != "realtime":
        return (f"sensors of their own run in realtime only; timing {mode!r} runs on the truth's grid "
                "(use realtime)")
    if multitarget and "bearing" in multitarget.sensor_kinds(spec.measurement, spec.nodes):
        return ("many-target bearing sensors start their tracks by triangulating the neighbours' scans of each step, "
                "which their trackers exchange; sensors of their own take point sensors only")
    if spec.plant not in INTERVAL_PLANTS:
        return (f"plant {spec.plant!r} is defined on its sample period only; sensors of their own need a plant a "
                f"tracker predicts over any interval ({', '.join(INTERVAL_PLANTS)})")
    if spec.roles is not None and "relay" in spec.roles:
        return "sensors of their own do not take relay nodes ([sensors] relays) yet"
    if spec.moving:
        return "sensors of their own sit still; moving sensors (velocities, orbits) are not taken yet"
    if fusion_params.get("rounds") == "auto":
        return f"fusion rule {fusion!r} with rounds = \"auto\" runs several rounds a step; sensors of their own take one"
    try:
        rule = make_rule(fusion, dict(fusion_params))
    except ValueError:
        return None  # (the rule's own check names what is wrong)
    if rule.exchanges_scans or rule.relays_scans:
        return (f"fusion rule {fusion!r} exchanges scans between trackers at each step; a tracker of sensors of "
                "their own shares its estimates only")
    if rule.fuses_posterior:
        return f"fusion rule {fusion!r} fuses posteriors; sensors of their own take a rule that fuses priors"
    if any(rule.rounds(k) > 1 for k in range(1, 4)):
        return f"fusion rule {fusion!r} runs several rounds a step; sensors of their own take one round"
    return None
