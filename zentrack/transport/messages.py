"""Typed wire messages: one frozen class per kind, its encoding beside its checked decoding.

Version 2 of the wire format (:mod:`zentrack.transport.codec` holds the framing) carries every seed's traffic:

- :class:`Measurement` (``meas``, truth -> node i): a *scan*, ``returns`` of shape ``(J, m)`` with J >= 0
  (J = 0: the sensor looked and saw nothing; None: no scan at all), and the sensor's ``pose`` at step k;
- :class:`RoundMessage` (``prior``, node -> neighbours): one fusion round's message, ``round`` (1..L) and
  ``blocks``, named information pairs (``{"state": (Y, y)}`` for a plain filter; e.g. kinematics and extent
  fused apart);
- :class:`EstimateMessage` (``est``, node -> observers): a node's kinematic posterior with its timings, flags
  and counters (named so as not to clash with ``zentrack.fusion.estimates.Estimate``);
- :class:`Truth` (``truth``), :class:`Start` (``ctl/start``, with the run's initial estimate ``x0``) and
  :class:`Stop` (``ctl/stop``).

The scans that rules of paper 2 exchange between neighbours (``scan``, ``relay``) are in
:mod:`zentrack.transport.scan_messages`, with the same conventions.

``encode()`` gives the bytes; ``decode(payload, ...)`` returns the class or raises
:class:`~zentrack.transport.codec.WireError` and nothing else: every field is checked, optional ones
included (an absent optional field takes its default; a present one must be of its type). Unknown fields are
ignored. The classes hold numpy arrays, so they compare by identity (``eq=False``); compare their fields, or
their encodings. The per-step decoders build their instances with :func:`~zentrack.transport.codec.built`
(without the frozen ``__init__``'s per-field ``object.__setattr__``), so the classes have no ``__slots__``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from zentrack.transport.codec import (
    MAX_BLOCK_NAME,
    MAX_BLOCKS,
    MAX_COUNT,
    MAX_COUNTER_NAME,
    MAX_COUNTERS,
    MAX_NODES,
    MAX_RELAYED,
    MAX_RETURNS,
    MAX_ROUNDS,
    MAX_SAMPLES,
    PSD_BLOCKS,
    WireError,
    all_within,
    built,
    check_pd,
    check_psd,
    check_step,
    encode,
    field,
    flag,
    header,
    node_id,
    node_message,
    number,
    optional_number,
    optional_rows,
    pack_array,
    pack_blocks,
    pack_symmetric,
    packed,
    short,
    truth_message,
    unpack,
    unpack_array,
    unpack_pose,
    unpack_returns,
    unpack_symmetric,
    unpack_vector,
    wire_kind,
)
from zentrack.transport.miss_notes import MissNote, unpack_notes

__all__ = ["Measurement", "RoundMessage", "EstimateMessage", "check_counters", "COUNTER_MAPS", "Truth", "Start",
           "Stop"]


@wire_kind("meas")
@dataclass(frozen=True, eq=False)
class Measurement:
    """Node ``node``'s scan at step k: ``returns`` ``(J, m)`` (J may be 0; a ``(m,)`` vector is one return) or
    None for no scan; ``pose`` the sensor's position, or None for the configured one (sent only with
    returns)."""

    k: int
    t: float
    node: int
    returns: np.ndarray | None
    pose: np.ndarray | None
    t_pub: float

    def encode(self) -> bytes:
        msg = header("meas", self.k, self.t, "truth")
        msg["node"], msg["present"], msg["t_pub"] = self.node, self.returns is not None, self.t_pub
        if self.returns is not None:
            msg["returns"] = pack_array(np.atleast_2d(self.returns))
            if self.pose is not None:
                msg["pose"] = pack_array(self.pose)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_node: int, m: int, lo: int | None = None, hi: int | None = None) -> Self:
        """A scan on ``meas/<key_node>`` (sender ``truth``) with returns of width ``m``, step in ``lo..hi``."""
        msg = unpack(payload)
        if msg["kind"] != "meas":
            raise WireError("kind", f"kind {msg['kind']!r} on a measurement key")
        if msg.get("sender") != "truth" or msg.get("node") != key_node or type(msg.get("node")) is not int:
            raise WireError("sender_mismatch", f"sender {short(msg.get('sender'))} / node {short(msg.get('node'))} on key of "
                                               f"node {key_node}")
        check_step(msg, lo, hi)
        present = field(msg, "present", bool)
        returns = unpack_returns(msg.get("returns"), m) if present else None
        pose = unpack_pose(msg["pose"]) if present and "pose" in msg else None
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "node": key_node, "returns": returns, "pose": pose,
                           "t_pub": number(msg, "t_pub")})


@wire_kind("prior")
@dataclass(frozen=True, eq=False)
class RoundMessage:
    """Node ``sender``'s message of fusion round ``round`` for step k: named information pairs ``(Y, y)``.
    ``t``: its time of validity, seconds after the run's ``t0`` on the sender's clock (``k ts``; a tracker of
    sensors of their own shares its estimate at the start of window k, ``(k - 1) ts``, which its receivers
    check); ``t_pub``: its publication on the sender's clock (receivers estimate the sender's clock from it).
    ``warm``: the sender has no recent measurement support (it is warming up or coasted too long), so a node
    with fresh pairs leaves this one out of its fusion."""

    k: int
    t: float
    sender: int
    round: int
    blocks: dict[str, tuple[np.ndarray, np.ndarray]]
    t_pub: float
    warm: bool = False

    def encode(self) -> bytes:
        msg = header("prior", self.k, self.t, self.sender)
        msg["round"], msg["blocks"] = int(self.round), pack_blocks(self.blocks)
        msg["t_pub"], msg["warm"] = self.t_pub, bool(self.warm)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_node: int, dims: dict[str, int] | int, lo: int | None = None,
               hi: int | None = None, max_round: int = 1) -> Self:
        """A message from ``prior/<key_node>``: sender, step window, round, the block names and sizes the
        receiver expects (``dims``: name -> n; an int means one block ``state``), finiteness, SPD (PSD for
        :data:`~zentrack.transport.codec.PSD_BLOCKS`)."""
        if isinstance(dims, int):
            dims = {"state": dims}
        msg = node_message(payload, ("prior",), key_node, lo, hi)
        rnd = field(msg, "round", int)
        if not 1 <= rnd <= min(max_round, MAX_ROUNDS):
            raise WireError("schema", f"round {rnd} outside 1..{max_round}")
        raw = field(msg, "blocks", dict)
        if len(raw) > MAX_BLOCKS or not all(isinstance(b, str) and len(b) <= MAX_BLOCK_NAME for b in raw):
            raise WireError("schema", "blocks: too many or badly named")
        if set(raw) != set(dims):
            raise WireError("shape", f"blocks {sorted(raw)} != expected {sorted(dims)}")
        blocks = {}
        for name, n in dims.items():
            pair = raw[name]
            if type(pair) is not dict:
                raise WireError("schema", f"block {name!r}: expected {{Y, y}}")
            y_mat = unpack_symmetric(pair.get("Y"), n, f"{name}.Y")
            y_vec = unpack_array(pair.get("y"), (n,), f"{name}.y")
            (check_psd if name in PSD_BLOCKS else check_pd)(y_mat, f"{name}.Y")
            blocks[name] = (y_mat, y_vec)
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "sender": key_node, "round": rnd, "blocks": blocks,
                           "t_pub": number(msg, "t_pub"), "warm": flag(msg, "warm")})


# ---------------------------------------------------------------- scans exchanged between nodes


#: the counters that are maps of name -> count (``NodeSchedule.snapshot``); every other counter is a count
COUNTER_MAPS = frozenset({"rejected", "dropped", "refused", "detections"})


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


@wire_kind("est")
@dataclass(frozen=True, eq=False)
class EstimateMessage:
    """A node's posterior for step k (kinematic mean ``x`` and covariance ``P``), valid at ``t`` (``k ts``)
    seconds after the run's ``t0`` on the sender's clock, and what it says about the step: ``t_meas_pub`` (the measurement's publication, None when it coasted), ``t_recv``, ``t_pub`` (wall
    clock, s) and ``update_us`` (the local update's duration); ``fused``, the pairs its prior fused;
    ``coasted``, ``warm``, ``miss`` (deadline missed); ``neighbours`` expected; ``round_ms``, how long each
    fusion round of the prior took; ``miss_notes``, the deadline misses it saw since its last estimate
    (:class:`~zentrack.transport.miss_notes.MissNote`); for viewers ``samples`` ``(S, n)`` of a particle cloud and ``beta``
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
    miss_notes: tuple[MissNote, ...] = ()

    def encode(self) -> bytes:
        msg = header("est", self.k, self.t, self.sender)
        msg.update(x=pack_array(self.x), P=pack_symmetric(self.P), t_meas_pub=self.t_meas_pub, t_recv=self.t_recv,
                   t_pub=self.t_pub, update_us=self.update_us, fused=self.fused, coasted=self.coasted, warm=self.warm,
                   miss=self.miss, neighbours=list(self.neighbours))
        if self.counters is not None:
            msg["counters"] = self.counters
        if self.miss_notes:
            msg["miss_notes"] = [n.pack() for n in self.miss_notes]
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
            "miss_notes": unpack_notes(msg.get("miss_notes")),
        })


