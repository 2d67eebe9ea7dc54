"""Multi-target metrics of a run: GOSPA with its localisation, missed and false parts, OSPA for sets of any sizes,
and identity switches and fragmentation of the truths' tracks over a run.

Every metric compares an estimated set ``X`` (``(n, d)``: track positions, or any state vectors with a Euclidean
distance) with a truth set ``Y`` (``(m, d)``); either may be empty. Both set metrics solve the same optimal assignment:
:func:`scipy.optimize.linear_sum_assignment` on the cut-off costs ``min(|x_i - y_j|, c)^p``. A rectangular assignment
matches ``min(n, m)`` pairs, which is the minimum over the permutations of both definitions; a matched pair at distance
``>= c`` costs ``c^p``, i.e. exactly one missed plus one false target in GOSPA, and is reported as that.

* GOSPA: Rahmathullah, García-Fernández, Svensson, "Generalized optimal sub-pattern assignment metric", FUSION 2017
  (arXiv:1601.05585). Definition 1, for ``|X| <= |Y|`` and ``0 < alpha <= 2``:
  ``d = ( min_{pi in Pi_|Y|} sum_{i=1}^{|X|} min(d(x_i, y_pi(i)), c)^p + c^p / alpha (|Y| - |X|) )^(1/p)``;
  Proposition 1, for ``alpha = 2``: ``d = ( min_gamma sum_{(i,j) in gamma} d(x_i, y_j)^p + c^p/2 (|X| + |Y| - 2|gamma|)
  )^(1/p)`` over assignment sets ``gamma``, i.e. localisation (assigned pairs) + missed (``c^p/2`` per unassigned
  truth) + false (``c^p/2`` per unassigned estimate). Stone Soup's ``GOSPAMetric`` (alpha 2) reports the same parts.
* OSPA: Schuhmacher, Vo, Vo, "A consistent metric for performance evaluation of multi-object filters", IEEE Trans.
  Signal Processing 56(8), 2008, Sec. III: for ``m <= n``,
  ``d = ( (1/n) ( min_{pi in Pi_n} sum_{i=1}^{m} min(d(x_i, y_pi(i)), c)^p + c^p (n - m) ) )^(1/p)``, with the
  localisation part ``((1/n) min_pi sum min(d, c)^p)^(1/p)`` and the cardinality part ``(c^p (n - m) / n)^(1/p)``
  (so ``d^p = loc^p + card^p``); ``d(empty, empty) = 0``. Stone Soup's ``OSPAMetric`` picks its assignment on the
  unpowered distances, which is not the definition's for ``p != 1`` (tests/test_multitarget_metrics.py shows a case).
* Identity switches and fragmentation: :func:`identity_switches_and_fragmentations`.
* False lives: :func:`longest_false_life`, the most consecutive steps one track id was false (a ghost's life).
"""
from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

Array = np.ndarray
#: the cut-off (m) the live runs, the viewer and the bench score GOSPA with: a track farther than this from every
#: target is false (ten times the 5 m sensor noise of the built-in many-target scenarios)
GOSPA_CUTOFF = 50.0
#: one step's labelled set: ``{id: position}``, or ``(ids, positions (n, d))``
LabelledSet = Mapping[Hashable, Any] | tuple[Sequence[Hashable], Any]


def _check_parameters(cutoff: float, order: float, alpha: float = 2.0) -> None:
    if not (np.isfinite(cutoff) and cutoff > 0):
        raise ValueError(f"cutoff c must be finite and > 0, got {cutoff!r}")
    if not (np.isfinite(order) and order >= 1):
        raise ValueError(f"order p must be finite and >= 1, got {order!r}")
    if not (0 < alpha <= 2):
        raise ValueError(f"GOSPA alpha must lie in (0, 2], got {alpha!r}")


def _point_sets(x: Any, y: Any, finite: bool = True) -> tuple[Array, Array]:
    """``x (..., n, d)`` and ``y (..., m, d)`` as float arrays of one dimension ``d``; an empty set may be ``[]``.
    ``finite``: refuse non-finite coordinates."""
    out = []
    for name, s in (("estimates", x), ("truths", y)):
        a = np.asarray(s, dtype=float)
        if a.size == 0 and a.ndim < 2:
            a = a.reshape(0, 0)
        if a.ndim < 2:
            raise ValueError(f"{name} must be a set of points (n, d), got shape {a.shape}")
        if finite and not np.all(np.isfinite(a)):
            raise ValueError(f"{name} hold non-finite values")
        out.append(a)
    a, b = out
    if a.shape[-2] and b.shape[-2] and a.shape[-1] != b.shape[-1]:
        raise ValueError(f"estimates are {a.shape[-1]}-D points but truths {b.shape[-1]}-D")
    return a, b


