"""Gating every track against every return of one scan, and the likelihood ratio the associators weigh.

For predicted tracks ``(m_t, P_t)`` the measurement model linearises at the mean as the local EKF and the
PDAF-EKF do (:mod:`~zentrack.fusion.filters.pdaf_ekf`): ``zhat_t = h(m_t)``, ``H_t = dh/dx(m_t)``,
``S_t = H_t P_t H_t^T + R``, ``nu_tj = y_j - zhat_t`` (angles wrapped by the model's ``residual``). Return ``j``
is in track ``t``'s gate when ``nu_tj^T S_t^-1 nu_tj <= gamma = chi2_m(P_G)``
(:func:`~zentrack.fusion.gate.gate_threshold`), and its likelihood is ``l_tj = N(nu_tj; 0, S_t)``.

The association of a scan is weighed by joint events ``theta`` (each track takes at most one return, each
return comes from at most one track, the others are clutter). With Poisson clutter of density ``lambda`` and
detection probability ``P_D`` (Bar-Shalom & Fortmann 1988 Sec. 9.3; Fortmann, Bar-Shalom & Scheffe 1983,
the parametric form)

    P(theta | Z) ∝ prod_{(t, j) in theta} P_D l_tj / lambda  *  prod_{t missed} (1 - P_D P_G),

so dividing by ``prod_t (1 - P_D P_G)``, an event's weight is the product of the likelihood ratios
``a_tj = P_D l_tj / (lambda (1 - P_D P_G))`` of its pairs (:func:`log_likelihood_ratio`). For one track it is
the PDA of :mod:`~zentrack.fusion.filters.pda_common` (``beta_j ∝ P_D l_j``, ``beta_0 ∝ b = lambda (1 - P_D P_G)``).
"""
from __future__ import annotations

import math

import numpy as np

from ..filters.pda_common import gaussian_log_density
from ..gate import gate_threshold, innovation_distances
from ..linalg import GaussianState, small_inverse
from ..measurement import MeasurementModel
from ..scan import Scan
from .base import ScanLikelihood

Array = np.ndarray


def check_clutter_params(detection_prob: float, clutter_density: float, gate_prob: float) -> None:
    """ValueError naming the parameter if ``P_D`` is not in (0, 1], ``lambda`` not positive and finite, or
    ``P_G`` not in (0, 1)."""
    if not 0.0 < detection_prob <= 1.0:
        raise ValueError(f"detection_prob must lie in (0, 1], got {detection_prob}")
    if not (0.0 < clutter_density < math.inf):
        raise ValueError(f"clutter_density must be positive and finite, got {clutter_density}")
    if not 0.0 < gate_prob < 1.0:
        raise ValueError(f"gate_prob must lie in (0, 1), got {gate_prob}")
    if detection_prob * gate_prob >= 1.0:
        raise ValueError("detection_prob * gate_prob must be below 1")


def gate_gamma(dim: int, gate_prob: float) -> float:
    """``gamma = chi2_dim(P_G)``: the gate holding the track's own return with probability ``P_G``."""
    return gate_threshold(dim, 1.0 - gate_prob)


def scan_likelihood(measurement: MeasurementModel, state: GaussianState, scan: Scan, gamma: float) -> ScanLikelihood:
    """Gate and likelihoods of every track of ``state`` (``(T, n)`` predicted means) against every return of
    ``scan`` (module docstring). ``T = 0`` or ``J = 0`` give empty ``(T, J)`` arrays."""
    t, n = state.mean.shape
    j = scan.count
    if t == 0 or j == 0:
        empty = np.zeros((t, j))
        return ScanLikelihood(empty, empty.copy(), np.zeros((t, j), dtype=bool), gamma)
    innov, s, d2 = innovation_distances(measurement, state, scan)
    log_lik = gaussian_log_density(innov, small_inverse(s), np.linalg.slogdet(s)[1])
    return ScanLikelihood(log_lik, d2, d2 <= gamma, gamma)


def log_likelihood_ratio(log_lik: Array, detection_prob: float, clutter_density: float, gate_prob: float) -> Array:
    """``log a_tj = log(P_D l_tj) - log(lambda (1 - P_D P_G))`` (module docstring), elementwise."""
    return log_lik + math.log(detection_prob) - math.log(clutter_density * (1.0 - detection_prob * gate_prob))


def track_clusters(gated: Array) -> tuple[Array, list[tuple[Array, Array]]]:
    """The clusters of the gate mask ``(T, J)``, the connected components of the bipartite graph "track t
    gates return j": the ``(T,)`` mask of the tracks alone in theirs (with or without gated returns), and
    ``(tracks, returns)`` index arrays of every cluster of two or more tracks, in the order of their first track.
    Each track's label is the least track index it is connected to, found by passing the least label through the
    returns both ways until nothing changes (a few passes: clusters of a scan are small)."""
    t, j = gated.shape
    rows, cols = np.nonzero(gated)
    label = np.arange(t)
    through = np.full(j, t)  # per return: the least label of the tracks that gate it (t: none)
    while rows.size:
        through = np.full(j, t)
        np.minimum.at(through, cols, label[rows])
        new = label.copy()
        np.minimum.at(new, rows, through[cols])
        new = new[new]  # (a label's own label: the least it has heard of so far)
        if np.array_equal(new, label):
            break
        label = new
    size = np.bincount(label, minlength=t)
    lone = size[label] == 1
    shared = np.flatnonzero(size >= 2)
    return lone, [(np.flatnonzero(label == c), np.flatnonzero(through == c)) for c in shared]
