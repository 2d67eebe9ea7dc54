"""The local-filter interface every tracker node runs, and how later filters plug into it.

A local filter works on a stack of estimates (:class:`~zentrack.fusion.linalg.GaussianState`, ``(B, n)``
means and ``(B, n, n)`` covariances) so that one node, every node of a network, or every node of many Monte
Carlo runs step through the same code.  One step of a diffusion node (paper 0 Algorithm 2) is::

    state = filt.update(prior, z, sensors, noise_cov)   # local correction, lines 6-7
    shared = filt.predict(state)                        # local time update, line 8
    pair = to_information(shared)                       # broadcast, line 9
    prior = fusion_rule(pairs from neighbours)          # CI diffusion, line 10

``kinematic(state)`` returns the part of the state that is compared with the truth (position/velocity),
so augmented filters (extended states, extents) are scored like plain ones.

How the later seeds fit this interface:

- **Particle filter in clutter (paper 1, PDA-FPF)**: the "state" keeps particles internally; ``update``
  receives every return of the scan in ``z`` (validation gate and association probabilities inside);
  the exported Gaussian is the particle mean and sample covariance, so ``to_information`` and any fusion
  rule apply unchanged.
- **Square-root cubature information filter (paper 2)**: ``update`` takes the stacked measurements of the
  node and its neighbours with a ``sensors`` array of shape ``(B, S, 3)`` (S > 1), exactly like the
  centralized filters here; the square-root factor is an internal detail and ``predict`` exports the usual
  Gaussian. Its inverse-CI fusion rule is another file in ``fusion/rules/`` (with ``exchanges_scans``).
- **Secant Kalman filter (paper 3)**: an :class:`ExtendedKalmanFilter` whose ``update`` replaces Jacobian
  elements by secant slopes between the prediction and a first EKF estimate; same signature.
- **Extended-object information filter (paper 4)**: the state is the kinematic block plus a separate
  extent block ``[alpha, l1, l2]``; ``kinematic`` returns the first block, ``update`` processes point
  measurements sequentially with the pseudo-measurement for the extent, and consensus acts on the two
  information pairs separately.

Two more pieces live here:

- :data:`FILTER_REGISTRY`: filters by name.  A factory receives a :class:`FilterContext` (the models, the
  kinematic prior covariance, the lumped prior variance and a seeded generator for filters that need
  randomness) plus its validated parameters, and returns a :class:`LocalFilter` (usable by the batched
  simulator and, wrapped in :class:`~zentrack.fusion.filters.gaussian_node.GaussianNodeFilter`, by one
  tracker) or a :class:`NodeFilter` directly (one tracker only).  Every module file in this package is
  imported when the registry is first used, so a new filter is one new file that calls
  ``FILTER_REGISTRY.register``.
- :class:`NodeFilter`: what one tracker process runs, on typed unbatched estimates
  (:mod:`zentrack.fusion.estimates`) and :class:`~zentrack.fusion.scan.Scan` lists.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..estimates import Estimate, GaussianEstimate
from ..linalg import GaussianState, InformationPair
from ..measurement import MeasurementModel
from ..motion import MotionModel
from ..registry import Registry
from ..scan import Scan

Array = np.ndarray


class LocalFilter(ABC):
    """A predictor/corrector on stacks of Gaussian estimates (see module docstring)."""

    #: dimension of the filter state (may exceed the kinematic dimension)
    state_dim: int
    #: dimension of the kinematic state compared with the truth
    kinematic_dim: int
    name: str = "filter"

    def initial_state(self, mean: Array, cov: Array, lumped_var: float = 1.0) -> GaussianState:
        """Prior at k = 0 from kinematic ``mean`` ``(B, n)`` and covariance ``(n, n)`` or ``(B, n, n)``.

        ``lumped_var`` is the prior variance of augmented components; plain filters have none.
        """
        mean = np.atleast_2d(np.asarray(mean, dtype=float))
        cov = np.broadcast_to(np.asarray(cov, dtype=float), (mean.shape[0],) + (mean.shape[1],) * 2)
        return GaussianState(mean.copy(), cov.copy())

    @abstractmethod
    def update(self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array) -> GaussianState:
        """Correct with stacked measurements ``z`` ``(B, S*m)`` from ``sensors`` ``(B, S, 3)``."""

    @abstractmethod
    def predict(self, state: GaussianState) -> GaussianState:
        """One sample period ahead."""

    def nominal_transition(self) -> Array | None:
        """The kinematic state's nominal linear transition ``(kinematic_dim, kinematic_dim)`` over one period, from
        which an isolated node finds what its measurement cannot observe (:mod:`~zentrack.fusion.isolation`); None
        (the default): the filter's own update whatever the node hears."""
        return None

    def node_filter(self, context: FilterContext) -> NodeFilter | None:
        """How this filter runs in one tracker: a :class:`NodeFilter` of its own, or None for the default
        Gaussian adapter (:class:`~zentrack.fusion.filters.gaussian_node.GaussianNodeFilter`)."""
        return None

    def kinematic(self, state: GaussianState) -> GaussianState:
        n = self.kinematic_dim
        return GaussianState(state.mean[:, :n], state.cov[:, :n, :n])


