"""A tracker cut off from both its neighbours: its error and NEES over the cut, per update rule (issue 54).

The batched simulator (:func:`~zentrack.study.simulator.run_distributed` with ``links``) cuts one node's links
both ways for the fusions of a window, so that its updates at steps ``start .. start + length - 1`` are an
isolated node's; each rule below is what that node does with its own measurement there (every other node and
step runs as always):

- ``today``: the filter's own update (what a tracker did before issue 54);
- ``prediction``: no update, the prior predicted (the reference the issue holds the others to);
- ``held``: :func:`~zentrack.fusion.isolation.isolated_update`, what trackers and the simulator do: the
  unobservable subspace of the kinematic state held (range and range rate for a bearing) with the lumped terms,
  prediction only where the prior's spread along it reaches past the sensor;
- ``held-unchecked``: the same hold without that spread check;
- ``held-los``: the unobservable subspace of the whole augmented state instead (the line-of-sight component of
  position, velocity and the lumped terms; the lumped terms' other components updated), with the check;
- ``held-range``: only the line-of-sight position held (the range, not its derivatives), with the check;
- ``log-polar``: the update in log-spherical coordinates of the position about the sensor, ``(ln r, az, el)``,
  where a bearing is linear (the change of coordinates of modified polar / log-polar filters, Aidala & Hammel
  1983; here for the update only), then back to Cartesian coordinates.

Figures per rule: the node's position error per step (mean over the runs), the NEES of its kinematic state per
step (mean over the runs) beside the 95 % band of that mean, and over the cut the RMS error, the error at its
end and the largest mean NEES. ``zentrack bench isolated`` prints and plots them.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.fusion.consistency import anees_band, nees
from zentrack.fusion.filters import LocalFilter
from zentrack.fusion.isolation import (
    held_projector,
    hold_unobserved,
    isolated_update,
    spread_keeps_measurement,
    unobserved_projector,
)
from zentrack.fusion.linalg import GaussianState, symmetrize
from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.rules import make_rule
from zentrack.truth.simulation.simulate import simulate

from .links import IsolatedUpdate, cut_links
from .simulator import build_filter, run_distributed

Array = np.ndarray

#: the node cut off (its ring neighbours are 3 and 5, as node 4's in the hour soak) and the first isolated update
#: (20 s into the run: every node has converged)
CUT_NODE, CUT_START = 4, 200
#: steps simulated after the cut (the node rejoins)
AFTER_CUT = 50


def own_update(filt: LocalFilter, prior: GaussianState, z: Array, sensors: Array, noise: Array) -> GaussianState:
    """The filter's own update, as if the node had neighbours."""
    return filt.update(prior, z, sensors, noise)


def no_update(filt: LocalFilter, prior: GaussianState, z: Array, sensors: Array, noise: Array) -> GaussianState:
    """The prior itself: prediction alone."""
    return prior


def _checked(filt: LocalFilter, prior: GaussianState, post: GaussianState, projector: Array, jac: Array,
             sensors: Array, noise: Array) -> GaussianState:
    """``post`` with ``projector``'s subspace held, or ``prior`` where its spread changes the measurement."""
    held = hold_unobserved(prior, post, projector)
    noise = np.broadcast_to(noise, (prior.mean.shape[0],) + noise.shape[-2:])
    ok = spread_keeps_measurement(filt.measurement, prior, projector, jac, sensors, noise,  # type: ignore[attr-defined]
                                  filt.kinematic_dim)
    return GaussianState(np.where(ok[:, None], held.mean, prior.mean), np.where(ok[:, None, None], held.cov, prior.cov))


def _jacobian(filt: LocalFilter, prior: GaussianState, sensors: Array) -> Array:
    return filt.measurement.jacobian(prior.mean[:, :filt.kinematic_dim], sensors, filt.state_dim)  # type: ignore[attr-defined]


def held_unchecked(filt: LocalFilter, prior: GaussianState, z: Array, sensors: Array, noise: Array) -> GaussianState:
    """:func:`~zentrack.fusion.isolation.isolated_update` without its spread check."""
    transition = filt.nominal_transition()
    assert transition is not None
    projector = held_projector(_jacobian(filt, prior, sensors), transition, filt.state_dim)
    return hold_unobserved(prior, filt.update(prior, z, sensors, noise), projector)


def held_line_of_sight(filt: LocalFilter, prior: GaussianState, z: Array, sensors: Array, noise: Array
                       ) -> GaussianState:
    """The unobservable subspace of the whole state with the extended-state filters' augmented transition
    ``Acal`` (the line-of-sight component of position, velocity and both lumped terms; the rest of the lumped
    terms updated), with the spread check."""
    jac = _jacobian(filt, prior, sensors)
    projector = unobserved_projector(jac, filt.a_cal)  # type: ignore[attr-defined]  # an extended-state filter
    return _checked(filt, prior, filt.update(prior, z, sensors, noise), projector, jac, sensors, noise)


def held_range(filt: LocalFilter, prior: GaussianState, z: Array, sensors: Array, noise: Array) -> GaussianState:
    """Only the position's line-of-sight component held, with the spread check."""
    d = prior.mean[:, :3] - sensors[:, 0]
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    projector = np.zeros(prior.cov.shape)
    projector[:, :3, :3] = u[:, :, None] * u[:, None, :]
    jac = _jacobian(filt, prior, sensors)
    return _checked(filt, prior, filt.update(prior, z, sensors, noise), projector, jac, sensors, noise)


