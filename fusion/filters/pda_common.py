"""Shared building blocks of the clutter filters (paper 1): scans, gate, association probabilities, particles,
and :class:`ClutterNodeFilter`, the clutter filter of one tracker process (end of this module).

**Update signature for ragged scans.**  Every clutter filter is a :class:`ClutterFilter`, a
:class:`~zentrack.fusion.filters.base.LocalFilter` whose update takes one optional argument more::

    update(state, z, sensors, noise_cov, counts=None)

- ``z`` ``(B, Jmax, m)``: the returns of each batch member's scan, padded to the longest (padding is
  ignored, its value does not matter); ``counts`` ``(B,)`` the number J_b of valid returns (J_b = 0: a
  look without returns, the predicted estimate is returned unchanged).  ``counts=None``: all Jmax valid.
- ``z`` ``(B, m)`` (the plain LocalFilter contract) is one return per member, so a clutter filter runs
  unchanged wherever a point-target filter runs (no clutter, one detection).
- ``sensors`` ``(B, 1, 3)``: one sensor per scan; ``noise_cov`` ``(B, m, m)`` or ``(m, m)``.

:meth:`ClutterFilter.update_scan` does the same for one :class:`~zentrack.fusion.scan.Scan` (batch of one).
:func:`pad_scans` turns a list of ``(J, m)`` arrays into ``z`` and ``counts``; padded scans of a whole
Monte Carlo study come from :meth:`zentrack.truth.simulation.clutter.ClutterScans.batch`.

**Particle states.**  The particle filters return a :class:`ParticleState`: a
:class:`~zentrack.fusion.linalg.GaussianState` (the particle mean and sample covariance, paper 1
eq. for the local summary, so ``to_information`` and every fusion rule apply unchanged) that also carries the
cloud ``particles`` ``(B, N, n)``.  A plain GaussianState given to a particle filter (an initial prior, or a
fused estimate without a cloud) is sampled into N particles with the filter's generator.

**Feeding a fused Gaussian back (re-seeding).**  :func:`reseed_cloud` moves a cloud so that its mean and
covariance equal a fused prior ``(m_f, P_f)`` while keeping its shape:

    x_i' = m_f + L_f L_p^-1 (x_i - m_p),     P_p = L_p L_p^T, P_f = L_f L_f^T (Cholesky),

``m_p``, ``P_p`` the cloud's own mean and (1/N) sample covariance, so the new cloud's sample moments are
exactly ``(m_f, P_f)``.  A degenerate cloud (P_p not positive definite) is replaced by N fresh samples of
N(m_f, P_f).  :meth:`ParticleClutterFilter.adopt` applies it; the seed-001 architecture itself is
feed-forward (the fusion centre does not feed back), so this is only used by runtimes that do feed back.

**Association probabilities** (PDAF, Bar-Shalom & Fortmann 1988 Sec. 6.4; paper 1 Sec. 3.2 and
Algorithm 2): for gated returns j with target likelihood ``l_j = p(y_j | target)`` (particle average for the
particle filters, ``N(nu_j; 0, S)`` for the PDAF-EKF),

    beta_j = P_D l_j / (b + sum_i P_D l_i),   beta_0 = b / (b + sum_i P_D l_i),   b = lambda (1 - P_D P_G),

``lambda`` the clutter density per unit measurement volume (rad^2 for bearings; parametric PDA) or, when
not given, ``m_k / V_gate`` (the non-parametric PDA, m_k the number of gated returns).  A return outside
the gate gets beta = 0; beta_0 is the probability that none of the returns is the target.  With P_D = 1 and
lambda = 0 this is the paper's particle formula ``beta_m = sum_i L_m(X_i) / sum_j sum_i L_j(X_i)``.
The gate is ``d^2 = nu^T S^-1 nu <= gamma`` around the predicted measurement (paper 1 Sec. 5.2),
``P_G`` the chi-square probability of that gate.
"""
from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import gammainc, logsumexp