def nominal_plant_transition(motion: MotionModel) -> Array | None:
    """A plant's linear part ``A`` ``(dim, dim)`` (None for a plant without one): what
    :meth:`LocalFilter.nominal_transition` of a filter on that plant returns."""
    a = getattr(motion, "A", None)
    return None if a is None or np.shape(a) != (motion.dim, motion.dim) else np.asarray(a, dtype=float)


@dataclass(frozen=True)
class FilterContext:
    """What a filter factory gets besides its parameters.

    ``p0`` is the kinematic prior covariance; augmented filters add ``lumped_var`` I for their extra blocks.
    ``rng`` is a seeded generator from the runtime for filters that need randomness (particle filters);
    deterministic filters ignore it.
    """

    motion: MotionModel
    measurement: MeasurementModel | None
    p0: Array
    lumped_var: float = 1.0
    rng: np.random.Generator | None = None

    @classmethod
    def from_scenario(cls, scn: Any, rng: np.random.Generator | None = None) -> FilterContext:
        """The context of a :class:`~zentrack.truth.simulation.scenario.ScenarioData` (anything with its model methods)."""
        return cls(scn.motion_model(), scn.measurement_model(), scn.p0, scn.lumped_var, rng)


#: local filters by name; a factory is ``factory(context: FilterContext, **params) -> LocalFilter | NodeFilter``
FILTER_REGISTRY: Registry[Any] = Registry("local filter", discover=__package__)


class NodeFilter(ABC):
    """The filter of one tracker process, on one unbatched :class:`~zentrack.fusion.estimates.Estimate`.

    One step of a node (paper 0 Algorithm 2, any fusion rule)::

        post = f.update(prior, scans)             # lines 6-7 ([] = coast: the posterior is the prior)
        shared = f.predict(post)                  # line 8
        blocks = f.blocks(shared)                 # line 9: block name -> InformationPair (n, n), (n,)
        fused = rule.combine(...)                 # line 10: block name -> GaussianState batch of one
        prior = f.from_fused(fused, like=shared)
    """

    #: dimension of the filter state (may exceed the kinematic dimension)
    state_dim: int
    #: dimension of the kinematic state compared with the truth
    kinematic_dim: int
    #: the information blocks this filter shares (and gets back fused)
    block_names: tuple[str, ...] = ("state",)
    name: str = "filter"

    @abstractmethod
    def initial(self, x0_mean: Array, rng: np.random.Generator | None = None) -> Estimate:
        """The prior at the first step from the kinematic mean ``x0_mean`` ``(kinematic_dim,)``."""

    @abstractmethod
    def predict(self, est: Estimate) -> Estimate:
        """One sample period ahead."""

    @abstractmethod
    def update(self, est: Estimate, scans: Sequence[Scan]) -> Estimate:
        """Correct with this step's scans (``[]``: coast, the result is ``est``)."""

    def blocks(self, est: Estimate) -> dict[str, InformationPair]:
        """The information blocks to share (unbatched)."""
        return est.information_blocks()

    @abstractmethod
    def from_fused(self, blocks: dict[str, GaussianState], like: Estimate | None) -> Estimate:
        """The estimate after fusion from the fused blocks (each one estimate: ``(1, n)``, or ``(1, 1, n)`` as
        :meth:`~zentrack.fusion.rules.FusionRule.combine` returns it for one receiver).

        ``like`` is the estimate that was shared, for what fusion does not carry (e.g. particles to resample);
        None when the node had none (a restarted node warm-starting from its neighbours).
        """

    def kinematic(self, est: Estimate) -> GaussianEstimate:
        return est.kinematic()

    def diagnostics(self, est: Estimate) -> dict[str, Array]:
        """What the tracker publishes beside its estimate for viewers (e.g. ``samples``: a subsample of a
        particle cloud's kinematic part; ``beta``: the association probability of each return of the last
        scan). Plain filters have none."""
        return {}