def _spherical(p: Array, s: Array) -> tuple[Array, Array]:
    """``(ln r, az, el)`` of positions ``p`` ``(B, 3)`` about ``s`` and its Jacobian ``(B, 3, 3)``."""
    d = p - s
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    rho2 = dx * dx + dy * dy
    rho, r2 = np.sqrt(rho2), rho2 + dz * dz
    q = np.stack([0.5 * np.log(r2), np.arctan2(dy, dx), np.arctan2(dz, rho)], axis=-1)
    jac = np.zeros((p.shape[0], 3, 3))
    jac[:, 0] = d / r2[:, None]
    jac[:, 1, 0], jac[:, 1, 1] = -dy / rho2, dx / rho2
    k = -dz / (r2 * rho)
    jac[:, 2, 0], jac[:, 2, 1], jac[:, 2, 2] = k * dx, k * dy, rho / r2
    return q, jac


def log_polar(filt: LocalFilter, prior: GaussianState, z: Array, sensors: Array, noise: Array) -> GaussianState:
    """The Kalman update with the position in ``(ln r, az, el)`` about the sensor, where a bearing is linear
    (``H = [0 I2 0]``), the covariance carried over by the Jacobian of the change of coordinates at the prior and
    back at the posterior; the noise as the filter weighs it (TESKF: ``R / (1 + theta)``)."""
    s = sensors[:, 0]
    b, n = prior.mean.shape
    q, jac_q = _spherical(prior.mean[:, :3], s)
    jac = np.broadcast_to(np.eye(n), (b, n, n)).copy()
    jac[:, :3, :3] = jac_q
    cov_y = jac @ prior.cov @ np.swapaxes(jac, -1, -2)
    r = np.broadcast_to(noise, (b, 2, 2)) * getattr(filt, "_r_scale", 1.0)
    gain = cov_y[:, :, 1:3] @ np.linalg.inv(cov_y[:, 1:3, 1:3] + r)
    y = prior.mean.copy()
    y[:, :3] = q
    y = y + (gain @ wrap_angle(z - q[:, 1:3])[:, :, None])[:, :, 0]
    h = np.zeros((2, n))
    h[0, 1] = h[1, 2] = 1.0
    i_kh = np.eye(n) - gain @ h
    cov_y = i_kh @ cov_y @ np.swapaxes(i_kh, -1, -2) + gain @ r @ np.swapaxes(gain, -1, -2)
    rad, az, el = np.exp(y[:, 0]), y[:, 1], y[:, 2]
    mean = y.copy()
    mean[:, :3] = s + np.stack([rad * np.cos(el) * np.cos(az), rad * np.cos(el) * np.sin(az), rad * np.sin(el)], -1)
    back = np.broadcast_to(np.eye(n), (b, n, n)).copy()
    back[:, :3, :3] = np.linalg.inv(_spherical(mean[:, :3], s)[1])
    return GaussianState(mean, symmetrize(back @ cov_y @ np.swapaxes(back, -1, -2)))


#: rule -> (label, the isolated node's update)
RULES: dict[str, tuple[str, IsolatedUpdate]] = {
    "today": ("own update (before issue 54)", own_update),
    "prediction": ("prediction alone", no_update),
    "held": ("unobservable subspace held (chosen)", isolated_update),
    "held-unchecked": ("held, no spread check", held_unchecked),
    "held-los": ("line of sight of every block held", held_line_of_sight),
    "held-range": ("only the range held", held_range),
    "log-polar": ("update in (ln r, az, el)", log_polar),
}


@dataclass
class CutResult:
    """One rule on one cut: per step of the whole run, the node's position error (mean over the runs) and the
    mean NEES of its kinematic state; the per-run position errors for the spread."""

    rule: str
    error: Array  # (K,)
    nees: Array  # (K,)
    run_error: Array  # (R, K)


def run_cut(scenario: str, seconds: float, runs: int, seed: int = 0, rules: Sequence[str] = tuple(RULES),
            node: int = CUT_NODE, start: int = CUT_START) -> dict:
    """Every rule in ``rules`` on ``scenario`` with ``node`` cut off for ``seconds``: the figures as a dict
    (``results``: :class:`CutResult` per rule; ``summary``: per rule the figures over the cut)."""
    cfg = load_scenario_config(scenario)
    length = int(round(seconds / cfg.ts))
    scn = simulate(resize(cfg, None, start + length + AFTER_CUT).spec, runs=runs, seed=seed, ts=cfg.ts)
    filt = build_filter(scn, cfg.filter_kind, qbar=cfg.qbar, theta=cfg.theta, params=cfg.filter_params)
    links = cut_links(scn.steps, scn.nodes, node, start, length)
    rule_ = make_rule(cfg.fusion, cfg.fusion_params)
    results = {}
    for rule in rules:
        res = run_distributed(scn, filt, rule_, links=links, alone=RULES[rule][1])
        err = res.mean[:, :, node] - scn.truth[:, :, : filt.kinematic_dim]
        run_error = np.linalg.norm(err[..., :3], axis=-1)
        results[rule] = CutResult(rule, run_error.mean(axis=0), nees(err, res.cov[:, :, node]).mean(axis=0), run_error)
    cut = slice(start, start + length)
    band = anees_band(filt.kinematic_dim, runs)
    summary = {}
    for rule, r in results.items():
        summary[rule] = {
            "label": RULES[rule][0],
            "rms_error_m": float(np.sqrt(np.mean(r.run_error[:, cut] ** 2))),
            "end_error_m": float(r.error[start + length - 1]),
            "max_nees": float(r.nees[cut].max()),
            "mean_nees": float(r.nees[cut].mean()),
            "after_error_m": float(r.error[start + length + 10]),
        }
    return {"scenario": scenario, "seconds": seconds, "steps": length, "start": start, "node": node, "runs": runs,
            "seed": seed, "ts": cfg.ts, "filter": cfg.filter_kind, "fusion": cfg.fusion, "nees_dof": filt.kinematic_dim,
            "nees_band": list(band), "results": results, "summary": summary}