from ..estimates import Estimate, GaussianEstimate, ParticleEstimate
from ..gate import gate_volume, mahalanobis2
from ..linalg import GaussianState, lower_triangular_inverse, symmetrize
from ..measurement import MeasurementModel
from ..motion import MotionModel
from ..registry import Param
from ..scan import Scan
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, NodeFilter

Array = np.ndarray


# --------------------------------------------------------------------------------------------- scans
def as_scan_batch(z: Array, counts: Array | None = None) -> tuple[Array, Array]:
    """``z`` as ``(B, J, m)`` and the ``(B, J)`` mask of valid returns (see the module docstring)."""
    z = np.asarray(z, dtype=float)
    if z.ndim == 2:
        z = z[:, None, :]
    if z.ndim != 3:
        raise ValueError(f"z: expected (B, m) or (B, Jmax, m), got shape {z.shape}")
    b, jmax, _ = z.shape
    if counts is None:
        return z, np.ones((b, jmax), dtype=bool)
    counts = np.asarray(counts)
    if counts.shape != (b,) or np.any(counts < 0) or np.any(counts > jmax):
        raise ValueError(f"counts: expected ({b},) integers in [0, {jmax}], got {counts}")
    return z, np.arange(jmax)[None, :] < counts[:, None]


def compress_gated(z: Array, beta: Array, gated: Array) -> tuple[Array, Array]:
    """The gated returns moved to the front and the rest cut: ``z`` ``(B, Jg, m)``, ``beta`` ``(B, Jg)``,
    Jg the largest gated count (the flow and the PF weights only involve gated returns)."""
    order = np.argsort(~gated, axis=1, kind="stable")
    jg = int(gated.sum(axis=1).max(initial=0))
    idx = order[:, :jg]
    return np.take_along_axis(z, idx[:, :, None], axis=1), np.take_along_axis(beta, idx, axis=1)


def pad_scans(scans: Sequence[Array], m: int = 2) -> tuple[Array, Array]:
    """Stack ``(J_b, m)`` arrays into padded ``z`` ``(B, Jmax, m)`` (padding 0) and ``counts`` ``(B,)``."""
    counts = np.array([np.shape(s)[0] for s in scans], dtype=int)
    z = np.zeros((len(scans), int(counts.max(initial=0)), m))
    for b, s in enumerate(scans):
        z[b, : counts[b]] = s
    return z, counts


# ------------------------------------------------------------------------------------ gate and beta
def gate_probability(gamma: float, m: int = 2) -> float:
    """P_G: probability that the target's return falls in the gate ``d^2 <= gamma`` (chi-square, m dof)."""
    return float(gammainc(m / 2.0, gamma / 2.0))  # chi-square CDF with m degrees of freedom


def gate(innov: Array, s_inv: Array, valid: Array, gamma: float) -> Array:
    """The ``(B, J)`` mask of valid returns inside the validation gate (paper 1 Sec. 5.2)."""
    return valid & (mahalanobis2(innov, s_inv) <= gamma)


def gaussian_log_density(innov: Array, cov_inv: Array, log_det_cov: Array) -> Array:
    """``log N(nu; 0, C)`` for ``nu`` ``(B, ..., m)``, ``C^-1`` ``(B, m, m)``, ``log det C`` ``(B,)``."""
    m = innov.shape[-1]
    flat = innov.reshape(innov.shape[0], -1, m)
    d2 = ((flat @ cov_inv) * flat).sum(axis=-1).reshape(innov.shape[:-1])
    extra = (1,) * (innov.ndim - 2)
    return -0.5 * d2 - 0.5 * (m * math.log(2.0 * math.pi) + log_det_cov.reshape((-1,) + extra))


