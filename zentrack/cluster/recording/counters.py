"""Each node's counters as the recorder hears them, banked over the node's restarts (its incarnations).

A node's counters (``NodeSchedule.snapshot``: steps, misses, messages received and refused, ...) ride on every
``COUNTERS_EVERY_STEPS``-th message it publishes and count from zero in each incarnation. The recorder keeps the
last ones heard per node; when they come from a new incarnation (another ``incarnation``, or fewer ``steps``),
the predecessor's last counts are banked, so a node's figures are summed over its restarts.
"""
from __future__ import annotations

from typing import Any

import numpy as np


class CounterBank:
    """The counters of every node of a run: the last heard, the banked ones of its earlier incarnations."""

    def __init__(self, nodes: int) -> None:
        #: per node, the counters of its earlier incarnations summed (each one's last counters heard)
        self.total: list[dict] = [dict() for _ in range(nodes)]
        #: per node, the last counters heard (of its current incarnation)
        self.last: list[dict] = [dict() for _ in range(nodes)]
        #: messages received from each node since its last one carrying counters (of that incarnation)
        self.received_since: np.ndarray = np.zeros(nodes, dtype=int)
        #: restarts seen per node (a new incarnation's counters after an earlier one's)
        self.restarts: np.ndarray = np.zeros(nodes, dtype=int)

    def bank(self, node: int, counters: dict[str, Any] | None) -> None:
        """Note the counters of a message from ``node`` (None: this message carries none)."""
        if counters is None:  # carried every COUNTERS_EVERY_STEPS messages, not by this one
            self.received_since[node] += 1
            return
        last = self.last[node]
        restarted = counters.get("incarnation", 0) != last.get("incarnation", 0) or counters.get("steps", 0) < last.get("steps", 0)
        if last and restarted:  # the node restarted: bank its predecessor's counts
            self.restarts[node] += 1
            _add_counters(self.total[node], _with_received(last, int(self.received_since[node])))
        self.last[node] = counters
        self.received_since[node] = 0

    def summed(self, node: int, report: dict | None) -> dict:
        """The node's counters summed over its incarnations (:func:`final_counters`), its final report
        ``report`` (``node-<i>.json``, None without one) taken where it counts more."""
        return final_counters(self.total[node], self.last[node], report, int(self.received_since[node]))

    def latest(self, node: int, report: dict | None) -> dict:
        """The node's final report when there is one, else the last counters heard (its current incarnation's)."""
        return report or self.last[node]


def final_counters(banked: dict, last: dict, report: dict | None, since: int = 0) -> dict:
    """Counters summed over a node's incarnations: ``banked`` (earlier ones, from their last estimates),
    then the current one from the larger of its last estimate's and its final report's counts. ``since``:
    estimates received after the last one carrying counters (published, so counted as such)."""
    total = dict(banked)
    last = _with_received(last, since)
    if report is None:
        _add_counters(total, last)
        return total
    if last and report.get("incarnation") != last.get("incarnation"):
        _add_counters(total, last)  # the reporting incarnation published no estimate at all
        _add_counters(total, report)
        return total
    merged = dict(last)
    for key, value in report.items():
        if isinstance(value, dict):
            merged[key] = {r: max(value.get(r, 0), (last.get(key) or {}).get(r, 0)) for r in {*value, *(last.get(key) or {})}}
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and key != "incarnation":
            merged[key] = max(value, last.get(key, 0) or 0)
    _add_counters(total, merged)
    return total


def _with_received(last: dict, since: int) -> dict:
    """An incarnation's last counters, with the ``since`` estimates received after them counted as published:
    counters ride on every COUNTERS_EVERY_STEPS-th estimate only, so a killed node's are up to 9 steps old
    (without this, those estimates would look lost)."""
    return {**last, "steps": last.get("steps", 0) + since} if last and since else last


def _add_counters(total: dict, add: dict) -> None:
    for key, value in add.items():
        if key == "incarnation" or isinstance(value, bool):
            continue
        if isinstance(value, dict):
            _add_counters(total.setdefault(key, {}), value)
        elif isinstance(value, (int, float)):
            total[key] = total.get(key, 0) + value
