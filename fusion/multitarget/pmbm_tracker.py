"""A node's PMBM filter behind the multi-target tracker's interface: what a network node
(:class:`~zentrack.fusion.multitarget.network.NetworkTracker`) steps, publishes and fuses its neighbours' lists into.

:class:`PmbmTracker` steps a :class:`~zentrack.fusion.multitarget.pmbm.Pmbm` (one prediction per step, each scan an
update) and shows its **best global hypothesis** as :class:`~.base.Track` views: every track of existence ``r`` at
least ``view_existence``, *confirmed* when ``r`` is at least the filter's ``estimate_existence`` (what the node
outputs and publishes: no M of N), *tentative* below it (what a neighbour's confirmed track can still join instead of
being taken over twice). A view's ``misses`` are the steps since its leaf was last detected
(:attr:`~zentrack.fusion.multitarget.pmbm.Tracks.last_hit`).

What the network's exchange does to the views goes back into the filter at the next step:

- a fused estimate replaces its leaf's Gaussian (the diffusion step the GNN nodes take), the least ``misses`` of its
  cluster its leaf's last detection;
- **existence, arithmetic-average fusion** (Li, Hlawatsch & Djurić 2019; Da, Li et al. 2020 for multi-Bernoulli
  densities): a track that neighbours' confirmed tracks joined takes the average of its own ``r`` and theirs (each
  list carries its tracks' existence; the exchange averages them over the cluster,
  :func:`~zentrack.fusion.track_to_track.fuse_track_lists`);
- a track whose cluster no holder has measured for ``max_misses`` steps is given up (``r`` 0: pruned), like the GNN
  nodes' deleter; a view the node dropped (a broken estimate) likewise;
- a neighbour's target it does not hold (a takeover, queued by :meth:`~.base.Initiator.from_prior`) starts a track of
  the existence it came with in every global hypothesis, shown at its first step whatever its ``r``, so that the
  node names it with the network id it came with.

Point sensors on the run's grid (the filter's undetected targets are spread evenly over what the point sensors see);
sensors of their own are refused in one line.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..filters.base import LocalFilter
from ..filters.interval import IntervalPredictor
from ..linalg import GaussianState
from ..measurement import MeasurementModel
from ..scan import Scan
from .base import Birth, Track, TrackStatus
from .initiator import PriorInitiator
from .pmbm import Pmbm, UniformIntensity

Array = np.ndarray

#: the undetected targets' density at the first step, and the density born at each step after, in units of the
#: clutter density: as many undetected targets at the start as clutter returns in a scan, a hundredth of that born
#: a step
INITIAL_DENSITY, BIRTH_DENSITY = 1.0, 0.01


def undetected(max_speed: float) -> UniformIntensity:
    """The undetected targets of a PMBM tracker of point sensors: spread evenly over the sensors' views at
    :data:`INITIAL_DENSITY` and :data:`BIRTH_DENSITY`, a new track's velocity spread ``max_speed / 2`` per axis."""
    return UniformIntensity(INITIAL_DENSITY, BIRTH_DENSITY, max_speed / 2)