@dataclass
class Association:
    """Association probabilities of one update: ``beta`` ``(B, J)`` (0 outside the gate), ``beta0`` ``(B,)``,
    ``gated`` ``(B, J)`` mask and the clutter term ``b`` ``(B,)`` they used (the paper's Figs. 2-4 plot beta
    of the true return)."""

    beta: Array
    beta0: Array
    gated: Array
    clutter: Array


def clutter_term(
    gated: Array, p_d: float, p_g: float, density: float | None, innov_cov: Array, gamma: float
) -> Array:
    """``b = lambda (1 - P_D P_G)`` ``(B,)``; ``density=None``: ``lambda = m_k / V_gate`` (non-parametric PDA)."""
    if density is None:
        lam = gated.sum(axis=1) / gate_volume(innov_cov, gamma)
    else:
        lam = np.full(gated.shape[0], float(density))
    return lam * (1.0 - p_d * p_g)


def pda_betas(log_lik: Array, gated: Array, p_d: float, clutter: Array) -> Association:
    """Association probabilities from the target log-likelihoods ``log l_j`` ``(B, J)`` of the returns, the gate
    mask and the clutter term ``b`` ``(B,)`` of :func:`clutter_term` (module docstring; paper 1 Sec. 3.2).

    Computed in log space; a batch member with no gated return (or b > 0 and every likelihood zero) has
    beta_0 = 1.
    """
    with np.errstate(divide="ignore"):
        log_e = np.where(gated, math.log(p_d) + log_lik if p_d > 0 else -np.inf, -np.inf)
        log_b = np.log(np.maximum(clutter, 0.0))
    log_all = np.concatenate([log_b[:, None], log_e], axis=1)
    log_norm = logsumexp(log_all, axis=1, keepdims=True)
    none = ~np.isfinite(log_norm[:, 0])
    log_norm = np.where(np.isfinite(log_norm), log_norm, 0.0)
    probs = np.exp(log_all - log_norm)
    probs[none] = 0.0
    probs[none, 0] = 1.0
    return Association(probs[:, 1:], probs[:, 0], gated, np.asarray(clutter, dtype=float))


# ------------------------------------------------------------------------------------------ particles
@dataclass
class ParticleState(GaussianState):
    """A particle filter's state: the Gaussian summary (``mean`` ``(B, n)``, ``cov`` ``(B, n, n)``) and the
    equally weighted cloud ``particles`` ``(B, N, n)``."""

    particles: Array

    def copy(self) -> ParticleState:
        return ParticleState(self.mean.copy(), self.cov.copy(), self.particles.copy())


def particle_moments(particles: Array) -> tuple[Array, Array]:
    """Mean ``(B, n)`` and (1/N) sample covariance ``(B, n, n)`` of a cloud ``(B, N, n)``
    (paper 1 Sec. 4.1: local estimate and sample covariance)."""
    mean = particles.mean(axis=1)
    d = particles - mean[:, None, :]
    cov = np.swapaxes(d, 1, 2) @ d / particles.shape[1]
    return mean, symmetrize(cov)


def summarize(particles: Array) -> ParticleState:
    """The :class:`ParticleState` of a cloud (its moments as the Gaussian summary)."""
    mean, cov = particle_moments(particles)
    return ParticleState(mean, cov, particles)


def sample_gaussian(mean: Array, cov: Array, count: int, rng: np.random.Generator) -> Array:
    """``count`` samples of N(mean_b, cov_b) per batch member: ``(B, count, n)``."""
    chol = np.linalg.cholesky(symmetrize(cov))
    xi = rng.standard_normal((mean.shape[0], count, mean.shape[1]))
    return mean[:, None, :] + xi @ np.swapaxes(chol, 1, 2)