def cutoff_distances(x: Array, y: Array, cutoff: float) -> Array:
    """``min(|x_i - y_j|, c)``, ``(..., n, m)``, for ``x (..., n, d)`` and ``y (..., m, d)``."""
    if x.shape[-2] == 0 or y.shape[-2] == 0:
        return np.zeros(np.broadcast_shapes(x.shape[:-2], y.shape[:-2]) + (x.shape[-2], y.shape[-2]))
    return np.minimum(np.linalg.norm(x[..., :, None, :] - y[..., None, :, :], axis=-1), cutoff)


def _optimal_pairs(cost: Array) -> tuple[Array, Array]:
    """Rows and columns of the minimum-cost assignment of ``min(n, m)`` pairs of ``cost (n, m)``."""
    if cost.size == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    return linear_sum_assignment(cost)


@dataclass(frozen=True)
class Gospa:
    """GOSPA between an estimated and a truth set, with its parts: ``total**order == localisation + missed + false``."""

    total: float  #: d_p^(c, alpha)(X, Y), in distance units
    localisation: float  #: sum of d^p over the assigned pairs (closer than c)
    missed: float  #: c^p / alpha per unassigned truth, c^p / 2 per pair at distance >= c
    false: float  #: c^p / alpha per unassigned estimate, c^p / 2 per pair at distance >= c
    n_assigned: int
    n_missed: int
    n_false: int
    #: ``(n_assigned, 2)`` ints: (estimate index, truth index) of each assigned pair (distance < c)
    pairs: Array


def gospa(estimates: Any, truths: Any, cutoff: float, order: float = 2.0, alpha: float = 2.0) -> Gospa:
    """GOSPA (Rahmathullah et al. 2017, Definition 1; its parts by Proposition 1) between ``estimates (n, d)`` and
    ``truths (m, d)``, any sizes (0 included).

    For ``alpha = 2`` (the default, the one that splits into parts) the parts are Proposition 1's: localisation,
    ``c^p/2`` per missed truth and per false estimate. For ``alpha < 2`` the total is Definition 1's; an unassigned
    point then costs ``c^p/alpha`` and a pair at distance ``>= c`` ``c^p`` (booked as half missed, half false).
    """
    _check_parameters(cutoff, order, alpha)
    x, y = _point_sets(estimates, truths)
    if x.ndim != 2 or y.ndim != 2:
        raise ValueError(f"gospa compares two sets (n, d) and (m, d), got shapes {x.shape} and {y.shape}")
    dist = cutoff_distances(x, y, cutoff)
    rows, cols = _optimal_pairs(dist**order)
    near = dist[rows, cols] < cutoff
    n_cut = int(np.count_nonzero(~near))
    n_assigned = len(rows) - n_cut
    localisation = float(np.sum(dist[rows[near], cols[near]] ** order))
    half, unassigned = cutoff**order / 2.0, cutoff**order / alpha
    missed = half * n_cut + unassigned * (len(y) - len(rows))
    false = half * n_cut + unassigned * (len(x) - len(rows))
    return Gospa(total=float((localisation + missed + false) ** (1.0 / order)), localisation=localisation,
                 missed=float(missed), false=float(false), n_assigned=n_assigned, n_missed=len(y) - n_assigned,
                 n_false=len(x) - n_assigned, pairs=np.column_stack([rows[near], cols[near]]).astype(int))


@dataclass(frozen=True)
class Ospa:
    """OSPA and its parts, each of the call's batch shape: ``total**order == localisation**order + cardinality**order``."""

    total: Array
    localisation: Array
    cardinality: Array


