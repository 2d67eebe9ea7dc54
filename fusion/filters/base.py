"""The local-filter interface every tracker node runs, and how later filters plug into it.

A local filter works on a stack of estimates (:class:`~zentrack.fusion.linalg.GaussianState`, ``(B, n)``
means and ``(B, n, n)`` covariances) so that one node, every node of a network, or every node of many Monte
Carlo runs step through the same code.  One step of a diffusion node (seed 000 Algorithm 2) is::

    state = filt.update(prior, z, sensors, noise_cov)   # local correction, lines 6-7
    shared = filt.predict(state)                        # local time update, line 8
    pair = to_information(shared)                       # broadcast, line 9
    prior = fusion_rule(pairs from neighbours)          # CI diffusion, line 10

``kinematic(state)`` returns the part of the state that is compared with the truth (position/velocity),
so augmented filters (extended states, extents) are scored like plain ones.

How the later seeds fit this interface:

- **Particle filter in clutter (seed 001, PDA-FPF)**: the "state" keeps particles internally; ``update``
  receives every return of the scan in ``z`` (validation gate and association probabilities inside);
  the exported Gaussian is the particle mean and sample covariance, so ``to_information`` and any fusion
  rule apply unchanged.
- **Square-root cubature information filter (seed 002)**: ``update`` takes the stacked measurements of the
  node and its neighbours with a ``sensors`` array of shape ``(B, S, 3)`` (S > 1), exactly like the
  centralized filters here; the square-root factor is an internal detail and ``predict`` exports the usual
  Gaussian. Its inverse-CI fusion rule is another function beside ``ci_fuse``.
- **Secant Kalman filter (seed 003)**: an :class:`ExtendedKalmanFilter` whose ``update`` replaces Jacobian
  elements by secant slopes between the prediction and a first EKF estimate; same signature.
- **Extended-object information filter (seed 004)**: the state is the kinematic block plus a separate
  extent block ``[alpha, l1, l2]``; ``kinematic`` returns the first block, ``update`` processes point
  measurements sequentially with the pseudo-measurement for the extent, and consensus acts on the two
  information pairs separately.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ..linalg import GaussianState

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

    def kinematic(self, state: GaussianState) -> GaussianState:
        n = self.kinematic_dim
        return GaussianState(state.mean[:, :n], state.cov[:, :n, :n])