def reseed_cloud(particles: Array, mean: Array, cov: Array, rng: np.random.Generator | None = None) -> Array:
    """Affine map of a cloud onto the Gaussian ``(mean, cov)``: ``x' = m_f + L_f L_p^-1 (x - m_p)``.

    ``particles`` ``(B, N, n)``, ``mean`` ``(B, n)``, ``cov`` ``(B, n, n)``.  The result's sample mean and
    (1/N) covariance equal ``mean`` and ``cov``.  Members whose cloud covariance is not positive definite are
    re-sampled from N(mean, cov) (needs ``rng``).
    """
    m_p, p_p = particle_moments(particles)
    l_f = np.linalg.cholesky(symmetrize(cov))
    scale = np.maximum(np.abs(np.diagonal(p_p, axis1=1, axis2=2)).max(axis=1), 1e-300)
    ok = np.linalg.eigvalsh(p_p)[:, 0] > 1e-12 * scale
    out = np.empty_like(particles)
    if np.any(ok):
        l_p = np.linalg.cholesky(p_p[ok])
        t = l_f[ok] @ lower_triangular_inverse(l_p)
        out[ok] = mean[ok, None, :] + (particles[ok] - m_p[ok, None, :]) @ np.swapaxes(t, 1, 2)
    if not np.all(ok):
        if rng is None:
            raise ValueError("reseed_cloud: a degenerate cloud needs a generator to re-sample")
        out[~ok] = sample_gaussian(mean[~ok], cov[~ok], particles.shape[1], rng)
    return out


def propagate_particles(motion: MotionModel, particles: Array, rng: np.random.Generator) -> Array:
    """One scan period ahead: Euler–Maruyama when the model is continuous-time (has ``euler_maruyama``,
    e.g. :class:`~zentrack.fusion.motion_cd.ContinuousCV3D`; paper 1 Algorithm 3 prediction), otherwise
    ``f(x) + w``, ``w ~ N(0, Q)``."""
    em = getattr(motion, "euler_maruyama", None)
    if em is not None:
        out: Array = em(particles, rng)
        return out
    b, count, n = particles.shape
    x = motion.f(particles.reshape(b * count, n)).reshape(b, count, n)
    chol = np.linalg.cholesky(motion.Q)
    return x + rng.standard_normal(x.shape) @ chol.T


def predict_particle_measurements(measurement: MeasurementModel, particles: Array, sensors: Array) -> Array:
    """``h(X_i)`` for a cloud ``(B, N, n)`` seen from ``sensors`` ``(B, 1, 3)`` -> ``(B, N, m)``."""
    b, count, n = particles.shape
    flat_sensors = np.repeat(np.asarray(sensors, dtype=float), count, axis=0)
    return measurement.h(particles.reshape(b * count, n), flat_sensors).reshape(b, count, -1)


def measurement_mean(measurement: MeasurementModel, h: Array) -> tuple[Array, Array]:
    """``hbar`` ``(B, m)`` and the wrapped deviations ``h_i - hbar`` ``(B, N, m)`` of predicted measurements
    ``(B, N, m)`` (angles averaged as wrapped residuals around the first particle's)."""
    ref = h[:, 0, :]
    hbar = ref + measurement.residual(h, ref[:, None, :]).mean(axis=1)
    return hbar, measurement.residual(h, hbar[:, None, :])


# ----------------------------------------------------------------------------------- the interfaces
CLUTTER_PARAMS = (
    Param("gate", float, 16.0, lo=0.0, lo_open=True,
          help="validation gate threshold gamma on the squared Mahalanobis distance (chi-square, m dof)"),
    Param("detection_prob", float, 1.0, lo=0.0, hi=1.0, lo_open=True, help="P_D of the target"),
    Param("clutter_density", float, None, lo=0.0,
          help="clutter returns per unit measurement volume (rad^2); None: gated count / gate volume"),
)


