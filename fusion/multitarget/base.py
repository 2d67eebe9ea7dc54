"""The pieces of a multi-target tracker and the base of each component family (after Stone Soup's families).

- :class:`Track`: one target hypothesis: its id, :class:`TrackStatus`, the per-track filter's estimate (full
  filter state, mean ``(n,)`` and covariance ``(n, n)`` at step :attr:`Track.step`), its birth step and the
  hit/miss history the life cycle reads.
- :class:`TrackStatus` moves only along :data:`TRANSITIONS` (tentative -> confirmed -> deleted, tentative ->
  deleted); :meth:`Track.move_to` refuses any other move.
- :class:`Association`: what an :class:`Associator` makes of one scan: the probability ``beta[t, j]`` that
  return ``j`` is track ``t``'s and ``beta0[t]`` that track ``t`` was not detected (rows sum to one). A hard
  assignment (GNN) is the 0/1 case, so one update serves both (:mod:`~zentrack.fusion.multitarget.combine`).
- :class:`Initiator` (births from returns no track gated, and from priors given to :meth:`Initiator.from_prior`),
  :class:`Confirmer` (tentative -> confirmed) and :class:`Deleter` (-> deleted).

:data:`ASSOCIATOR_REGISTRY` finds associators by name (``gnn``, ``jpda``) like the filters and fusion rules.
"""
from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from ..linalg import is_spd
from ..registry import Registry
from ..scan import Scan

Array = np.ndarray


class TrackStatus(enum.Enum):
    """Where a track is in its life cycle."""

    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"
    DELETED = "deleted"

    def can_become(self, other: TrackStatus) -> bool:
        """Whether :data:`TRANSITIONS` allows the move ``self -> other`` (staying is always allowed)."""
        return other is self or other in TRANSITIONS[self]


#: the allowed status changes; a deleted track never comes back (a target seen again is a new track)
TRANSITIONS: dict[TrackStatus, frozenset[TrackStatus]] = {
    TrackStatus.TENTATIVE: frozenset({TrackStatus.CONFIRMED, TrackStatus.DELETED}),
    TrackStatus.CONFIRMED: frozenset({TrackStatus.DELETED}),
    TrackStatus.DELETED: frozenset(),
}


@dataclass
class Track:
    """One track: ``mean`` ``(n,)`` and ``cov`` ``(n, n)`` of the per-track filter's state at step ``step``.

    ``hits`` has one entry per step since birth (the birth step is a hit: a track is born of a return or a
    prior); ``misses`` counts the consecutive misses up to now.
    """

    id: int
    mean: Array
    cov: Array
    birth_step: int
    step: int
    status: TrackStatus = TrackStatus.TENTATIVE
    hits: list[bool] = field(default_factory=lambda: [True])
    misses: int = 0
    #: how many neighbours' tracks the last exchange fused into it (a node of a network; 0 alone)
    support: int = 0
    #: the probability its target exists (a PMBM node's Bernoulli, fused by the exchange; 1 for M of N)
    existence: float = 1.0
    #: sensor index -> the last step a return of its scan was this track's (what a deleter may ask of the sensors)
    detected_by: dict[int, int] = field(default_factory=dict)
    #: the same, counting only the returns that no other track gated
    detected_alone_by: dict[int, int] = field(default_factory=dict)

    def record(self, hit: bool) -> None:
        """Add this step's outcome (detected or not) to the history."""
        self.hits.append(bool(hit))
        self.misses = 0 if hit else self.misses + 1

    def move_to(self, status: TrackStatus) -> None:
        """Change the status; ValueError if :data:`TRANSITIONS` does not allow it."""
        if not self.status.can_become(status):
            raise ValueError(f"track {self.id}: status {self.status.value} cannot become {status.value}")
        self.status = status

    @property
    def alive(self) -> bool:
        return self.status is not TrackStatus.DELETED


@dataclass(frozen=True)
class Birth:
    """A track to start: the kinematic ``mean`` ``(k,)`` and ``cov`` ``(k, k)`` (the per-track filter adds
    its augmented blocks), the status it starts in and the probability its target exists (a prior's)."""

    mean: Array
    cov: Array
    status: TrackStatus = TrackStatus.TENTATIVE
    existence: float = 1.0


@dataclass(frozen=True)
class ScanLikelihood:
    """Tracks x returns of one scan (:func:`~zentrack.fusion.multitarget.gating.scan_likelihood`):
    ``log_lik[t, j] = log N(nu_tj; 0, S_t)``, ``distance2`` the squared Mahalanobis distance
    ``nu_tj^T S_t^-1 nu_tj``, ``gated`` ``distance2 <= gamma`` (all ``(T, J)``), ``gamma`` the gate."""

    log_lik: Array
    distance2: Array
    gated: Array
    gamma: float


