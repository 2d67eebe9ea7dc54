"""Track-to-track fusion between nodes: association of track lists, fusion of what they share, one identity
per target across the network, and takeover of the tracks a node does not hold.

Each node publishes its confirmed tracks; a receiver holds its own list and one list per neighbour, all at
the same step (it predicts them there first).

**Distance.** Two nodes' estimates of one target are correlated by an unknown amount (common process noise,
earlier fusion), so the covariance of their difference ``d = x_a - x_b`` is not ``P_a + P_b`` (Bar-Shalom &
Campo 1986 need the cross-covariance, which no node has). What holds for *any* correlation is the
covariance-intersection bound ``Cov(d) <= P_a / omega + P_b / (1 - omega)`` (derived in
:mod:`~zentrack.fusion.gate`'s docstring), so the distance is the Mahalanobis distance with the sum
covariance replaced by that bound at the smallest-volume ``omega``,
:func:`~zentrack.fusion.gate.ci_gate_statistic`. For the same target it is stochastically below a chi-square
with ``n`` degrees of freedom whatever the correlation, which is why it is consistent with unknown
correlation: the gate (:func:`~zentrack.fusion.gate.ci_gate_passes` at
:func:`~zentrack.fusion.gate.gate_threshold`) refuses a true pair with probability at most its
false-rejection probability, and a true pair does not look farther than it is because its errors happen to
be correlated.

**Association** (:func:`associate_tracks`) is a constrained 2-D assignment (Bar-Shalom, Willett & Tian,
"Tracking and Data Fusion", 2011, track-to-track association as an assignment problem): only gated pairs are
admissible, and among the assignments it takes the most pairs, then the smallest sum of distances
(``scipy.optimize.linear_sum_assignment`` with a cost above any sum of admissible ones on the other pairs).

**Fusion** (:func:`fuse_tracks`) goes through a registered fusion rule (:func:`~zentrack.fusion.rules.make_rule`;
``ci-fast``, CI with the fast-CI weights, by default), any number of estimates at once.

**Identity.** A track id is :class:`TrackId` ``(born, node, serial)``: the step its track started, the node that
started it and that node's counter. Ids order oldest first (then by node, then by serial), and when associated
tracks carry different ids every node takes the smallest: after one exchange in which each node sees every
holder's list, all holders of a target carry one id. A track a node takes over keeps its id, so identity
survives handovers; it survives a node's dropout because every other holder keeps the id, and a restart
because the restarted node takes its tracks back, ids included, from its neighbours' lists. ``born`` keeps
ids unique after a restart whose counter starts again at 0 (see :class:`TrackIdIssuer`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .defaults import DEFAULT_GATE
from .estimates import STATE_BLOCK
from .gate import ci_gate_statistic, ci_gate_statistics, gate_threshold
from .linalg import GaussianState, InformationPair, is_spd, to_information
from .rules import FusionRule, make_rule

Array = np.ndarray

#: the statuses a track may have in a list (deleted tracks are not published)
TRACK_STATUSES = ("tentative", "confirmed")
#: the fusion rule of :func:`fuse_tracks` by default: CI with the fast-CI weights (Niehsen 2002), a fifth of
#: ``ci-trace``'s cost per track (0.2 ms against 0.9 ms for two 4-D estimates)
DEFAULT_TRACK_RULE = "ci-fast"


@dataclass(frozen=True, order=True)
class TrackId:
    """A network-wide track identity; ordered oldest first (``born``), then by ``node`` and ``serial``."""

    born: int
    node: int
    serial: int


class TrackIdIssuer:
    """New ids for the tracks node ``node`` starts: ``TrackId(step, node, serial)`` with a serial counting up
    from ``first_serial``. Unique across restarts: a restarted node starts again at serial 0, but at a later
    step than any id its earlier run issued (a restart within the same step must pass a ``first_serial`` past
    the earlier run's, e.g. its incarnation times a bound on the tracks one run starts)."""

    def __init__(self, node: int, first_serial: int = 0) -> None:
        if node < 0 or first_serial < 0:
            raise ValueError(f"node and first_serial must be >= 0, got {node} and {first_serial}")
        self.node, self._serial = int(node), int(first_serial)

    def issue(self, step: int) -> TrackId:
        """The next id, for a track started at ``step``."""
        self._serial += 1
        return TrackId(int(step), self.node, self._serial - 1)


@dataclass(frozen=True, eq=False)
class TrackEstimate:
    """One track of a list: its id, Gaussian estimate ``mean (n,)``, ``cov (n, n)``, status, step and
    ``misses``, the steps since its holder last measured the target (0: measured at this step). Checked on
    construction (ValueError naming the field)."""

    id: TrackId
    mean: Array
    cov: Array
    status: str = "confirmed"
    step: int = 0
    misses: int = 0

    def __post_init__(self) -> None:
        mean, cov = np.asarray(self.mean, dtype=float), np.asarray(self.cov, dtype=float)
        if mean.ndim != 1 or mean.size == 0 or cov.shape != (mean.size, mean.size):
            raise ValueError(f"track {self.id}: mean {mean.shape} and cov {cov.shape} are not (n,) and (n, n)")
        if not np.isfinite(mean).all():
            raise ValueError(f"track {self.id}: mean has non-finite values")
        if not is_spd(cov):
            raise ValueError(f"track {self.id}: cov is not symmetric positive definite")
        if self.status not in TRACK_STATUSES:
            raise ValueError(f"track {self.id}: status {self.status!r} not one of {TRACK_STATUSES}")
        if not (isinstance(self.misses, int) and self.misses >= 0):
            raise ValueError(f"track {self.id}: misses {self.misses!r} is not a count")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", 0.5 * (cov + cov.T))

    @classmethod
    def checked_before(cls, id: TrackId, mean: Array, cov: Array, status: str = "confirmed", step: int = 0,
                       misses: int = 0) -> TrackEstimate:
        """An estimate whose values were checked where they came from (a decoded track list, which refuses any
        that is not finite or SPD; a fusion rule's output): built without the checks of the constructor, whose
        positive-definiteness test is most of a receiver's time on a list of many tracks."""
        obj = object.__new__(cls)
        for name, value in (("id", id), ("mean", mean), ("cov", cov), ("status", status), ("step", step),
                            ("misses", misses)):
            object.__setattr__(obj, name, value)
        return obj


def track_distance(a: TrackEstimate, b: TrackEstimate) -> float:
    """The association distance of two tracks: :func:`~zentrack.fusion.gate.ci_gate_statistic` (module
    docstring)."""
    return ci_gate_statistic(a.mean, a.cov, b.mean, b.cov)


def sum_distance(own: Sequence[TrackEstimate], other: Sequence[TrackEstimate]) -> Array:
    """``m2 = d^T (P_a + P_b)^-1 d`` for every pair ``(own[i], other[j])``, ``(len(own), len(other))``: the
    squared Mahalanobis distance as if the errors were independent, a cheap screen for the CI gate. The gate
    passes only if ``m2 <= 2^n * threshold``: its ``omega = 1/2`` bound is ``2 (P_a + P_b)``, and its
    smallest-volume bound ``B(omega*)`` is at most ``2^n (P_a + P_b)``. (In the basis of
    :mod:`~zentrack.fusion.gate`, ``B`` has eigenvalues ``s_i = 1/omega + lam_i/(1 - omega) >= 1 + lam_i``, and
    ``sum_i log s_i(omega*) <= sum_i log s_i(1/2) = sum_i log 2 (1 + lam_i)``, so each
    ``s_j(omega*) <= 2^n (1 + lam_j)``; ``1/2`` is among the omegas the gate searches.)"""
    (mean_a, cov_a), (mean_b, cov_b) = _stacked(own), _stacked(other)
    rows, cols = np.indices((len(own), len(other))).reshape(2, -1)
    return pair_sum_distance(mean_a[rows] - mean_b[cols], cov_a[rows], cov_b[cols]).reshape(len(own), len(other))


def pair_sum_distance(d: Array, cov_a: Array, cov_b: Array) -> Array:
    """:func:`sum_distance` of pairs: ``d`` ``(P, n)`` their differences, ``cov_a``, ``cov_b`` ``(P, n, n)``."""
    return np.einsum("pk,pk->p", d, np.linalg.solve(cov_a + cov_b, d[..., None])[..., 0])


def trace_screen(mean_a: Array, cov_a: Array, mean_b: Array, cov_b: Array, bound: float) -> tuple[Array, Array]:
    """The pairs ``(rows, cols)`` of two stacks of estimates whose :func:`sum_distance` may be within ``bound``:
    ``m2 >= |d|^2 / lam_max(P_a + P_b) >= |d|^2 / (tr P_a + tr P_b)``, so a pair with ``|d|^2`` above ``bound``
    times the traces' sum is out without solving its system (most pairs of a list of well separated targets)."""
    diff = mean_a[:, None, :] - mean_b[None, :, :]
    dist2 = np.einsum("ijk,ijk->ij", diff, diff)
    traces = np.trace(cov_a, axis1=1, axis2=2)[:, None] + np.trace(cov_b, axis1=1, axis2=2)[None, :]
    rows, cols = np.nonzero(dist2 <= bound * traces)
    return rows, cols


def _stacked(tracks: Sequence[TrackEstimate]) -> tuple[Array, Array]:
    return np.stack([t.mean for t in tracks]), np.stack([t.cov for t in tracks])


def associate_tracks(own: Sequence[TrackEstimate], other: Sequence[TrackEstimate],
                     false_rejection: float = DEFAULT_GATE) -> list[tuple[int, int]]:
    """Pairs ``(i, j)`` of ``own[i]`` and ``other[j]`` taken to be one target (module docstring): gated by
    :func:`~zentrack.fusion.gate.ci_gate_passes` at ``gate_threshold(n, false_rejection)``, the most gated pairs,
    then the smallest sum of :func:`track_distance`; sorted by ``i``."""
    return gated_assignment(own, other, false_rejection)[0]


def gated_assignment(own: Sequence[TrackEstimate], other: Sequence[TrackEstimate],
                     false_rejection: float = DEFAULT_GATE) -> tuple[list[tuple[int, int]], Array]:
    """:func:`associate_tracks`'s pairs and the gate's verdict on every pair, ``(len(own), len(other))`` bool."""
    admissible = np.zeros((len(own), len(other)), dtype=bool)
    if not own or not other:
        return [], admissible
    dims = {t.mean.size for t in (*own, *other)}
    if len(dims) != 1:
        raise ValueError(f"tracks of different state dimensions {sorted(dims)} cannot be associated")
    n = dims.pop()
    threshold = gate_threshold(n, false_rejection)
    (mean_a, cov_a), (mean_b, cov_b) = _stacked(own), _stacked(other)
    # necessary conditions, cheap for all pairs: the traces' screen, then sum_distance's for the pairs it leaves
    rows, cols = trace_screen(mean_a, cov_a, mean_b, cov_b, 2.0**n * threshold)
    d = mean_a[rows] - mean_b[cols]
    m2 = pair_sum_distance(d, cov_a[rows], cov_b[cols]) if rows.size else np.zeros(0)
    near = m2 <= 2.0**n * threshold
    rows, cols, d, m2 = rows[near], cols[near], d[near], m2[near]
    if not rows.size:
        return [], admissible
    # the gate passes as ci_gate_passes decides: the omega = 1/2 bound (0.5 m2) within the threshold, else the
    # smallest-volume one (q, track_distance). q is computed, in one batch each, only where it decides: for the pairs
    # the first bound leaves out, and as the assignment's cost where a track has more than one admissible partner (a
    # pair alone in its row and its column is in every assignment with the most pairs, whatever it costs). Every
    # TrackEstimate is SPD (checked on construction or where it came from), so a pair the first bound passes has a
    # finite q.
    half = 0.5 * m2 <= threshold
    q = np.zeros(rows.size)
    if not half.all():
        q[~half] = ci_gate_statistics(d[~half], cov_a[rows[~half]], cov_b[cols[~half]])
    passes = half | (q <= threshold)
    admissible[rows[passes], cols[passes]] = True
    rows, cols, d, q, known = rows[passes], cols[passes], d[passes], q[passes], ~half[passes]
    shared = (admissible.sum(axis=1)[rows] > 1) | (admissible.sum(axis=0)[cols] > 1)
    if not shared.any():  # (no admissible pair at all, or each alone: the assignment is the admissible pairs)
        return sorted(zip(rows.tolist(), cols.tolist())), admissible
    needed = shared & ~known
    q[needed] = ci_gate_statistics(d[needed], cov_a[rows[needed]], cov_b[cols[needed]])
    cost = np.zeros(admissible.shape)
    cost[rows, cols] = q
    # an inadmissible pair costs more than every admissible pair together: fewest inadmissible pairs first
    cost[~admissible] = 1.0 + 2.0 * float(cost[admissible].sum())
    from scipy.optimize import linear_sum_assignment  # imported here: a node without track lists never needs it

    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols) if admissible[i, j]], admissible