def ospa(x: Any, y: Any, cutoff: float, order: float = 2.0) -> Ospa:
    """OSPA (Schuhmacher, Vo, Vo 2008, Sec. III) between ``x (..., n, d)`` and ``y (..., m, d)``, any ``n``, ``m``.

    Batched over the leading axes (broadcast against each other; one assignment per set pair): ``(..., )``
    results, numpy scalars for a single pair. Each part lies in ``[0, c]``. A set pair with a non-finite coordinate scores
    NaN (as numpy's reductions do), so a diverged Monte Carlo run shows in the figures instead of stopping them.
    """
    _check_parameters(cutoff, order)
    x, y = _point_sets(x, y, finite=False)
    lead = np.broadcast_shapes(x.shape[:-2], y.shape[:-2])
    n, m = x.shape[-2], y.shape[-2]
    big = max(n, m)
    if big == 0:
        zero = np.zeros(lead)[()]
        return Ospa(total=zero, localisation=zero, cardinality=zero)
    finite = np.broadcast_to(np.isfinite(x).all(axis=(-2, -1)) & np.isfinite(y).all(axis=(-2, -1)), lead).ravel()
    with np.errstate(invalid="ignore"):
        cost = (cutoff_distances(x, y, cutoff) ** order).reshape((int(np.prod(lead)), n, m))
    assigned = np.full(len(cost), np.nan)
    for k in np.flatnonzero(finite):
        rows, cols = _optimal_pairs(cost[k])
        assigned[k] = cost[k][rows, cols].sum()
    loc_p = assigned.reshape(lead) / big
    card_p = np.where(finite.reshape(lead), cutoff**order * abs(n - m) / big, np.nan)
    inv = 1.0 / order
    return Ospa(total=((loc_p + card_p) ** inv)[()], localisation=(loc_p**inv)[()], cardinality=(card_p**inv)[()])


# --------------------------------------------------------------------------------------------------- over a run


def _labelled(step: Any, name: str) -> tuple[list[Hashable], Array]:
    """``(ids, positions (n, d))`` of one step's ``{id: position}`` or ``(ids, positions)``."""
    if isinstance(step, Mapping):
        ids, pos = list(step.keys()), [np.ravel(np.asarray(v, dtype=float)) for v in step.values()]
        positions = np.array(pos) if pos else np.zeros((0, 0))
    elif isinstance(step, tuple) and len(step) == 2:
        ids, positions = list(step[0]), np.asarray(step[1], dtype=float)
        if positions.size == 0:
            positions = positions.reshape(0, 0)
    else:
        raise ValueError(f"{name}: a step is {{id: position}} or (ids, positions), got {type(step).__name__}")
    if positions.ndim != 2 or len(positions) != len(ids):
        raise ValueError(f"{name}: {len(ids)} ids but positions of shape {positions.shape}")
    if len(set(ids)) != len(ids):
        raise ValueError(f"{name}: duplicate ids in one step")
    return ids, positions


@dataclass(frozen=True)
class IdentityErrors:
    """Identity switches and fragmentations of a run, in total and per step (counted at the step they happen)."""

    switches: int
    fragmentations: int
    switches_per_step: Array  #: (K,) ints
    fragmentations_per_step: Array  #: (K,) ints


def _count_identity_errors(assignments: Sequence[tuple[list[Hashable], dict[Hashable, Hashable]]]) -> IdentityErrors:
    """Counts from per step (present truth ids, {truth id: assigned track id})."""
    last_track: dict[Hashable, Hashable] = {}  # truth -> its last assigned track
    tracked_at_last_presence: dict[Hashable, bool] = {}
    switches = np.zeros(len(assignments), dtype=int)
    fragments = np.zeros(len(assignments), dtype=int)
    for k, (present, assigned) in enumerate(assignments):
        for truth in present:
            tracked = truth in assigned
            if tracked:
                if truth in last_track and last_track[truth] != assigned[truth]:
                    switches[k] += 1
                if truth in last_track and not tracked_at_last_presence[truth]:
                    fragments[k] += 1
                last_track[truth] = assigned[truth]
            tracked_at_last_presence[truth] = tracked
    return IdentityErrors(switches=int(switches.sum()), fragmentations=int(fragments.sum()),
                          switches_per_step=switches, fragmentations_per_step=fragments)


def _longest_false_run(false_ids: Sequence[set[Hashable]]) -> int:
    """The most consecutive steps one id is in the per-step sets of false track ids."""
    running: dict[Hashable, int] = {}
    longest = 0
    for ids in false_ids:
        running = {i: running.get(i, 0) + 1 for i in ids}
        longest = max([longest, *running.values()])
    return longest


def _run(track_steps: Sequence[LabelledSet], truth_steps: Sequence[LabelledSet], cutoff: float, order: float,
         alpha: float) -> tuple[list[Gospa], IdentityErrors, int]:
    if len(track_steps) != len(truth_steps):
        raise ValueError(f"{len(track_steps)} track steps but {len(truth_steps)} truth steps")
    per_step, assignments, false_ids = [], [], []
    for tracks, truths in zip(track_steps, truth_steps):
        track_ids, x = _labelled(tracks, "tracks")
        truth_ids, y = _labelled(truths, "truths")
        g = gospa(x, y, cutoff, order, alpha)
        per_step.append(g)
        assignments.append((truth_ids, {truth_ids[j]: track_ids[i] for i, j in g.pairs}))
        false_ids.append(set(track_ids) - {track_ids[i] for i in g.pairs[:, 0]})
    return per_step, _count_identity_errors(assignments), _longest_false_run(false_ids)


