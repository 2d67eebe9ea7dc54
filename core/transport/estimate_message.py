"""The estimate message (``est``): a node's kinematic posterior, its timings, flags and counters.

Named :class:`EstimateMessage` so as not to clash with ``zentrack.fusion.estimates.Estimate``; like the classes
of :mod:`zentrack.transport.messages` (which re-exports it) it is frozen, ``encode()`` gives its bytes and
``decode()`` returns it or raises :class:`~zentrack.transport.codec.WireError`. Observers (the recorder, the
viewer, the truth's lockstep barrier) read only what :meth:`EstimateMessage.decode` checked: every optional
field of its type, times finite, counts non-negative, and the counters of the structure
``NodeSchedule.snapshot`` gives them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from zentrack.transport.codec import (
    MAX_COUNT,
    MAX_COUNTER_NAME,
    MAX_COUNTERS,
    MAX_NODES,
    MAX_RELAYED,
    MAX_RETURNS,
    MAX_ROUNDS,
    MAX_SAMPLES,
    WireError,
    all_within,
    built,
    check_pd,
    flag,
    header,
    node_id,
    node_message,
    number,
    optional_number,
    optional_rows,
    pack_array,
    pack_symmetric,
    packed,
    short,
    unpack_symmetric,
    unpack_vector,
)

#: the counters that are maps of name -> count (``NodeSchedule.snapshot``); every other counter is a count
COUNTER_MAPS = frozenset({"rejected", "dropped", "refused"})


def _names(obj: Any, what: str) -> dict:
    """``obj`` if it is a map of at most MAX_COUNTERS names of 1 to MAX_COUNTER_NAME characters."""
    if type(obj) is not dict or len(obj) > MAX_COUNTERS:
        raise WireError("schema", f"counters: {what} must be a map of at most {MAX_COUNTERS} names")
    return obj


def _bad_name(name: Any) -> bool:
    return type(name) is not str or not 0 < len(name) <= MAX_COUNTER_NAME


def _bad_count(value: Any) -> bool:
    return type(value) is not int or not 0 <= value <= MAX_COUNT


def check_counters(obj: Any) -> dict[str, Any]:
    """A node's counters (``NodeSchedule.snapshot``): names -> counts (ints from 0 to MAX_COUNT), except
    :data:`COUNTER_MAPS`, which map names (reasons) -> counts; ``incarnation`` is a count too."""
    for name, value in _names(obj, "the counters").items():
        if _bad_name(name):
            raise WireError("schema", f"counters: a name that is not 1 to {MAX_COUNTER_NAME} characters")
        if name not in COUNTER_MAPS:
            if _bad_count(value):
                raise WireError("schema", f"counters: {name} is {short(value)}, not a count")
            continue
        for reason, count in _names(value, name).items():
            if _bad_name(reason) or _bad_count(count):
                raise WireError("schema", f"counters: {name} holds a bad name or count")
    return obj


def _neighbours(obj: Any) -> tuple[int, ...]:
    if obj is None:
        return ()
    if type(obj) is not list or len(obj) > MAX_RELAYED:
        raise WireError("schema", f"neighbours: expected a list of at most {MAX_RELAYED} node ids")
    return tuple(node_id(j, "neighbours") for j in obj)


@dataclass(frozen=True, eq=False)
class EstimateMessage:
    """A node's posterior for step k (kinematic mean ``x`` and covariance ``P``) and what it says about the
    step: ``t_meas_pub`` (the measurement's publication, None when it coasted), ``t_recv``, ``t_pub`` (wall
    clock, s) and ``update_us`` (the local update's duration); ``fused``, the pairs its prior fused;
    ``coasted``, ``warm``, ``miss`` (deadline missed); ``neighbours`` expected; ``round_ms``, how long each
    fusion round of the prior took; for viewers ``samples`` ``(S, n)`` of a particle cloud and ``beta``
    ``(J,)``, the association probability of each return of its scan; ``counters`` every few steps."""

    k: int
    t: float
    sender: int
    x: np.ndarray
    P: np.ndarray
    t_pub: float
    t_meas_pub: float | None = None
    t_recv: float | None = None
    update_us: float | None = None
    fused: int = 0
    coasted: bool = False
    warm: bool = False
    miss: bool = False
    neighbours: tuple[int, ...] = ()
    round_ms: np.ndarray | None = None
    samples: np.ndarray | None = None
    beta: np.ndarray | None = None
    counters: dict[str, Any] | None = None

    def encode(self) -> bytes:
        msg = header("est", self.k, self.t, self.sender)
        msg.update(x=pack_array(self.x), P=pack_symmetric(self.P), t_meas_pub=self.t_meas_pub, t_recv=self.t_recv,
                   t_pub=self.t_pub, update_us=self.update_us, fused=self.fused, coasted=self.coasted, warm=self.warm,
                   miss=self.miss, neighbours=list(self.neighbours))
        if self.counters is not None:
            msg["counters"] = self.counters
        if self.round_ms is not None and len(self.round_ms):
            msg["round_ms"] = pack_array(np.asarray(self.round_ms, dtype=float))
        if self.samples is not None:
            msg["samples"] = pack_array(self.samples)
        if self.beta is not None:
            msg["beta"] = pack_array(self.beta)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_node: int) -> Self:
        """An estimate on ``est/<key_node>``: ``x`` a vector of 1 to MAX_DIM values, ``P`` its symmetric
        positive definite covariance, every other field of its type (times finite, counts non-negative)."""
        msg = node_message(payload, ("est",), key_node)
        x = unpack_vector(msg.get("x"), "x")
        n = x.shape[0]
        cov = unpack_symmetric(msg.get("P"), n, "P")
        check_pd(cov, "P")
        fused = msg.get("fused", 0)
        if type(fused) is not int or not 0 <= fused <= MAX_NODES:  # the own pair and every neighbour's
            raise WireError("schema", f"fused: {short(fused)} is not a count of pairs")
        beta = optional_rows(msg.get("beta"), None, MAX_RETURNS, "beta")
        if beta is not None and not all_within(beta, 0.0, 1.0):
            raise WireError("schema", "beta: association probabilities must lie in [0, 1]")
        rounds = optional_rows(msg.get("round_ms"), None, MAX_ROUNDS, "round_ms")
        if rounds is not None and not all_within(rounds, 0.0, math.inf):
            raise WireError("schema", "round_ms: round durations must be non-negative")
        counters = msg.get("counters")
        return built(cls, {
            "k": msg["k"], "t": float(msg["t"]), "sender": key_node, "x": x, "P": cov, "t_pub": number(msg, "t_pub"),
            "t_meas_pub": optional_number(msg, "t_meas_pub"), "t_recv": optional_number(msg, "t_recv"),
            "update_us": optional_number(msg, "update_us"), "fused": fused, "coasted": flag(msg, "coasted"),
            "warm": flag(msg, "warm"), "miss": flag(msg, "miss"), "neighbours": _neighbours(msg.get("neighbours")),
            "round_ms": rounds, "samples": optional_rows(msg.get("samples"), n, MAX_SAMPLES, "samples"), "beta": beta,
            "counters": None if counters is None else check_counters(counters),
        })