def fuse_tracks(tracks: Sequence[TrackEstimate], rule: str | FusionRule = DEFAULT_TRACK_RULE,
                params: Mapping[str, object] | None = None) -> tuple[Array, Array]:
    """The fused ``(mean, cov)`` of several estimates of one target by the registered fusion rule ``rule`` (a
    name with its ``params``, or a rule instance): :func:`fuse_track_sets` of one set."""
    return fuse_track_sets([tracks], rule, params)[0]


def fuse_track_sets(sets: Sequence[Sequence[TrackEstimate]], rule: str | FusionRule = DEFAULT_TRACK_RULE,
                    params: Mapping[str, object] | None = None) -> list[tuple[Array, Array]]:
    """The fused ``(mean, cov)`` of each set of estimates (one target each), in order. Each estimate is shared as
    the rule shares a filter's ``state`` block (round 1), the rule's ``network_weights`` over a set's estimates (a
    complete graph, uniform diffusion weights) give the first estimate's row, and the rule's
    :meth:`~zentrack.fusion.rules.FusionRule.combine` fuses them; sets of one size go through it as one batch
    (a receiver's 50 targets are a few numpy calls, not 50 rounds of them). A set of one is returned as it is."""
    out: list[tuple[Array, Array] | None] = [None] * len(sets)
    by_size: dict[int, list[int]] = {}
    for c, tracks in enumerate(sets):
        if not tracks:
            raise ValueError("no track to fuse")
        n = tracks[0].mean.size
        if any(t.mean.size != n for t in tracks):
            raise ValueError(f"tracks of different state dimensions {sorted({t.mean.size for t in tracks})}")
        if len(tracks) == 1:
            out[c] = (tracks[0].mean.copy(), tracks[0].cov.copy())
        else:
            by_size.setdefault(len(tracks), []).append(c)
    if by_size:
        fusion = make_rule(rule, params)
        for count, members in by_size.items():
            if len({sets[c][0].mean.size for c in members}) != 1:
                raise ValueError("sets of tracks of different state dimensions")
            weights = fusion.network_weights(np.full((count, count), 1.0 / count), 1.0 - np.eye(count))[0]
            means = np.stack([[t.mean for t in sets[c]] for c in members])  # (R, S, n)
            covs = np.stack([[t.cov for t in sets[c]] for c in members])  # (R, S, n, n)
            info = to_information(GaussianState(means, covs))
            shared = fusion.share(1, {STATE_BLOCK: InformationPair(info.matrix, info.vector)}).blocks
            fused = fusion.combine(1, np.asarray(weights, dtype=float)[None, :], shared,
                                   np.ones((1, count), dtype=bool))[STATE_BLOCK]
            n = means.shape[-1]
            mean, cov = fused.mean.reshape(len(members), n), fused.cov.reshape(len(members), n, n)
            for r, c in enumerate(members):
                out[c] = (mean[r], cov[r])
    return [o for o in out if o is not None]


