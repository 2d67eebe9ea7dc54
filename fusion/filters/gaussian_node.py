"""A :class:`~zentrack.fusion.filters.base.NodeFilter` around any batched :class:`LocalFilter` (batch of one).

This is how every Gaussian filter of the registry (TESKF, ESKF, EKF, UKF, CKF) runs in one tracker process.
For one scan the update is exactly the per-node call of the batched simulator and of a tracker, so a lockstep
cluster reproduces ``zentrack sim`` bit for bit::

    local_filter.update(prior, z[None, :], pose[None, None, :], noise_cov[None])   # (1, m), (1, 1, 3), (1, m, m)

Several scans (the node's own and forwarded ones, paper 2) are stacked like the centralized filter of seed
000 eq. 15: ``z`` ``(1, S*m)``, ``sensors`` ``(1, S, 3)`` and a block-diagonal noise ``(1, S*m, S*m)``.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..estimates import Estimate, GaussianEstimate
from ..isolation import isolated_update
from ..linalg import GaussianState, InformationPair
from ..scan import Scan
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, NodeFilter

Array = np.ndarray


def stack_scans(scans: Sequence[Scan]) -> tuple[Array, Array, Array] | None:
    """``(z (1, S*m), sensors (1, S, 3), noise (1, S*m, S*m))`` of the point-target scans, or None (coast).

    A scan with J = 0 (looked, saw nothing) is skipped; J > 1 is an error for point-target filters.
    """
    used = []
    for scan in scans:
        if scan.count > 1:
            raise ValueError(
                f"scan of sensor {scan.sensor} at step {scan.step} has {scan.count} returns; "
                "a point-target filter takes at most one per scan"
            )
        if scan.count == 1:
            used.append(scan)
    if not used:
        return None
    if len(used) == 1:
        s = used[0]
        return s.returns[0][None, :], s.pose[None, None, :], s.noise_cov[None]
    dims = {s.dim for s in used}
    if len(dims) != 1:
        raise ValueError(f"scans of one update must share the measurement dimension, got {sorted(dims)}")
    m = dims.pop()
    noise = np.zeros((len(used) * m, len(used) * m))
    for i, s in enumerate(used):
        noise[i * m : (i + 1) * m, i * m : (i + 1) * m] = s.noise_cov
    z = np.concatenate([s.returns[0] for s in used])[None, :]
    return z, np.stack([s.pose for s in used])[None], noise[None]


class GaussianNodeFilter(NodeFilter):
    """Runs ``local_filter`` on a batch of one; estimates are :class:`GaussianEstimate`.

    ``p0`` is the kinematic prior covariance and ``lumped_var`` the prior variance of augmented components,
    as in :meth:`LocalFilter.initial_state`.
    """

    def __init__(self, local_filter: LocalFilter, lumped_var: float, p0: Array) -> None:
        self.local_filter = local_filter
        self.lumped_var = lumped_var
        self.p0 = np.asarray(p0, dtype=float)
        self.state_dim = local_filter.state_dim
        self.kinematic_dim = local_filter.kinematic_dim
        self.name = getattr(local_filter, "name", "filter")
        #: the last estimate this adapter returned and the filter state it came from (a subclass of
        #: GaussianState may carry more, e.g. SecKF's previous prediction), reused when that estimate comes back
        self._last: tuple[GaussianEstimate, GaussianState] | None = None

    def _state(self, est: Estimate) -> GaussianState:
        if self._last is not None and self._last[0] is est:
            return self._last[1]  # the filter's own output: with whatever it carries between steps (SecKF)
        if not isinstance(est, GaussianEstimate):
            raise TypeError(f"{self.name}: expected a GaussianEstimate, got {type(est).__name__}")
        if est.dim != self.state_dim:
            raise ValueError(f"{self.name}: estimate has dimension {est.dim}, the filter state {self.state_dim}")
        return est.to_state()

    def _estimate(self, state: GaussianState) -> GaussianEstimate:
        est = GaussianEstimate.from_state(state, self.kinematic_dim)
        self._last = (est, state)
        return est

    def initial(self, x0_mean: Array, rng: np.random.Generator | None = None) -> GaussianEstimate:
        x0 = np.asarray(x0_mean, dtype=float)
        if x0.shape != (self.kinematic_dim,):
            raise ValueError(f"x0_mean: expected shape ({self.kinematic_dim},), got {x0.shape}")
        return self._estimate(self.local_filter.initial_state(x0[None, :], self.p0, self.lumped_var))

    def predict(self, est: Estimate) -> GaussianEstimate:
        return self._estimate(self.local_filter.predict(self._state(est)))

    def blocks(self, est: Estimate) -> dict[str, InformationPair]:
        """The filter's own information blocks where it has them (paper 4's scan increment), else the
        estimate's."""
        own = getattr(self.local_filter, "information_blocks", None)
        if own is None:
            return est.information_blocks()
        return {name: InformationPair(p.matrix[0], p.vector[0]) for name, p in own(self._state(est)).items()}

    def update(self, est: Estimate, scans: Sequence[Scan]) -> GaussianEstimate:
        state = self._state(est)
        if getattr(self.local_filter, "takes_scans", False):  # every point of each scan, one scan after another
            used = [s for s in scans if s.count > 0]
            if not used:
                assert isinstance(est, GaussianEstimate)
                return est
            for scan in used:
                state = self.local_filter.update(state, scan.returns[None], scan.pose[None, None], scan.noise_cov[None],
                                                 counts=np.array([scan.count]))  # type: ignore[call-arg]
            return self._estimate(state)
        stacked = stack_scans(scans)
        if stacked is None:
            assert isinstance(est, GaussianEstimate)
            return est
        z, sensors, noise = stacked
        return self._estimate(self.local_filter.update(state, z, sensors, noise))

    def update_isolated(self, est: Estimate, scans: Sequence[Scan]) -> GaussianEstimate:
        """:meth:`update` of a node that heard no neighbour in the fusion that made ``est``: the batched
        simulator's isolated row, :func:`~zentrack.fusion.isolation.isolated_update` on a batch of one (a
        filter without a nominal transition, or one that takes whole scans, updates as always)."""
        if getattr(self.local_filter, "takes_scans", False) or self.local_filter.nominal_transition() is None:
            return self.update(est, scans)
        stacked = stack_scans(scans)
        if stacked is None:
            assert isinstance(est, GaussianEstimate)
            return est
        z, sensors, noise = stacked
        return self._estimate(isolated_update(self.local_filter, self._state(est), z, sensors, noise))

    def from_fused(self, blocks: Mapping[str, GaussianState], like: Estimate | None) -> GaussianEstimate:
        """The fused ``"state"`` block: one estimate, ``(1, n)`` or as :meth:`FusionRule.combine` returns it
        for one receiver, ``(1, 1, n)``."""
        if set(blocks) != {"state"}:
            raise ValueError(f"{self.name}: expected the fused block 'state', got {sorted(blocks)}")
        fused = blocks["state"]
        n = self.state_dim
        if fused.mean.size != n or fused.mean.shape[-1] != n or fused.cov.shape[-2:] != (n, n) or fused.cov.size != n * n:
            raise ValueError(f"{self.name}: fused block has shape {fused.mean.shape}, expected one estimate of {n}")
        # combine's output for one receiver is (R=1, 1, n); a plain batch of one is (1, n)
        return self._estimate(GaussianState(fused.mean.reshape(1, n), fused.cov.reshape(1, n, n)))


def make_node_filter(name: str, context: FilterContext, params: Mapping[str, Any] | None = None) -> NodeFilter:
    """The registered filter ``name`` for one tracker: a registered :class:`NodeFilter` as is, a
    :class:`LocalFilter` as its own :meth:`~LocalFilter.node_filter` says (clutter filters keep their particle
    cloud and take every return of a scan), else wrapped in :class:`GaussianNodeFilter`."""
    built = FILTER_REGISTRY.create(name, params, context)
    if isinstance(built, NodeFilter):
        return built
    if isinstance(built, LocalFilter):
        own = built.node_filter(context)
        return own if own is not None else GaussianNodeFilter(built, context.lumped_var, context.p0)
    raise TypeError(f"local filter {name!r}: factory returned {type(built).__name__}, not a LocalFilter or NodeFilter")