class PmbmTracker:
    """One node's PMBM filter as a multi-target tracker (module docstring)."""

    def __init__(self, pmbm: Pmbm, measurement: MeasurementModel, lumped_var: float = 1.0, max_misses: int = 5,
                 view_existence: float = 0.1) -> None:
        if not 0 < view_existence <= pmbm.s.estimate_existence:
            raise ValueError("PMBM tracker: view_existence must be in (0, estimate_existence]")
        self.pmbm, self.measurement, self.lumped_var = pmbm, measurement, float(lumped_var)
        self.local_filter: LocalFilter = pmbm.filter
        self.max_misses, self.view_existence = max_misses, view_existence
        self.initiator = PriorInitiator()
        self.tracks: list[Track] = []
        self.deleted: list[Track] = []
        self.last_step: int | None = None
        self._shown: list[tuple[Track, int]] = []  # the views of the last step and their leaves
        self._born: dict[int, int] = {}  # a filter track's id -> the step it was first shown

    def confirmed(self) -> list[Track]:
        """The views of existence at least the filter's ``estimate_existence``."""
        return [t for t in self.tracks if t.status is TrackStatus.CONFIRMED]

    def kinematic(self, track: Track) -> tuple[Array, Array]:
        """A track's kinematic mean and covariance (what is compared with the truth)."""
        k = self.local_filter.kinematic_dim
        return track.mean[:k], track.cov[:k, :k]

    def step(self, step: int, scans: Sequence[Scan] | Scan | None = None) -> list[Track]:
        """Advance to ``step`` with its scans (the exchange's results first into the filter); the views."""
        if self.last_step is not None and step <= self.last_step:
            raise ValueError(f"step {step} does not follow the last step {self.last_step}")
        scan_list = [] if scans is None else [scans] if isinstance(scans, Scan) else list(scans)
        for scan in scan_list:
            scan.validate()
        self._write_back()
        for _ in range(step - self.last_step if self.last_step is not None else 0):
            self.pmbm.predict()
        priors = self.initiator.take_priors()
        taken = self._take_over(priors)
        for scan in scan_list:
            self.pmbm.update(scan)
        self._show(step, taken)
        self.last_step = step
        return self.tracks

    def step_over(self, step: int, t_from: float, t_to: float, timed: Sequence[tuple[float, Scan]],
                  predictor: IntervalPredictor) -> list[Track]:
        """Sensors of their own: not taken by the PMBM tracker yet (ValueError)."""
        raise ValueError("the PMBM tracker steps on the run's grid; sensors of their own need the GNN tracker")

    def _take_over(self, priors: Sequence[Birth]) -> set[int]:
        """The queued priors as new tracks of the existence they came with; their filter ids."""
        if not priors:
            return set()
        states = [self.local_filter.initial_state(p.mean[None], p.cov, self.lumped_var) for p in priors]
        state = GaussianState(np.concatenate([s.mean for s in states]), np.concatenate([s.cov for s in states]))
        return set(self.pmbm.add_tracks(state, np.array([p.existence for p in priors])).tolist())

    def _show(self, step: int, taken: set[int]) -> None:
        """The best global hypothesis's tracks as views (module docstring): those of existence at least
        ``view_existence`` and this step's takeovers (first among the new ones, in the order they were queued)."""
        t, pm = self.pmbm.tracks, self.pmbm
        self.tracks, self._shown = [], []
        if t.state is None or t.ids.size == 0:
            return
        leaves = t.hypotheses[int(np.argmax(t.log_weights))]
        ids = t.ids[t.track[leaves]]
        shown = (t.r[leaves] >= self.view_existence) | np.isin(ids, list(taken))
        hit = t.hit_clock()
        # shown before first, then this step's takeovers in the order they were queued (their ids were issued so),
        # then the other new ones: the node names its new tracks in this order, the takeovers' ids first
        order = sorted(np.flatnonzero(shown).tolist(),
                       key=lambda n: (int(ids[n]) not in self._born, int(ids[n]) not in taken, int(ids[n])))
        for n in order:
            leaf, tid = int(leaves[n]), int(ids[n])
            misses = int(pm.clock - hit[leaf])
            confirmed = t.r[leaf] >= pm.s.estimate_existence or tid in taken
            born = self._born.setdefault(tid, step)
            view = Track(tid, t.state.mean[leaf].copy(), t.state.cov[leaf].copy(), born, step,
                         TrackStatus.CONFIRMED if confirmed else TrackStatus.TENTATIVE, [True, misses == 0], misses,
                         existence=float(t.r[leaf]))
            self.tracks.append(view)
            self._shown.append((view, leaf))
        self._born = {i: b for i, b in self._born.items() if i in set(t.ids.tolist())}

    def _write_back(self) -> None:
        """The exchange's results on the last step's views into their leaves (module docstring)."""
        t, pm = self.pmbm.tracks, self.pmbm
        if not self._shown or t.state is None:
            return
        kept = {id(v) for v in self.tracks}
        hit = t.hit_clock().copy()
        mean, cov, r = t.state.mean.copy(), t.state.cov.copy(), t.r.copy()
        for view, leaf in self._shown:
            if id(view) not in kept or view.misses >= self.max_misses:
                r[leaf] = 0.0  # dropped by the node, or no holder measured it for max_misses steps
                continue
            mean[leaf], cov[leaf] = view.mean, view.cov
            hit[leaf] = pm.clock - view.misses  # (the least count of its cluster: at most its own)
            if view.support:  # the cluster's average existence (module docstring)
                r[leaf] = view.existence
        self.pmbm.tracks = type(t)(t.ids, t.track, r, t.log_w, GaussianState(mean, cov), t.hypotheses,
                                   t.log_weights, hit)
        self._shown = []
