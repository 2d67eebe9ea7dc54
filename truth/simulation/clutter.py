"""Bearing scans in clutter (paper 1 Section 2.2): target returns with P_D plus uniform clutter.

Per run r, step k and sensor i, a scan holds the target's return with probability ``p_d``
(``z = h(x) + v``, ``h`` the bearing model of :mod:`~zentrack.fusion.measurement`, ``v ~ N(0, R)``, azimuth
wrapped to (-pi, pi]) and clutter returns drawn uniformly over an (azimuth, elevation) window:

- ``"fixed"``: exactly ``count`` clutter returns per scan (the paper: a fixed clutter cardinality, P_D = 1);
- ``"poisson"``: Poisson(``density`` * window area) returns, ``density`` in returns per rad^2.

The returns of a scan are shuffled, so the target's return is not recognisable by its position; its index
is kept in :attr:`ClutterScans.target_index` (-1: missed) for evaluation only (association probability of
the true return, paper Figs. 2-4), never for filters.

Scans are ragged: :class:`ClutterScans` stores them padded, ``returns`` ``(R, K, M, Jmax, 2)`` (padding is
0) and ``counts`` ``(R, K, M)``; :meth:`ClutterScans.scan` gives one scan's ``(J, 2)`` array and
:meth:`ClutterScans.batch` step k of every run and sensor flattened to the ``(R*M, Jmax, 2)``, ``(R*M,)``
layout the clutter filters take (batch index ``r*M + i``, as ``truth`` and node stacks elsewhere).

The gate's volume and the clutter expected in it (what a clutter filter computes) are in
:mod:`zentrack.fusion.gate` (:func:`~zentrack.fusion.gate.gate_volume`,
:func:`~zentrack.fusion.gate.expected_gate_clutter`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zentrack.fusion.measurement import bearing, wrap_angle

Array = np.ndarray

CLUTTER_MODES = ("fixed", "poisson")


@dataclass(frozen=True)
class ClutterSpec:
    """Detection and clutter of every sensor.

    ``az_window``/``el_window`` are ``(lo, hi)`` in radians, one pair shared by every sensor ``(2,)`` or one
    per sensor ``(M, 2)``.  ``count`` is used by ``mode="fixed"``, ``density`` (per rad^2) by ``"poisson"``.
    """

    p_d: float = 1.0
    mode: str = "fixed"
    count: int = 0
    density: float = 0.0
    az_window: Array = field(default_factory=lambda: np.array([-np.pi, np.pi]))
    el_window: Array = field(default_factory=lambda: np.array([-np.pi / 2, np.pi / 2]))

    def __post_init__(self) -> None:
        if self.mode not in CLUTTER_MODES:
            raise ValueError(f"mode must be one of {CLUTTER_MODES}, got {self.mode!r}")
        if not 0.0 <= self.p_d <= 1.0:
            raise ValueError(f"p_d must be in [0, 1], got {self.p_d}")
        if self.count < 0 or not self.density >= 0:
            raise ValueError(f"count and density must be non-negative, got {self.count}, {self.density}")
        for key in ("az_window", "el_window"):
            w = np.asarray(getattr(self, key), dtype=float)
            if w.shape[-1] != 2 or w.ndim > 2 or np.any(w[..., 1] <= w[..., 0]):
                raise ValueError(f"{key}: expected (lo, hi) pairs with lo < hi, shape (2,) or (M, 2), got {w}")
            object.__setattr__(self, key, w)

    def windows(self, sensors: int) -> tuple[Array, Array]:
        """Azimuth and elevation windows per sensor, each ``(M, 2)``."""
        return (np.broadcast_to(self.az_window, (sensors, 2)), np.broadcast_to(self.el_window, (sensors, 2)))

    def area(self, sensors: int) -> Array:
        """Window area per sensor ``(M,)`` in rad^2."""
        az, el = self.windows(sensors)
        return (az[:, 1] - az[:, 0]) * (el[:, 1] - el[:, 0])

    def clutter_density(self, sensors: int) -> Array:
        """Spatial clutter density per sensor ``(M,)`` in returns per rad^2 (``count / area`` when fixed)."""
        if self.mode == "fixed":
            return self.count / self.area(sensors)
        return np.full(sensors, self.density)

    def mean_clutter(self, sensors: int) -> Array:
        """Expected clutter returns per scan and sensor ``(M,)``."""
        if self.mode == "fixed":
            return np.full(sensors, float(self.count))
        return self.density * self.area(sensors)


@dataclass
class ClutterScans:
    """Ragged scans, padded: ``returns`` ``(R, K, M, Jmax, 2)``, ``counts`` ``(R, K, M)``, ``target_index``
    ``(R, K, M)`` (position of the target's return in the scan, -1 when missed; evaluation only)."""

    returns: Array
    counts: Array
    target_index: Array

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(R, K, M)``: runs, steps, sensors."""
        r, k, m = self.counts.shape
        return r, k, m

    def scan(self, run: int, step: int, sensor: int) -> Array:
        """The ``(J, 2)`` returns of one scan (a copy)."""
        j = int(self.counts[run, step, sensor])
        return self.returns[run, step, sensor, :j].copy()

    def batch(self, step: int) -> tuple[Array, Array]:
        """Step ``step`` of every run and sensor: ``(R*M, Jmax, 2)`` returns and ``(R*M,)`` counts."""
        r, _, m = self.shape
        jmax = self.returns.shape[3]
        return self.returns[:, step].reshape(r * m, jmax, 2), self.counts[:, step].reshape(r * m)


def generate_clutter_scans(
    truth: Array,
    sensors: Array,
    noise_cov: Array,
    spec: ClutterSpec,
    rng: np.random.Generator | int,
) -> ClutterScans:
    """Scans of every run, step and sensor (see the module docstring).

    ``truth`` ``(R, K, n)`` (position first), ``sensors`` ``(M, 3)``, ``noise_cov`` ``(2, 2)``.  ``rng`` is a
    generator, or an int seed: then run r draws from its own child of ``SeedSequence(seed)``, so run r's
    scans are identical whatever R is.
    """
    truth = np.asarray(truth, dtype=float)
    sensors = np.asarray(sensors, dtype=float)
    r_runs, k_steps, _ = truth.shape
    m_sens = sensors.shape[0]
    chol = np.linalg.cholesky(np.asarray(noise_cov, dtype=float))
    if isinstance(rng, (int, np.integer)):
        gens = [np.random.default_rng(c) for c in np.random.SeedSequence(int(rng)).spawn(r_runs)]
        parts = [_generate(truth[r : r + 1], sensors, chol, spec, g) for r, g in enumerate(gens)]
        jmax = max(p.returns.shape[3] for p in parts)
        returns = np.zeros((r_runs, k_steps, m_sens, jmax, 2))
        for r, p in enumerate(parts):
            returns[r, :, :, : p.returns.shape[3]] = p.returns[0]
        return ClutterScans(
            returns, np.concatenate([p.counts for p in parts]), np.concatenate([p.target_index for p in parts])
        )
    return _generate(truth, sensors, chol, spec, rng)


def _generate(truth: Array, sensors: Array, chol: Array, spec: ClutterSpec, rng: np.random.Generator) -> ClutterScans:
    r_runs, k_steps, n = truth.shape
    m_sens = sensors.shape[0]
    shape = (r_runs, k_steps, m_sens)
    # target returns: h(x) + v (paper 1 eq. for the target measurement; noise convention of measurement.py)
    flat = truth.reshape(-1, n)
    z_true = bearing(flat, np.broadcast_to(sensors, (flat.shape[0], m_sens, 3))).reshape(shape + (2,))
    z_true = z_true + rng.standard_normal(shape + (2,)) @ chol.T
    z_true[..., 0] = wrap_angle(z_true[..., 0])
    detected = rng.random(shape) < spec.p_d
    if spec.mode == "fixed":
        n_clutter = np.full(shape, spec.count, dtype=int)
    else:
        n_clutter = rng.poisson(np.broadcast_to(spec.mean_clutter(m_sens), shape))
    counts = n_clutter + detected
    jmax = int(counts.max(initial=0))
    returns = np.zeros(shape + (jmax, 2))
    target_index = np.full(shape, -1, dtype=int)
    if jmax == 0:
        return ClutterScans(returns, counts, target_index)
    az_w, el_w = spec.windows(m_sens)
    u = rng.random(shape + (jmax, 2))
    clutter = np.empty_like(u)
    clutter[..., 0] = wrap_angle(az_w[:, None, 0] + u[..., 0] * (az_w[:, None, 1] - az_w[:, None, 0]))
    clutter[..., 1] = el_w[:, None, 0] + u[..., 1] * (el_w[:, None, 1] - el_w[:, None, 0])
    # a random slot among the first J for the target; clutter fills the other valid slots
    slot = np.floor(rng.random(shape) * np.maximum(counts, 1)).astype(int)
    target_index = np.where(detected, slot, -1)
    j = np.arange(jmax)
    valid = j < counts[..., None]
    is_target = j == target_index[..., None]
    returns = np.where(is_target[..., None], z_true[..., None, :], clutter)
    returns = np.where(valid[..., None], returns, 0.0)
    return ClutterScans(returns, counts, target_index)


def bearing_windows(truth: Array, sensors: Array, margin: float) -> tuple[Array, Array]:
    """Per-sensor (azimuth, elevation) windows ``(M, 2)`` covering every bearing of ``truth`` ``(R, K, n)``
    from ``sensors`` ``(M, 3)``, widened by ``margin`` rad on each side (a helper for scenario files).

    Azimuths are unwrapped around each sensor's circular mean, so a window may extend beyond pi.
    """
    flat = np.asarray(truth, dtype=float).reshape(-1, truth.shape[-1])
    m_sens = sensors.shape[0]
    z = bearing(flat, np.broadcast_to(sensors, (flat.shape[0], m_sens, 3))).reshape(-1, m_sens, 2)
    centre = np.angle(np.exp(1j * z[..., 0]).mean(axis=0))
    az = centre + wrap_angle(z[..., 0] - centre)
    az_w = np.stack([az.min(axis=0) - margin, az.max(axis=0) + margin], axis=-1)
    el_w = np.stack([z[..., 1].min(axis=0) - margin, z[..., 1].max(axis=0) + margin], axis=-1)
    return az_w, el_w