@dataclass
class TrackCluster:
    """One target as a receiver sees it: its own track (None if it does not hold the target) and the
    neighbours' tracks associated with it, at most one per neighbour (``senders`` beside them)."""

    own: TrackEstimate | None
    members: list[TrackEstimate] = field(default_factory=list)
    senders: list[int] = field(default_factory=list)

    @property
    def tracks(self) -> list[TrackEstimate]:
        return ([self.own] if self.own is not None else []) + self.members

    @property
    def representative(self) -> TrackEstimate:
        """What a neighbour's list is associated with: the own track, else the first neighbour's."""
        return self.own if self.own is not None else self.members[0]


def _checked_list(tracks: Sequence[TrackEstimate], what: str, step: int | None) -> None:
    ids = [t.id for t in tracks]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{what}: duplicate track ids")
    if step is not None and any(t.step != step for t in tracks):
        raise ValueError(f"{what}: tracks not at step {step} (predict them to one step first)")


def cluster_tracks(own: Sequence[TrackEstimate], neighbour_lists: Mapping[int, Sequence[TrackEstimate]],
                   false_rejection: float = DEFAULT_GATE) -> list[TrackCluster]:
    """The receiver's targets: one cluster per own track, then one per neighbour's confirmed track that no
    cluster took, unless it is a duplicate at its sender (a cluster gates it and it gates the sender's track that
    cluster took: left out, so a duplicate does not spread through the network). Lists are associated (:func:`associate_tracks`) in the order of their senders' ids, each with the
    clusters' representatives so far; tentative neighbour tracks are left out."""
    step = own[0].step if own else None
    _checked_list(own, "own tracks", step)
    clusters = [TrackCluster(t) for t in own]
    for sender in sorted(neighbour_lists):
        tracks = [t for t in neighbour_lists[sender] if t.status == "confirmed"]
        step = tracks[0].step if step is None and tracks else step
        _checked_list(tracks, f"node {sender}'s tracks", step)
        assigned, gated = gated_assignment([c.representative for c in clusters], tracks, false_rejection)
        pairs = dict((j, i) for i, j in assigned)
        taken_by = {i: j for i, j in assigned}  # cluster -> the sender's track it took
        for j, track in enumerate(tracks):
            if j in pairs:
                clusters[pairs[j]].members.append(track)
                clusters[pairs[j]].senders.append(sender)
            elif not _duplicate(track, [tracks[taken_by[c]] for c in np.flatnonzero(gated[:, j]).tolist() if c in taken_by],
                                false_rejection):
                clusters.append(TrackCluster(None, [track], [sender]))  # a target no cluster holds
    return clusters


