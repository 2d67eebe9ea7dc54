"""Bootstrap particle filter with the PDA likelihood (comparator for paper 1), ``"pda-pf"``.

Prediction as the PDA-FPF (Euler–Maruyama with the motion's process noise).  Update: the same gate
(``S = R + cov(h_i)`` around the predicted mean measurement) and the PDA measurement likelihood of each
particle (Bar-Shalom & Fortmann 1988 eq. 6.4.1-type; Gordon, Salmond & Smith 1993 for the bootstrap filter):

    w_i  proportional to  b + P_D sum_{j in gate} N(y_j; h(X_i), R),     b = lambda (1 - P_D P_G),

then systematic resampling to N equal weights.  The exported summary is the weighted mean and covariance
before resampling; the returned cloud is the resampled one.  beta (diagnostics) is computed as for the
PDA-FPF from the predicted cloud.  A scan without gated returns leaves the cloud untouched.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

from ..linalg import GaussianState, symmetrize
from ..measurement import MeasurementModel
from ..motion import MotionModel
from .base import FILTER_REGISTRY, FilterContext
from .pda_common import ParticleClutterFilter, ParticleState, context_models, particle_params, summarize

Array = np.ndarray


def systematic_resample(weights: Array, rng: np.random.Generator) -> Array:
    """Indices ``(B, N)`` of systematic resampling of normalised ``weights`` ``(B, N)`` (one uniform per row)."""
    b, n = weights.shape
    cw = np.cumsum(weights, axis=1)
    cw /= cw[:, -1:]
    offsets = np.arange(b)[:, None]
    u = (rng.random((b, 1)) + np.arange(n)[None, :]) / n
    idx = np.searchsorted((cw + offsets).ravel(), (u + offsets).ravel(), side="right").reshape(b, n)
    return np.minimum(idx - offsets * n, n - 1)


class PdaBootstrapParticleFilter(ParticleClutterFilter):
    """SIR particle filter with the PDA likelihood and systematic resampling at every scan."""

    name = "pda-pf"

    def __init__(
        self,
        motion: MotionModel,
        measurement: MeasurementModel,
        particles: int = 1000,
        rng: np.random.Generator | None = None,
        **clutter: float | None,
    ) -> None:
        super().__init__(motion, measurement, particles, rng, **clutter)

    def update_batch(
        self, state: GaussianState, z: Array, valid: Array, sensors: Array, noise_cov: Array
    ) -> GaussianState:
        particles = self.cloud(state)
        if z.shape[1] == 0 or not np.any(valid):
            self.last_association = None
            return state if isinstance(state, ParticleState) else summarize(particles)
        _, s, gated, log_l, log_avg = self.particle_likelihoods(particles, z, valid, sensors, noise_cov)
        assoc = self.associate(log_avg, gated, s)
        active = np.any(gated, axis=1)
        if not np.any(active):
            return state if isinstance(state, ParticleState) else summarize(particles)
        # log w_i = log(b + P_D sum_j N(y_j; h(X_i), R)) over the gated returns (members with one at least)
        x, g, ll = particles[active], gated[active], log_l[active]
        with np.errstate(divide="ignore"):
            log_e = np.where(g[:, None, :], math.log(self.p_d) + ll, -np.inf)
            log_b = np.log(np.maximum(assoc.clutter[active], 0.0))[:, None, None]
        log_w = logsumexp(np.concatenate([np.broadcast_to(log_b, log_e.shape[:2] + (1,)), log_e], axis=2), axis=2)
        w = np.exp(log_w - log_w.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        mean = np.einsum("bn,bni->bi", w, x)
        d = x - mean[:, None, :]
        cov = symmetrize(np.swapaxes(d * w[:, :, None], 1, 2) @ d)
        resampled = np.take_along_axis(x, systematic_resample(w, self.rng)[:, :, None], axis=1)
        # members without a gated return keep their predicted cloud and its moments
        out = summarize(particles.copy())
        out.particles[active] = resampled
        out.mean[active] = mean
        out.cov[active] = cov
        return out


def _pda_pf(context: FilterContext, gate: float, detection_prob: float, clutter_density: float | None,
            particles: int) -> PdaBootstrapParticleFilter:
    motion, measurement = context_models(context)
    return PdaBootstrapParticleFilter(
        motion, measurement, particles, context.rng,
        gate=gate, detection_prob=detection_prob, clutter_density=clutter_density,
    )


FILTER_REGISTRY.register(
    "pda-pf", _pda_pf, particle_params(1000),
    "bootstrap particle filter with the PDA likelihood and systematic resampling (paper 1 comparator)",
    tags=("scans",),
)
