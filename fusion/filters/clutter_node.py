"""One tracker process running a clutter filter (seed 001): :class:`ClutterNodeFilter`.

:func:`~zentrack.fusion.filters.gaussian_node.make_node_filter` wraps a batched LocalFilter in a
GaussianNodeFilter, which takes at most one return per scan and keeps no particles; a
:class:`~zentrack.fusion.filters.pda_common.ClutterFilter` needs this wrapper instead
(:func:`make_clutter_node_filter`, or ``ClutterNodeFilter(built, context.p0)``):

- ``update(est, scans)``: every scan in turn (J >= 0 returns each, :meth:`ClutterFilter.update_scan`);
  ``[]`` coasts;
- estimates: a :class:`~zentrack.fusion.estimates.ParticleEstimate` (equal weights) for the particle filters,
  a :class:`~zentrack.fusion.estimates.GaussianEstimate` for the PDAF-EKF and NN-EKF; either shares its
  Gaussian summary for fusion;
- ``from_fused(blocks, like)``: the fused Gaussian; a particle filter moves ``like``'s cloud onto it
  (:func:`~zentrack.fusion.filters.pda_common.reseed_cloud`), or samples it when there is no ``like``.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..estimates import Estimate, GaussianEstimate, ParticleEstimate
from ..linalg import GaussianState
from ..scan import Scan
from .base import FILTER_REGISTRY, FilterContext, NodeFilter
from .pda_common import ClutterFilter, ParticleClutterFilter, ParticleState, summarize

Array = np.ndarray
#: particles a tracker publishes with each estimate for viewers (a subsample of its cloud)
DIAGNOSTIC_SAMPLES = 64


class ClutterNodeFilter(NodeFilter):
    """A :class:`ClutterFilter` on a batch of one (module docstring); ``p0`` is the prior covariance."""

    def __init__(self, local_filter: ClutterFilter, p0: Array) -> None:
        self.local_filter = local_filter
        self.p0 = np.asarray(p0, dtype=float)
        self.state_dim = local_filter.state_dim
        self.kinematic_dim = local_filter.kinematic_dim
        self.name = local_filter.name

    @property
    def particles(self) -> bool:
        return isinstance(self.local_filter, ParticleClutterFilter)

    def _state(self, est: Estimate) -> GaussianState:
        if isinstance(est, ParticleEstimate):
            return summarize(est.samples[None])
        if isinstance(est, GaussianEstimate):
            return est.to_state()
        raise TypeError(f"{self.name}: expected a ParticleEstimate or GaussianEstimate, got {type(est).__name__}")

    def _estimate(self, state: GaussianState) -> Estimate:
        if isinstance(state, ParticleState):
            cloud = state.particles[0]
            return ParticleEstimate(cloud, np.full(cloud.shape[0], 1.0 / cloud.shape[0]), self.kinematic_dim)
        return GaussianEstimate.from_state(state, self.kinematic_dim)

    def initial(self, x0_mean: Array, rng: np.random.Generator | None = None) -> Estimate:
        x0 = np.asarray(x0_mean, dtype=float)
        if x0.shape != (self.kinematic_dim,):
            raise ValueError(f"x0_mean: expected shape ({self.kinematic_dim},), got {x0.shape}")
        return self._estimate(self.local_filter.initial_state(x0[None], self.p0))

    def predict(self, est: Estimate) -> Estimate:
        return self._estimate(self.local_filter.predict(self._state(est)))

    def update(self, est: Estimate, scans: Sequence[Scan]) -> Estimate:
        self._beta: Array | None = None
        if not scans:
            return est
        state = self._state(est)
        for scan in scans:
            state = self.local_filter.update_scan(state, scan)
        if scans[0].returns.shape[0] > 0 and self.local_filter.last_association is not None and len(scans) == 1:
            self._beta = np.asarray(self.local_filter.last_association.beta[0], dtype=float).copy()
        return self._estimate(state)

    def diagnostics(self, est: Estimate) -> dict[str, Array]:
        """``samples``: up to :data:`DIAGNOSTIC_SAMPLES` particles' kinematic part (evenly strided);
        ``beta``: the association probability of each return of the node's own scan (this step's update)."""
        out: dict[str, Array] = {}
        if isinstance(est, ParticleEstimate):
            cloud = est.samples[:, : self.kinematic_dim]
            stride = max(1, cloud.shape[0] // DIAGNOSTIC_SAMPLES)
            out["samples"] = np.ascontiguousarray(cloud[::stride][:DIAGNOSTIC_SAMPLES])
        beta = getattr(self, "_beta", None)
        if beta is not None:
            out["beta"] = beta
        return out

    def from_fused(self, blocks: Mapping[str, GaussianState], like: Estimate | None) -> Estimate:
        if set(blocks) != {"state"}:
            raise ValueError(f"{self.name}: expected the fused block 'state', got {sorted(blocks)}")
        n = self.state_dim
        fused = GaussianState(blocks["state"].mean.reshape(1, n), blocks["state"].cov.reshape(1, n, n))
        if isinstance(self.local_filter, ParticleClutterFilter):
            previous = self._state(like) if like is not None else None
            return self._estimate(self.local_filter.adopt(fused, previous))
        return self._estimate(fused)


def make_clutter_node_filter(name: str, context: FilterContext, params: Mapping[str, Any] | None = None) -> NodeFilter:
    """The registered clutter filter ``name`` for one tracker (a :class:`ClutterNodeFilter`)."""
    built = FILTER_REGISTRY.create(name, params, context)
    if not isinstance(built, ClutterFilter):
        raise TypeError(f"local filter {name!r} is not a clutter filter")
    return ClutterNodeFilter(built, context.p0)
