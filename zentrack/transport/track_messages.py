"""Typed wire messages of a many-target run: a node's track list, :class:`TrackList` (``tracks``, node ->
neighbours and observers, on ``tracks/<i>``), one :class:`TrackEntry` per track; and the truth's
:class:`TargetSet` (``targets``, truth -> observers, on ``truth``): the targets present at step k.

Each step a node with a multi-target tracker publishes its tracks at step k (confirmed ones for its
neighbours' track-to-track fusion, :mod:`zentrack.fusion.track_to_track`; an empty list says "no track", so
the neighbours need not wait). Same conventions as :mod:`zentrack.transport.messages`: a frozen class,
``encode()`` beside a ``decode()`` that returns the class or raises
:class:`~zentrack.transport.codec.WireError` and nothing else. Decoding checks the kind, that the sender is
the key's node, the step window, at most :data:`MAX_TRACKS` tracks, each id ``[born, node, serial]`` (born no
later than k, node a node id, serial a count) and unique in the list, the status, every mean value finite
and within MAX_COORDINATE and every covariance a symmetric positive definite ``(n, n)`` matrix whose
eigenvalues lie from :data:`MIN_TRACK_VARIANCE` to :data:`MAX_TRACK_VARIANCE` within a condition number of
``1 / MIN_EIGEN_RATIO``.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from zentrack.fusion.track_to_track import TRACK_STATUSES, TrackEstimate, TrackId
from zentrack.transport.codec import (
    MAX_COORDINATE,
    MAX_COUNT,
    MAX_MESSAGE_BYTES,
    WireError,
    built,
    encode,
    field,
    flag,
    node_id,
    node_message,
    number,
    optional_number,
    optional_rows,
    pack_array,
    pack_symmetric,
    short,
    truth_message,
    unpack_symmetrics,
    unpack_vectors,
    wire_kind,
)
from zentrack.transport.messages import check_counters

__all__ = ["MAX_TARGETS_ON_WIRE", "MAX_TRACKS", "TargetSet", "TrackEntry", "TrackList"]

#: the largest variance a track's covariance may hold (m^2 or (m/s)^2: a 1000 km standard deviation), and the
#: smallest eigenvalue relative to the largest: beyond either, the fusion's inverses overflow or lose every digit
MAX_TRACK_VARIANCE = 1e12
MIN_EIGEN_RATIO = 1e-12
#: the smallest variance (a micrometre's standard deviation): below it the information form overflows
MIN_TRACK_VARIANCE = 1e-12
#: targets one truth message may carry (a many-target scenario holds at most 1000; 1000 6-D states are 48 KB)
MAX_TARGETS_ON_WIRE = 1000

#: tracks one list may carry: five times the 50 targets of the issue's live goal (a list of 256 6-D tracks is
#: about 75 KB, within MAX_MESSAGE_BYTES)
MAX_TRACKS = 256


@dataclass(frozen=True, eq=False)
class TrackEntry:
    """One track of a :class:`TrackList`: its network id, its status (``tentative`` or ``confirmed``), mean
    ``(n,)`` and covariance ``(n, n)`` at the list's step, ``misses``: the steps since the sender last
    measured it (0: at this step), and ``existence``: the probability the target exists (a PMBM node's; ``r``
    on the wire, left out when it is 1)."""

    id: TrackId
    status: str
    mean: np.ndarray
    cov: np.ndarray
    misses: int = 0
    existence: float = 1.0

    def packed(self) -> dict:
        out = {"id": [int(self.id.born), int(self.id.node), int(self.id.serial)], "status": self.status,
               "x": pack_array(self.mean), "P": pack_symmetric(self.cov), "m": int(self.misses)}
        if self.existence < 1.0:
            out["r"] = float(self.existence)
        return out


def _count(value: Any, what: str) -> int:
    if type(value) is not int or not 0 <= value <= MAX_COUNT:
        raise WireError("schema", f"{what}: {short(value)} is not a count")
    return value


def _track_id(obj: Any, k: int) -> TrackId:
    if type(obj) is not list or len(obj) != 3:
        raise WireError("schema", f"track id {short(obj)} is not [born, node, serial]")
    born = _count(obj[0], "track id born")
    if born > k:
        raise WireError("schema", f"track id {short(obj)} born at step {born}, after the list's step {k}")
    # built without the frozen dataclass's __init__, which costs more than these checks (50 ids a list)
    return built(TrackId, {"born": born, "node": node_id(obj[1], "track id node"),
                           "serial": _count(obj[2], "track id serial")})


def _entries(raw: list, n: int, k: int) -> tuple[TrackEntry, ...]:
    """A list's tracks, each one's fields checked (id, status, the form of its mean and covariance, misses), then
    the values of every mean (finite, within range) and covariance (finite) at once, the first failing track named;
    the covariances' eigenvalues not yet (:func:`_check_covariances` checks the whole list's in one call)."""
    heads = []
    for obj in raw:
        if type(obj) is not dict:
            raise WireError("schema", "tracks: expected a map per track")
        track_id = _track_id(obj.get("id"), k)
        status = obj.get("status")
        if type(status) is not str or status not in TRACK_STATUSES:
            raise WireError("schema", f"{_name(track_id)}: status {short(status)} not one of {', '.join(TRACK_STATUSES)}")
        misses = obj.get("m", 0)
        if type(misses) is not int or not 0 <= misses <= MAX_COUNT:  # (_count, its name made only when it fails)
            _count(misses, f"{_name(track_id)} misses")
        existence = obj.get("r", 1.0)
        if type(existence) is not float or not 0.0 < existence <= 1.0:  # (NaN fails both)
            raise WireError("schema", f"{_name(track_id)}: existence r {short(existence)} is not a probability in (0, 1]")
        heads.append((track_id, status, misses, existence))
    means = unpack_vectors([obj.get("x") for obj in raw], n, lambda i: f"{_name(heads[i][0])} x", MAX_COORDINATE)
    covs = unpack_symmetrics([obj.get("P") for obj in raw], n, lambda i: f"{_name(heads[i][0])} P")
    return tuple(built(TrackEntry, {"id": track_id, "status": status, "mean": mean, "cov": cov, "misses": misses,
                                    "existence": existence})
                 for (track_id, status, misses, existence), mean, cov in zip(heads, means, covs))


def _name(track_id: TrackId) -> str:
    return f"track {track_id.born}/{track_id.node}/{track_id.serial}"


def _check_covariances(tracks: tuple[TrackEntry, ...]) -> None:
    """Every track's covariance (finite and symmetric: :func:`_entry`) positive definite (``not_pd``) with
    eigenvalues a track can hold (``range``): one batched eigen-decomposition for the list, the first failing
    track named (a check per track was the largest part of a many-target tracker's decoding)."""
    if not tracks:
        return
    eig = np.linalg.eigvalsh(np.stack([e.cov for e in tracks]))
    low, high = eig[:, 0], eig[:, -1]
    bad = np.flatnonzero(~(low > 0) | (high > MAX_TRACK_VARIANCE) | (low < np.maximum(MIN_TRACK_VARIANCE,
                                                                                     MIN_EIGEN_RATIO * high)))
    if bad.size == 0:
        return
    i = int(bad[0])
    name = f"{_name(tracks[i].id)} P"
    if not low[i] > 0:
        raise WireError("not_pd", f"{name}: not positive definite")
    raise WireError("range", f"{name}: eigenvalues {low[i]:.3g} to {high[i]:.3g} outside what a track can "
                             f"hold (at most {MAX_TRACK_VARIANCE:g}, condition at most {1 / MIN_EIGEN_RATIO:g})")


@wire_kind("tracks")
@dataclass(frozen=True, eq=False)
class TrackList:
    """Node ``sender``'s tracks at step k (at most MAX_TRACKS, ids unique), published at ``t_pub``; what it says
    about the step: ``t_meas_pub`` (the measurement's publication, None when it coasted), ``t_recv``,
    ``update_us`` (the local tracker's step), ``fused`` (the neighbours' lists its last fusion took),
    ``coasted``, ``miss`` (the list is past the step's deadline); ``counters`` every few steps."""

    k: int
    t: float
    sender: int
    tracks: tuple[TrackEntry, ...]
    t_pub: float
    t_meas_pub: float | None = None
    t_recv: float | None = None
    update_us: float | None = None
    fused: int = 0
    coasted: bool = False
    miss: bool = False
    counters: dict[str, Any] | None = None

    @classmethod
    def of(cls, k: int, t: float, sender: int, estimates: Sequence[TrackEstimate], t_pub: float,
           **about: Any) -> Self:
        """The list of ``estimates`` (the tracker's, at step ``k``) and what it says about the step (``about``:
        the optional fields)."""
        return cls(k, t, sender, tuple(TrackEntry(e.id, e.status, e.mean, e.cov, e.misses, e.existence)
                                       for e in estimates), t_pub, **about)

    def estimates(self) -> list[TrackEstimate]:
        """The tracks as :class:`~zentrack.fusion.track_to_track.TrackEstimate` at step k (decoding checked them:
        finite, symmetric, positive definite)."""
        return [TrackEstimate.checked_before(e.id, e.mean, e.cov, e.status, self.k, e.misses, e.existence)
                for e in self.tracks]

    def encode(self) -> bytes:
        """The message; ValueError for a list its receivers would refuse for its count, ids or size."""
        if len(self.tracks) > MAX_TRACKS:
            raise ValueError(f"{len(self.tracks)} tracks > MAX_TRACKS = {MAX_TRACKS}")
        if len({e.id for e in self.tracks}) != len(self.tracks):
            raise ValueError("duplicate track ids in the list")
        about: dict[str, Any] = {"t_meas_pub": self.t_meas_pub, "t_recv": self.t_recv, "update_us": self.update_us,
                 "fused": self.fused, "coasted": self.coasted, "miss": self.miss}
        if self.counters is not None:
            about["counters"] = self.counters
        payload = encode("tracks", self.k, self.t, self.sender, tracks=[e.packed() for e in self.tracks],
                         t_pub=self.t_pub, **about)
        if len(payload) > MAX_MESSAGE_BYTES:
            raise ValueError(f"a list of {len(self.tracks)} tracks is {len(payload)} bytes > {MAX_MESSAGE_BYTES}")
        return payload

    @classmethod
    def decode(cls, payload: bytes, key_node: int, n: int, lo: int | None = None, hi: int | None = None) -> Self:
        """A list on ``tracks/<key_node>`` of tracks with ``n``-dimensional states, step in ``lo..hi``."""
        msg = node_message(payload, ("tracks",), key_node, lo, hi)
        raw = field(msg, "tracks", list)
        if len(raw) > MAX_TRACKS:
            raise WireError("schema", f"tracks: {len(raw)} tracks > {MAX_TRACKS}")
        tracks = _entries(raw, n, msg["k"])
        if len({e.id for e in tracks}) != len(tracks):
            raise WireError("schema", "tracks: a track id twice in the list")
        _check_covariances(tracks)
        counters = msg.get("counters")
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "sender": key_node, "tracks": tracks,
                           "t_pub": number(msg, "t_pub"), "t_meas_pub": optional_number(msg, "t_meas_pub"),
                           "t_recv": optional_number(msg, "t_recv"), "update_us": optional_number(msg, "update_us"),
                           "fused": _count(msg.get("fused", 0), "fused"), "coasted": flag(msg, "coasted"),
                           "miss": flag(msg, "miss"),
                           "counters": None if counters is None else check_counters(counters)})