def _duplicate(track: TrackEstimate, siblings: Sequence[TrackEstimate], false_rejection: float) -> bool:
    """Whether a sender's track is a second track of a target a cluster holds: the gate passes it against the
    sender's own track that the cluster took (two of the sender's tracks that agree are one target twice; two
    targets close together, each with its track, are not)."""
    return bool(siblings) and bool(gated_assignment(siblings, [track], false_rejection)[1].any())


def network_ids(clusters: Sequence[TrackCluster], issuer: TrackIdIssuer | None = None) -> list[TrackId | None]:
    """Per cluster its network id: the smallest id its tracks carry that no other cluster of this receiver took.
    Clusters are served in the order of their smallest ids, so on every node the oldest id of a target wins. A
    cluster whose ids were all taken gets a new id from ``issuer`` if it holds an own track (ValueError without
    an issuer), else None: it duplicates a target the receiver already holds."""
    ids = [sorted({t.id for t in cluster.tracks}) for cluster in clusters]  # each cluster's ids, oldest first
    order = sorted(range(len(clusters)), key=lambda c: ids[c][0])
    seen = set().union(*ids)  # a new id must not be one a neighbour already sent
    taken: set[TrackId] = set()
    out: list[TrackId | None] = [None] * len(clusters)
    for c in order:
        own = clusters[c].own
        chosen = next((i for i in ids[c] if i not in taken), None)
        if chosen is None and own is not None:
            if issuer is None:
                raise ValueError(f"own track {own.id}: every id of its target is taken; pass an issuer")
            chosen = issuer.issue(own.step)
            while chosen in seen or chosen in taken:
                chosen = issuer.issue(own.step)
        if chosen is not None:
            out[c] = chosen
            taken.add(chosen)
    return out


