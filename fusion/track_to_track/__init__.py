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

The package's rooms: :mod:`.tracks` (what a list holds: ids and estimates), :mod:`.association` (distances and
the gated assignment), :mod:`.lists` (a receiver's clusters, network ids and fused list).
"""
from .association import (
                    associate_tracks,
                    gated_assignment,
                    pair_sum_distance,
                    sum_distance,
                    trace_screen,
                    track_distance,
)
from .lists import (
                    TrackCluster,
                    TrackListFusion,
                    cluster_tracks,
                    fuse_track_lists,
                    fuse_track_sets,
                    fuse_tracks,
                    network_ids,
)
from .tracks import DEFAULT_TRACK_RULE, TRACK_STATUSES, TrackEstimate, TrackId, TrackIdIssuer

__all__ = ["DEFAULT_TRACK_RULE", "TRACK_STATUSES", "TrackCluster", "TrackEstimate", "TrackId", "TrackIdIssuer",
           "TrackListFusion", "associate_tracks", "cluster_tracks", "fuse_track_lists", "fuse_track_sets",
           "fuse_tracks", "gated_assignment", "network_ids", "pair_sum_distance", "sum_distance", "trace_screen",
           "track_distance"]