@wire_kind("targets")
@dataclass(frozen=True, eq=False)
class TargetSet:
    """The targets present at step k: their ids ``(N,)`` (the scenario's target index, unique) and true states
    ``(N, 6)``, published by the truth at ``t_pub`` (for evaluators: the recorder, the viewer)."""

    k: int
    t: float
    ids: np.ndarray
    states: np.ndarray
    t_pub: float

    def encode(self) -> bytes:
        return encode("targets", self.k, self.t, "truth", ids=[int(i) for i in self.ids],
                      x=pack_array(np.asarray(self.states, dtype=float).reshape(-1, 6)), t_pub=self.t_pub)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        msg = truth_message(payload, "targets")
        ids = msg.get("ids")
        if type(ids) is not list or len(ids) > MAX_TARGETS_ON_WIRE:
            raise WireError("schema", f"targets: ids must be a list of at most {MAX_TARGETS_ON_WIRE}")
        ids = [_count(i, "target id") for i in ids]
        if len(set(ids)) != len(ids):
            raise WireError("schema", "targets: a target id twice")
        states = optional_rows(msg.get("x"), 6, MAX_TARGETS_ON_WIRE, "targets x")
        if states is None or states.shape[0] != len(ids):
            raise WireError("shape", f"targets: {len(ids)} ids but {None if states is None else states.shape[0]} states")
        return built(cls, {"k": msg["k"], "t": float(msg["t"]), "ids": np.array(ids, dtype=np.int64),
                           "states": states, "t_pub": number(msg, "t_pub")})