def longest_false_life(track_steps: Sequence[LabelledSet], truth_steps: Sequence[LabelledSet], cutoff: float,
                       order: float = 2.0) -> int:
    """The most consecutive steps one track id was **false** (left unassigned by GOSPA's assignment of its step,
    :func:`gospa`: no target within the cut-off ``c`` that another track did not take): the life of the longest
    ghost. A track that comes within ``c`` of a free target for a step ends its run; steps as for
    :func:`identity_switches_and_fragmentations`."""
    _check_parameters(cutoff, order)
    return _run(track_steps, truth_steps, cutoff, order, 2.0)[2]


def identity_switches_and_fragmentations(track_steps: Sequence[LabelledSet], truth_steps: Sequence[LabelledSet],
                                         cutoff: float, order: float = 2.0) -> IdentityErrors:
    """Identity switches and fragmentations of the truths' tracks over a run of steps.

    Each step gives the tracks and the truths as ``{id: position}`` or ``(ids, positions (n, d))``. Per step the
    truths are assigned to tracks by GOSPA's assignment (:func:`gospa`); a truth counts as *tracked* by a track when
    they are an assigned pair (closer than the cut-off ``c``). Over the steps in which a truth is present (steps
    without it are skipped, whatever happens in them):

    * an **identity switch** is counted at step k when the truth is tracked at k by a track whose id differs from
      the track that tracked it the last time it was tracked (however long ago: a gap does not reset it). This is
      CLEAR MOT's mismatch against the last known correspondence (Bernardin, Stiefelhagen, EURASIP J. Image and
      Video Processing 2008, Sec. 2.1.2), with GOSPA's optimal assignment in place of CLEAR MOT's matching that
      keeps previous correspondences first; a switch to or from "untracked" is not a switch. (Stone Soup's GOSPA
      switching term instead charges half a switch for a change to or from unassigned.)
    * a **fragmentation** is counted at step k when the truth is tracked at k, was untracked at its previous present
      step, and was tracked at some earlier step: the number of times its track coverage is interrupted and resumed
      (the "Frag" of Li, Huang, Nevatia, CVPR 2009), i.e. per truth its number of tracked stretches minus one. A
      coverage that ends untracked counts nothing. Resuming under another track id counts one of each.
    """
    _check_parameters(cutoff, order)
    return _run(track_steps, truth_steps, cutoff, order, 2.0)[1]


@dataclass(frozen=True)
class RunSummary:
    """Means over the steps of a run: GOSPA and its parts, the counts, and the run's identity errors."""

    steps: int
    gospa: float  #: mean total
    rms_gospa: float  #: sqrt(mean total^2), the paper's root mean squared GOSPA
    localisation: float
    missed: float
    false: float
    n_missed: float
    n_false: float
    identity: IdentityErrors
    per_step: list[Gospa]
    longest_false: int = 0  #: :func:`longest_false_life`: the most consecutive steps one track was false


def summarize_run(track_steps: Sequence[LabelledSet], truth_steps: Sequence[LabelledSet], cutoff: float,
                  order: float = 2.0, alpha: float = 2.0) -> RunSummary:
    """GOSPA per step (:func:`gospa`) and its means over the run, with the identity switches and fragmentations
    (:func:`identity_switches_and_fragmentations`) from the same assignments. Steps as for the latter."""
    _check_parameters(cutoff, order, alpha)
    if not track_steps:
        raise ValueError("summarize_run needs at least one step")
    per_step, identity, longest_false = _run(track_steps, truth_steps, cutoff, order, alpha)
    field = {name: np.array([getattr(g, name) for g in per_step], dtype=float)
             for name in ("total", "localisation", "missed", "false", "n_missed", "n_false")}
    return RunSummary(steps=len(per_step), gospa=float(field["total"].mean()),
                      rms_gospa=float(np.sqrt(np.mean(field["total"] ** 2))),
                      localisation=float(field["localisation"].mean()), missed=float(field["missed"].mean()),
                      false=float(field["false"].mean()), n_missed=float(field["n_missed"].mean()),
                      n_false=float(field["n_false"].mean()), identity=identity, per_step=per_step,
                      longest_false=longest_false)