class ClutterFilter(LocalFilter):
    """A local filter whose update takes every return of a scan (module docstring: the ragged signature).

    ``last_association`` holds the association probabilities of the latest update (diagnostics).
    """

    def __init__(
        self,
        motion: MotionModel,
        measurement: MeasurementModel,
        gate: float = 16.0,
        detection_prob: float = 1.0,
        clutter_density: float | None = None,
    ) -> None:
        self.motion = motion
        self.measurement = measurement
        self.state_dim = self.kinematic_dim = motion.dim
        self.gamma = float(gate)
        self.p_d = float(detection_prob)
        self.density = clutter_density
        self.p_g = gate_probability(self.gamma, measurement.dim)
        self.last_association: Association | None = None

    def update(
        self, state: GaussianState, z: Array, sensors: Array, noise_cov: Array, counts: Array | None = None
    ) -> GaussianState:
        """Correct with the scans ``z`` ``(B, Jmax, m)`` (or ``(B, m)``) and ``counts`` ``(B,)``."""
        zz, valid = as_scan_batch(z, counts)
        b, _, m = zz.shape
        noise = np.broadcast_to(np.asarray(noise_cov, dtype=float), (b, m, m))
        return self.update_batch(state, zz, valid, np.asarray(sensors, dtype=float), noise)

    @abstractmethod
    def update_batch(
        self, state: GaussianState, z: Array, valid: Array, sensors: Array, noise_cov: Array
    ) -> GaussianState:
        """The update on ``z`` ``(B, J, m)`` with the valid mask ``(B, J)`` and ``noise_cov`` ``(B, m, m)``."""

    def node_filter(self, context: FilterContext) -> NodeFilter | None:
        """In one tracker: :class:`ClutterNodeFilter` (every return of a
        scan, the particle cloud kept between steps and moved onto each fused prior)."""
        return ClutterNodeFilter(self, context.p0)

    def update_scan(self, state: GaussianState, scan: Scan) -> GaussianState:
        """Correct a batch of one with one :class:`~zentrack.fusion.scan.Scan` (J >= 0 returns)."""
        return self.update(state, scan.returns[None], scan.pose[None, None, :], scan.noise_cov[None])

    def associate(self, log_lik: Array, gated: Array, innov_cov: Array) -> Association:
        """beta and beta_0 from target log-likelihoods ``(B, J)``, the gate mask and ``S`` ``(B, m, m)``."""
        m = innov_cov.shape[-1]
        p_g = self.p_g if m == self.measurement.dim else gate_probability(self.gamma, m)  # stacked sensors
        clutter = clutter_term(gated, self.p_d, p_g, self.density, innov_cov, self.gamma)
        assoc = pda_betas(log_lik, gated, self.p_d, clutter)
        self.last_association = assoc
        return assoc


