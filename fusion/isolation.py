"""An isolated tracker's update: what its own measurements cannot observe is held at its prior.

A tracker whose neighbours all fell silent (cut, frozen, killed) fuses with itself only, and its own sensor may
observe only part of the state: a bearing gives the direction of the target, never its range. A Cartesian
Kalman update on bearings alone still moves the range, through the correlations of the prior and the
linearisation at a wrong range, and collapses its variance while the range is unobservable: the estimate slides
along the ray faster than prediction alone would move it (about 10 m a step in the hour soak, issue 54).

What such a node's update does instead (:func:`isolated_update`):

1. The directions of the kinematic state its measurement cannot observe: the null space of the observability
   matrix ``O = [C; C A; ...; C A^(n-1)]`` of the plant's nominal transition ``A`` and the measurement Jacobian
   ``C`` at the prior (:func:`unobserved_projector`). For a bearing and a position-velocity state they are the
   line-of-sight components of position and velocity: the range and its rate. For a point measurement there are
   none, and the update is the filter's own. Where there are some, the filter's augmented states (the lumped
   model-error terms of the extended-state filters), which one bearing sees only through the second and third
   differences of its angles scaled by that unknown range, are held too (:func:`held_projector`).
2. The filter's own update, with the held directions set back to the prior (:func:`hold_unobserved`): the
   Schmidt-Kalman ("consider") update with zero gain on them (S. F. Schmidt, "Application of state-space methods
   to navigation problems", Advances in Control Systems 3, 1966; D. Simon, *Optimal State Estimation*, 2006,
   Section 7.4). The observed part and its correlation with the held part are the optimal update's; the held
   mean and covariance are the prior's, so the range keeps what the last fusion gave it and grows by prediction.
   For any linear-regression update (EKF, TESKF, UKF, CKF) the result is the covariance of the error under that
   gain, hence positive semi-definite and consistent as far as the linearisation holds.
3. That linearisation is honest only while the prior's spread along the held directions leaves the measurement
   unchanged (a bearing is the same anywhere on the ray beyond the sensor): where the measurement at the prior mean
   moved ``SPREAD_SIGMAS`` standard deviations along a held direction differs from the one at the mean by more than
   one noise standard deviation (the spread reaches past the sensor), the measurement cannot be used by a Gaussian
   in these coordinates, and the node predicts only (:func:`spread_keeps_measurement`).

Modified polar and log-polar coordinates and range-parametrised banks (Aidala & Hammel, IEEE TAC 28(3) 1983;
Peach, IEE Proc. Radar Sonar Navig. 142(2) 1995) are the literature's other remedies; the figures of this one
beside a change of coordinates and other choices of what to hold are in ``docs/isolated-tracker.md``
(``zentrack bench isolated``). A node with neighbours updates as before: only the batched simulator
(:func:`~zentrack.study.simulator.run_distributed` with ``links``) and a tracker
(:class:`~zentrack.node.diffusion.tracker.Tracker`) that heard no neighbour in the fusion that made its prior,
:func:`fused_alone`, call this.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .linalg import GaussianState, mat_vec, symmetrize

Array = np.ndarray

#: a singular value of the observability matrix below this fraction of its largest is zero (the held directions
#: of a bearing and a kinematic chain are exact zeros, about 1e-17 of the largest)
NULL_TOLERANCE = 1e-9
#: the prior's spread checked along the held directions (standard deviations): 3 keeps 99.7 % of its mass
SPREAD_SIGMAS = 3.0


def fused_alone(heard: Array, neighbours: Array) -> Array:
    """Whether each receiver is isolated: it has neighbours (``neighbours`` ``(..., M)`` booleans per sender, the
    receiver itself excluded) and fused none of their messages (``heard`` ``(..., M)``, broadcast against it). The
    batched simulator asks it of every node and step at once, a tracker of its last fusion."""
    neighbours = np.asarray(neighbours, dtype=bool)
    return neighbours.any(axis=-1) & ~(np.asarray(heard, dtype=bool) & neighbours).any(axis=-1)


def unobserved_projector(jac: Array, transition: Array) -> Array:
    """``(B, n, n)``: the orthogonal projector onto the null space of ``O = [C; C A; ...; C A^(n-1)]`` per row,
    the directions the measurement with Jacobian ``jac`` ``(B, m, n)`` does not observe through the dynamics
    ``transition`` ``(n, n)`` (zero where everything is observed)."""
    n = jac.shape[-1]
    blocks = [jac]
    for _ in range(n - 1):
        blocks.append(blocks[-1] @ transition)
    _, sv, vt = np.linalg.svd(np.concatenate(blocks, axis=-2))
    null = sv < NULL_TOLERANCE * sv[..., :1]  # (B, n): O has at least n rows, so n singular values
    basis = np.swapaxes(vt, -1, -2) * null[..., None, :]
    return basis @ np.swapaxes(basis, -1, -2)


def hold_unobserved(prior: GaussianState, post: GaussianState, projector: Array) -> GaussianState:
    """The Schmidt update from the optimal one: ``post`` with the mean and covariance of the subspace ``projector``
    set back to ``prior``'s, ``x = x+ - Pi (x+ - x-)``, ``P = P+ + Pi (P- - P+) Pi`` (in coordinates
    ``[observed; held]`` only the held mean and the held block change; the cross block is the optimal one's)."""
    mean = post.mean - mat_vec(projector, post.mean - prior.mean)
    cov = post.cov + projector @ (prior.cov - post.cov) @ projector
    return GaussianState(mean, symmetrize(cov))