@dataclass(frozen=True)
class Association:
    """Association of one scan: ``beta`` ``(T, J)``, ``beta0`` ``(T,)`` (each row of ``[beta0, beta]`` sums
    to one), the gate mask ``gated`` ``(T, J)``."""

    beta: Array
    beta0: Array
    gated: Array

    def detected(self) -> Array:
        """``(T,)``: the track was more likely detected than missed (``1 - beta0 > 1/2``); the hit the life
        cycle counts."""
        return np.asarray(self.beta0 < 0.5)

    def detected_alone(self) -> Array:
        """``(T,)``: detected (:meth:`detected`) by its most likely return, and that return inside no other track's
        gate (a return no other track could explain)."""
        detected = self.detected()
        if self.beta.shape[1] == 0:
            return detected
        best = self.beta.argmax(axis=1)
        return np.asarray(detected & (self.gated.sum(axis=0)[best] <= 1))

    def unassociated(self) -> Array:
        """``(J,)`` mask of the returns inside no track's gate: what the initiator may start tracks from."""
        return np.asarray(~self.gated.any(axis=0))


class Associator(ABC):
    """Tracks x returns of one scan -> :class:`Association`.

    ``gate_prob`` is P_G, the probability that a track's own return falls inside its validation gate
    ``d^2 <= chi2_m(P_G)`` (:func:`~zentrack.fusion.gate.gate_threshold`).
    """

    name: str = "associator"
    gate_prob: float = 0.999

    @abstractmethod
    def associate(self, likelihood: ScanLikelihood) -> Association:
        """The association of one scan from its gated likelihoods."""


def check_gaussian(mean: Array, cov: Array, what: str) -> tuple[Array, Array]:
    """``mean`` ``(k,)`` and ``cov`` ``(k, k)`` as float arrays; ValueError naming ``what`` if a shape, a
    value or the covariance's positive definiteness is wrong."""
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if mean.ndim != 1 or cov.shape != (mean.size, mean.size):
        raise ValueError(f"{what}: expected mean (k,) and cov (k, k), got {mean.shape} and {cov.shape}")
    if not np.all(np.isfinite(mean)):
        raise ValueError(f"{what}: mean contains NaN or Inf")
    if not bool(is_spd(cov)):
        raise ValueError(f"{what}: cov is not finite, symmetric and positive definite")
    return mean, cov


class Initiator(ABC):
    """Starts tracks: from returns no track gated (:meth:`births_from_returns`) and from priors handed over
    by others (:meth:`from_prior`: a neighbour's track of a target entering this sensor's view; the only way a
    bearing-only sensor starts one)."""

    def __init__(self) -> None:
        self._priors: list[Birth] = []

    def from_prior(self, mean: Array, cov: Array, status: TrackStatus = TrackStatus.TENTATIVE,
                   existence: float = 1.0) -> Birth:
        """Queue a track from the kinematic prior ``(mean, cov)`` (its target's ``existence``), taken as the
        estimate at the step of the tracker's next
        :meth:`~zentrack.fusion.multitarget.tracker.MultiTargetTracker.step` (ValueError if it is malformed).
        Returns the queued birth."""
        if status is TrackStatus.DELETED:
            raise ValueError("from_prior: a track cannot be born deleted")
        if not 0.0 < existence <= 1.0:
            raise ValueError(f"from_prior: existence {existence!r} is not a probability in (0, 1]")
        mean, cov = check_gaussian(mean, cov, "from_prior")
        birth = Birth(mean, cov, status, float(existence))
        self._priors.append(birth)
        return birth

    def births(self, returns: Array, scan: Scan, step: int) -> list[Birth]:
        """Every track to start at ``step``: the queued priors, then those :meth:`births_from_returns` makes
        of the unassociated ``returns`` ``(J', m)`` of ``scan``."""
        out, self._priors = self._priors, []
        return out + self.births_from_returns(returns, scan, step)

    def births_at(self, returns: Array, scan: Scan, step: int, t: float) -> list[Birth]:
        """Sensors of their own: the tracks to start from the unassociated ``returns`` of ``scan``, measured at
        time ``t`` (s) within ``step``'s window (the queued priors are taken at the window's start). By default
        :meth:`births_from_returns`; an initiator that pairs scans over time pairs them by their times."""
        return self.births_from_returns(returns, scan, step)

    def take_priors(self) -> list[Birth]:
        """The queued priors (emptying the queue): for a step without a scan."""
        out, self._priors = self._priors, []
        return out

    @abstractmethod
    def births_from_returns(self, returns: Array, scan: Scan, step: int) -> list[Birth]:
        """Tracks to start from unassociated returns ``(J', m)`` of ``scan`` at ``step``."""


class Confirmer(ABC):
    """Decides when a tentative track becomes confirmed, or is given up."""

    @abstractmethod
    def decide(self, track: Track) -> TrackStatus:
        """The status a tentative track should have after this step's :meth:`Track.record`."""


class Deleter(ABC):
    """Decides when a track is deleted."""

    @abstractmethod
    def should_delete(self, track: Track) -> bool:
        """Whether ``track`` (after this step's update and :meth:`Track.record`) is to be deleted."""


#: associators by name; a factory is ``factory(**params) -> Associator``
ASSOCIATOR_REGISTRY: Registry[Associator] = Registry("associator", discover=__package__)
