"""The phases of a tracker's step and the transitions between them, as explicit tables: :class:`Phase` for the
single-target payload (``node/diffusion/``), :class:`TrackListPhase` for the many-target one (``node/track_lists/``).

A step k goes ``AWAIT_MEAS`` (its own measurement, or the coast deadline) → [``AWAIT_SCANS``: the neighbours'
forwarded scans, rules that exchange scans] → local update, estimate published → [``AWAIT_RELAYS``: the
neighbours' relays of two-hop scans, rules with ``relay_scans``] → ``FUSING`` (the rounds for step k + 1) →
``AWAIT_MEAS`` (step k + 1). A node without a usable prior (a restart, a long gap) is ``WARMING`` until it
takes its neighbours' pairs, its own prediction or the cold prior; ``IDLE`` is before the run's start.
:data:`TRANSITIONS` lists every move the schedule may make; :func:`check_transition` refuses any other, so a
wrong move is a bug caught where it happens, never a silent stall.
"""
from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import TypeVar


class Phase(StrEnum):
    """Where a tracker is in its step (the values are the names logged and compared in tests)."""

    IDLE = "idle"  #: before ``ctl/start``
    AWAIT_MEAS = "await_meas"  #: waiting for step k's measurement, or the deadline to coast
    AWAIT_SCANS = "await_scans"  #: own scan forwarded; waiting for the neighbours' scans of step k
    AWAIT_RELAYS = "await_relays"  #: estimate out, scans relayed; waiting for the neighbours' relays of step k
    FUSING = "fusing"  #: fusing the neighbours' round messages for step k + 1
    WARMING = "warming"  #: no usable prior: rejoining from the neighbours' pairs


#: phase -> the phases it may move to (staying is always allowed)
TRANSITIONS: dict[Phase, frozenset[Phase]] = {
    Phase.IDLE: frozenset({Phase.AWAIT_MEAS, Phase.WARMING}),  # a fresh start, or a late join
    Phase.AWAIT_MEAS: frozenset({
        Phase.AWAIT_SCANS,  # own scan forwarded
        Phase.AWAIT_RELAYS,  # updated and relayed (a rule that relays without forwarding first)
        Phase.FUSING,  # updated, round 1 out (or held until the deadline)
        Phase.WARMING,  # fell behind past the coast limit, or a measurement after a long gap
    }),
    Phase.AWAIT_SCANS: frozenset({Phase.AWAIT_RELAYS, Phase.FUSING}),
    Phase.AWAIT_RELAYS: frozenset({Phase.FUSING}),
    Phase.FUSING: frozenset({Phase.AWAIT_MEAS}),  # the prior for k + 1 is ready
    Phase.WARMING: frozenset({Phase.AWAIT_MEAS}),  # a warm, resumed or cold start
}


class TransitionError(RuntimeError):
    """A move the table does not allow: a bug in the schedule, not bad input."""


class TrackListPhase(StrEnum):
    """Where a many-target tracker is in its step: its scan, [the neighbours' scans,] the neighbours' lists."""

    IDLE = "idle"  #: before ``ctl/start``
    AWAIT_MEAS = "await_meas"  #: waiting for step k's scan, or the deadline to coast
    AWAIT_SCANS = "await_scans"  #: (bearing sensors) own scan sent; waiting for the neighbours' scans of step k
    AWAIT_LISTS = "await_lists"  #: list of step k out; waiting for the neighbours' lists of step k


#: phase -> the phases a many-target tracker may move to
TRACK_LIST_TRANSITIONS: dict[TrackListPhase, frozenset[TrackListPhase]] = {
    TrackListPhase.IDLE: frozenset({TrackListPhase.AWAIT_MEAS}),
    TrackListPhase.AWAIT_MEAS: frozenset({TrackListPhase.AWAIT_LISTS, TrackListPhase.AWAIT_SCANS}),
    TrackListPhase.AWAIT_SCANS: frozenset({TrackListPhase.AWAIT_LISTS}),
    TrackListPhase.AWAIT_LISTS: frozenset({TrackListPhase.AWAIT_MEAS}),
}


P = TypeVar("P", Phase, TrackListPhase)


def checked_move(table: Mapping[P, frozenset[P]], current: P, target: P) -> P:
    """``target`` if ``table`` allows ``current`` → ``target`` (or it is the same phase); else TransitionError."""
    if target is not current and target not in table[current]:
        raise TransitionError(f"no transition from {current.value} to {target.value}")
    return target


def check_transition(current: Phase, target: Phase) -> Phase:
    """A single-target tracker's move, checked against :data:`TRANSITIONS`."""
    return checked_move(TRANSITIONS, current, target)