def spread_keeps_measurement(measurement: Any, prior: GaussianState, projector: Array, jac: Array, sensors: Array,
                             noise: Array, kinematic_dim: int) -> Array:
    """``(B,)``: whether the measurement at the prior mean moved ``SPREAD_SIGMAS`` standard deviations of the
    prior's held spread, along each principal axis of it in the columns the measurement sees, stays within one
    noise standard deviation of the one at the mean (a bearing: the spread stays on the far side of the sensor)."""
    seen = np.flatnonzero(np.any(jac != 0, axis=(0, 1)))
    held_cov = (projector @ prior.cov @ projector)[:, seen[:, None], seen]
    values, axes = np.linalg.eigh(symmetrize(held_cov))
    at_mean = measurement.h(prior.mean[:, :kinematic_dim], sensors)
    tolerance = np.sqrt(np.diagonal(noise, axis1=-2, axis2=-1))
    ok = np.ones(prior.mean.shape[0], dtype=bool)
    for j in range(len(seen)):
        step = SPREAD_SIGMAS * np.sqrt(np.maximum(values[:, j], 0.0))[:, None] * axes[:, :, j]
        for sign in (1.0, -1.0):
            moved = prior.mean[:, :kinematic_dim].copy()
            moved[:, seen] += sign * step
            ok &= np.all(np.abs(measurement.residual(measurement.h(moved, sensors), at_mean)) <= tolerance, axis=-1)
    return ok


def held_projector(jac: Array, transition: Array, state_dim: int) -> Array:
    """``(B, n, n)``: what an isolated node holds (module docstring, step 1): the kinematic directions
    :func:`unobserved_projector` finds with the kinematic columns of ``jac`` ``(B, m, n)`` and ``transition``
    ``(k, k)``, and, in the rows where there are some, the augmented states ``k .. n - 1``."""
    kin = transition.shape[-1]
    projector = np.zeros(jac.shape[:1] + (state_dim, state_dim))
    projector[:, :kin, :kin] = unobserved_projector(jac[:, :, :kin], transition)
    partial = projector.any(axis=(-1, -2))
    projector[partial, kin:, kin:] = np.eye(state_dim - kin)
    return projector


def isolated_update(filt: Any, prior: GaussianState, z: Array, sensors: Array, noise: Array) -> GaussianState:
    """The update of an isolated node (module docstring): ``filt``'s own where it observes everything or has no
    nominal transition, else the Schmidt update holding what it cannot observe, or the prior itself where the
    prior's spread along the held directions changes the measurement. Arguments as
    :meth:`~zentrack.fusion.filters.base.LocalFilter.update`."""
    post = filt.update(prior, z, sensors, noise)
    transition = filt.nominal_transition()
    if transition is None:
        return post
    kin = filt.kinematic_dim
    jac = filt.measurement.jacobian(prior.mean[:, :kin], sensors, filt.state_dim)
    projector = held_projector(jac, transition, filt.state_dim)
    if not projector.any():
        return post
    held = hold_unobserved(prior, post, projector)
    noise = np.broadcast_to(noise, (prior.mean.shape[0],) + noise.shape[-2:])
    ok = spread_keeps_measurement(filt.measurement, prior, projector, jac, sensors, noise, kin)
    return GaussianState(np.where(ok[:, None], held.mean, prior.mean), np.where(ok[:, None, None], held.cov, prior.cov))