@dataclass(frozen=True)
class TrackListFusion:
    """What a receiver makes of its own and its neighbours' lists: ``tracks``, its own tracks fused with their
    associated neighbours' tracks, under their network ids (in the order of its own list); ``renamed``, the own
    ids that changed (old -> network id) for the local tracker to relabel; ``takeovers``, one prior per target
    it does not hold (neighbours' tracks fused, under their network id), for the local tracker to start. Each
    fused estimate's ``misses`` is the least of its tracks': 0 when some holder measured the target at this
    step."""

    tracks: tuple[TrackEstimate, ...]
    renamed: dict[TrackId, TrackId]
    takeovers: tuple[TrackEstimate, ...]
    #: per own track, how many neighbours' tracks were fused into it
    support: tuple[int, ...] = ()


def fuse_track_lists(own: Sequence[TrackEstimate], neighbour_lists: Mapping[int, Sequence[TrackEstimate]],
                     rule: str = DEFAULT_TRACK_RULE, params: Mapping[str, object] | None = None,
                     false_rejection: float = DEFAULT_GATE, issuer: TrackIdIssuer | None = None) -> TrackListFusion:
    """One receiver's track-to-track fusion: :func:`cluster_tracks`, :func:`network_ids`, :func:`fuse_tracks`
    per cluster (see :class:`TrackListFusion`)."""
    clusters = cluster_tracks(own, neighbour_lists, false_rejection)
    ids = network_ids(clusters, issuer)
    kept = [(cluster, net_id) for cluster, net_id in zip(clusters, ids) if net_id is not None]
    estimates = fuse_track_sets([cluster.tracks for cluster, _ in kept], rule, params)  # one batch per set size
    fused_own, renamed, takeovers, support = [], {}, [], []
    for (cluster, net_id), (mean, cov) in zip(kept, estimates):
        first = cluster.representative
        fused = TrackEstimate.checked_before(net_id, mean, 0.5 * (cov + cov.T), first.status, first.step,
                                             min(t.misses for t in cluster.tracks))
        if cluster.own is None:
            takeovers.append(fused)
            continue
        fused_own.append(fused)
        support.append(len(cluster.members))
        if net_id != cluster.own.id:
            renamed[cluster.own.id] = net_id
    return TrackListFusion(tuple(fused_own), renamed, tuple(takeovers), tuple(support))