class ParticleClutterFilter(ClutterFilter):
    """A clutter filter on an equally weighted particle cloud (:class:`ParticleState`)."""

    def __init__(
        self,
        motion: MotionModel,
        measurement: MeasurementModel,
        particles: int = 500,
        rng: np.random.Generator | None = None,
        **clutter: float | None,
    ) -> None:
        super().__init__(motion, measurement, **clutter)  # type: ignore[arg-type]
        if particles < 2:
            raise ValueError(f"particles must be >= 2, got {particles}")
        self.count = int(particles)
        #: the generator of every draw (initial cloud, process noise, resampling); seeded 0 when none is given
        self.rng = rng if rng is not None else np.random.default_rng(0)

    def cloud(self, state: GaussianState) -> Array:
        """The state's particles, or N samples of its Gaussian when it carries none."""
        if isinstance(state, ParticleState):
            return state.particles
        return sample_gaussian(state.mean, state.cov, self.count, self.rng)

    def initial_state(self, mean: Array, cov: Array, lumped_var: float = 1.0) -> ParticleState:
        """N particles of N(mean_b, cov) per batch member (paper 1 Sec. 5.3: drawn around a biased mean)."""
        base = super().initial_state(mean, cov, lumped_var)
        return summarize(sample_gaussian(base.mean, base.cov, self.count, self.rng))

    def predict(self, state: GaussianState) -> ParticleState:
        """Euler–Maruyama propagation of every particle over one scan period (paper 1 Algorithm 3)."""
        return summarize(propagate_particles(self.motion, self.cloud(state), self.rng))

    def adopt(self, fused: GaussianState, like: GaussianState | None = None) -> ParticleState:
        """The fused Gaussian as a particle state: ``like``'s cloud moved onto it by :func:`reseed_cloud`
        (fresh samples when ``like`` carries no cloud)."""
        if isinstance(like, ParticleState):
            return summarize(reseed_cloud(like.particles, fused.mean, fused.cov, self.rng))
        return summarize(sample_gaussian(fused.mean, fused.cov, self.count, self.rng))

    def particle_likelihoods(
        self, particles: Array, z: Array, valid: Array, sensors: Array, noise_cov: Array
    ) -> tuple[Array, Array, Array, Array, Array]:
        """Shared first half of the particle updates.

        Returns ``h`` ``(B, N, m)``, ``S`` ``(B, m, m)`` (``R + cov(h_i)``), the gate mask ``(B, J)``, the
        per-particle log-likelihoods ``log N(y_j; h(X_i), R)`` ``(B, N, J)`` and the particle-averaged target
        log-likelihood ``log (1/N) sum_i N(y_j; h(X_i), R)`` ``(B, J)`` (paper 1 Algorithm 2).
        """
        h = predict_particle_measurements(self.measurement, particles, sensors)
        hbar, dh = measurement_mean(self.measurement, h)
        s = noise_cov + np.swapaxes(dh, 1, 2) @ dh / particles.shape[1]
        innov_bar = self.measurement.residual(z, hbar[:, None, :])
        gated = gate(innov_bar, np.linalg.inv(s), valid, self.gamma)
        r_inv = np.linalg.inv(noise_cov)
        log_det_r = np.linalg.slogdet(noise_cov)[1]
        innov = self.measurement.residual(z[:, None, :, :], h[:, :, None, :])  # (B, N, J, m)
        log_l = gaussian_log_density(innov, r_inv, log_det_r)  # (B, N, J)
        log_avg = logsumexp(log_l, axis=1) - math.log(particles.shape[1])
        return h, s, gated, log_l, log_avg


def particle_params(default_count: int) -> tuple[Param, ...]:
    """The registry parameters of a particle clutter filter: the clutter ones and ``particles``."""
    return CLUTTER_PARAMS + (Param("particles", int, default_count, lo=2, help="number of particles N"),)


def context_models(context: FilterContext) -> tuple[MotionModel, MeasurementModel]:
    """The context's models (a clutter filter needs a measurement model)."""
    if context.measurement is None:
        raise ValueError("a clutter filter needs a measurement model in its FilterContext")
    return context.motion, context.measurement


# --------------------------------------------------------------------------------------------------------
# One tracker process running a clutter filter (paper 1): :class:`ClutterNodeFilter`.
#
# :func:`~zentrack.fusion.filters.gaussian_node.make_node_filter` wraps a batched LocalFilter in a
# GaussianNodeFilter, which takes at most one return per scan and keeps no particles; a
# :class:`~zentrack.fusion.filters.pda_common.ClutterFilter` needs this wrapper instead
# (:func:`make_clutter_node_filter`, or ``ClutterNodeFilter(built, context.p0)``):
#
# - ``update(est, scans)``: every scan in turn (J >= 0 returns each, :meth:`ClutterFilter.update_scan`);
#   ``[]`` coasts;
# - estimates: a :class:`~zentrack.fusion.estimates.ParticleEstimate` (equal weights) for the particle filters,
#   a :class:`~zentrack.fusion.estimates.GaussianEstimate` for the PDAF-EKF and NN-EKF; either shares its
#   Gaussian summary for fusion;
# - ``from_fused(blocks, like)``: the fused Gaussian; a particle filter moves ``like``'s cloud onto it
#   (:func:`~zentrack.fusion.filters.pda_common.reseed_cloud`), or samples it when there is no ``like``.

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
