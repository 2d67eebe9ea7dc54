"""A receiver's track-to-track fusion: its own and its neighbours' lists clustered per target, one network id per
cluster, each cluster's estimates fused by a registered rule, and the takeovers of targets it does not hold."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..defaults import DEFAULT_GATE
from ..estimates import STATE_BLOCK
from ..linalg import GaussianState, InformationPair, to_information
from ..rules import FusionRule, make_rule
from .association import gated_assignment
from .tracks import DEFAULT_TRACK_RULE, TrackEstimate, TrackId, TrackIdIssuer

Array = np.ndarray


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
    step; its ``existence`` the average of theirs (arithmetic-average fusion of the Bernoulli existences, Li,
    Hlawatsch & Djurić 2019: 1 for M-of-N tracks)."""

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
        members = cluster.tracks
        fused = TrackEstimate.checked_before(net_id, mean, 0.5 * (cov + cov.T), first.status, first.step,
                                             min(t.misses for t in members),
                                             sum(t.existence for t in members) / len(members))
        if cluster.own is None:
            takeovers.append(fused)
            continue
        fused_own.append(fused)
        support.append(len(cluster.members))
        if net_id != cluster.own.id:
            renamed[cluster.own.id] = net_id
    return TrackListFusion(tuple(fused_own), renamed, tuple(takeovers), tuple(support))