@wire_kind("truth")
@dataclass(frozen=True, eq=False)
class Truth:
    """The true state ``x`` at step k (for viewers)."""

    k: int
    t: float
    x: np.ndarray
    t_pub: float

    def encode(self) -> bytes:
        return encode("truth", self.k, self.t, "truth", x=pack_array(self.x), t_pub=self.t_pub)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        msg = truth_message(payload, "truth")
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "x": unpack_vector(msg.get("x"), "x"),
                           "t_pub": number(msg, "t_pub")})


@wire_kind("start")
@dataclass(frozen=True, eq=False)
class Start:
    """The run's start: ``t0`` (wall clock of step 0), the period ``ts``, ``steps``, ``mode`` (realtime or
    lockstep), the ``participants``, the deadline as a fraction of the period, and the initial estimate ``x0``
    every tracker starts from."""

    t0: float
    ts: float
    steps: int
    mode: str
    participants: tuple[int, ...]
    deadline_frac: float
    x0: np.ndarray

    def encode(self) -> bytes:
        return encode("start", 0, 0.0, "truth", t0=self.t0, ts=self.ts, steps=self.steps, mode=self.mode,
                      participants=list(self.participants), deadline_frac=self.deadline_frac, x0=pack_array(self.x0))

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        msg = truth_message(payload, "start")
        t0, ts, steps = number(msg, "t0"), number(msg, "ts"), field(msg, "steps", int)
        mode, parts = field(msg, "mode", str), field(msg, "participants", list)
        frac = number(msg, "deadline_frac")
        if not (ts > 0 and 0 < steps <= MAX_COUNT and 0 < frac < 1):
            raise WireError("schema", "start: ts/steps/deadline_frac out of range")
        if mode not in ("realtime", "lockstep"):
            raise WireError("schema", f"start: bad mode {short(mode)}")
        participants = tuple(node_id(p, "start: participants") for p in parts)
        return cls(t0, ts, steps, mode, participants, frac, unpack_vector(msg.get("x0"), "start: x0"))


@wire_kind("stop")
@dataclass(frozen=True, eq=False)
class Stop:
    """The run's end (the truth's last step, or the step at which it gave up)."""

    k: int

    def encode(self) -> bytes:
        return encode("stop", self.k, 0.0, "truth")

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        return cls(truth_message(payload, "stop")["k"])
