"""A many-target node slice's tracker parameters (``NodeConfig.multitarget``, the fields of
:class:`~zentrack.fusion.multitarget.network.TrackerSettings` after the models): their names and what each takes."""
from __future__ import annotations

import math
from typing import Any

from zentrack.common.suggest import did_you_mean
from zentrack.fusion.defaults import MULTITARGET_TRACKERS

#: the numbers a slice may carry and their ranges
MULTITARGET_NUMBERS: dict[str, tuple[float, float]] = {
    "detection_prob": (1e-6, 1.0), "clutter_density": (1e-30, 1e6), "gate_prob": (0.5, 1.0 - 1e-12),
    "max_speed": (0.0, 1e5), "confirm_m": (1, 100), "confirm_n": (1, 100), "max_misses": (1, 10_000),
    "max_range": (1e-3, 1e8),
}
#: the other fields: what each must be
MULTITARGET_CHOICES = {"track_rule": "a fusion rule's name", "tracker": f"one of {', '.join(MULTITARGET_TRACKERS)}",
                       "share_scans": "true or false"}
MULTITARGET_KEYS = (*MULTITARGET_NUMBERS, *MULTITARGET_CHOICES)


def _fits(key: str, value: Any) -> bool:
    if key == "track_rule":
        return isinstance(value, str) and bool(value)
    if key == "tracker":
        return value in MULTITARGET_TRACKERS
    if key == "share_scans":
        return isinstance(value, bool)
    lo, hi = MULTITARGET_NUMBERS[key]
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and lo <= value <= hi


def multitarget_problem(mt: Any) -> tuple[str, str] | None:
    """The first thing wrong with a slice's ``multitarget`` map, ``(field, why)``; None when nothing is."""
    if not isinstance(mt, dict):
        return "multitarget", f"must be a map of {', '.join(MULTITARGET_KEYS)}"
    for key in sorted(set(mt) - set(MULTITARGET_KEYS)):
        return f"multitarget.{key}", f"unknown key{did_you_mean(key, MULTITARGET_KEYS)}; allowed: {', '.join(MULTITARGET_KEYS)}"
    for key, value in mt.items():
        if not _fits(key, value):
            lo_hi = MULTITARGET_NUMBERS.get(key)
            want = f"from {lo_hi[0]:g} to {lo_hi[1]:g}" if lo_hi else MULTITARGET_CHOICES[key]
            return f"multitarget.{key}", f"must be {want}, got {value!r}"
    return None
