"""Batched in-process network simulator: M nodes x K steps x R Monte Carlo runs in stacked linear algebra.

Distributed filters (``d`` + local filter, e.g. ``dteskf``) run seed 000 Algorithm 2 at every node with one
round of diffusion; centralized filters (``c`` + local filter, e.g. ``cteskf``) run Algorithm 1 on all
measurements stacked (eq. 15).  The state stack is ``(R*M, n)``: every node of every run steps in the same
numpy calls, which is what makes Monte Carlo studies cheap.  Deterministic for a given scenario.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filters import LOCAL_FILTERS, LocalFilter, make_local_filter
from .fusion_rules import ci_fuse, independent_fuse
from .linalg import GaussianState, InformationPair, to_information
from .metrics import summarize
from .scenario import ScenarioData

Array = np.ndarray

FUSION_RULES = ("ci", "independent")
FILTERS = tuple(f"d{k}" for k in LOCAL_FILTERS) + tuple(f"c{k}" for k in LOCAL_FILTERS)


@dataclass
class NetworkResult:
    """Posterior kinematic estimates of every node at every step: ``mean`` ``(R, K, M, n)``, ``cov`` ``(R, K, M, n, n)``."""

    filter: str
    mean: Array
    cov: Array

    def errors(self, scn: ScenarioData) -> Array:
        return self.mean - scn.truth[:, :, None, :]


def parse_filter_name(name: str) -> tuple[str, str]:
    """``"dteskf"`` -> ``("teskf", "distributed")``; ``"cekf"`` -> ``("ekf", "centralized")``."""
    if name not in FILTERS:
        raise ValueError(f"unknown filter {name!r}; choose one of {', '.join(FILTERS)}")
    return name[1:], "distributed" if name[0] == "d" else "centralized"


def build_filter(scn: ScenarioData, kind: str, qbar: float = 1e-6, theta: float | None = None) -> LocalFilter:
    return make_local_filter(
        kind, scn.motion_model(), scn.measurement_model(), scn.p0, scn.lumped_var, qbar=qbar, theta=theta
    )


def select(mask: Array, a: GaussianState, b: GaussianState) -> GaussianState:
    """Row-wise choice: ``a`` where ``mask`` ``(B,)`` is true, else ``b``."""
    return GaussianState(np.where(mask[:, None], a.mean, b.mean), np.where(mask[:, None, None], a.cov, b.cov))


def run_distributed(
    scn: ScenarioData, filt: LocalFilter, fusion: str = "ci", weights: Array | None = None
) -> NetworkResult:
    """Seed 000 Algorithm 2 for every node of every run. A node without a measurement predicts only."""
    if fusion not in FUSION_RULES:
        raise ValueError(f"fusion must be one of {FUSION_RULES}, got {fusion!r}")
    r, k_steps, m = scn.runs, scn.steps, scn.nodes
    w = scn.weights if weights is None else np.asarray(weights, dtype=float)
    nk, nx = filt.kinematic_dim, filt.state_dim
    state = filt.initial_state(np.repeat(scn.x0_estimate, m, axis=0), scn.p0, scn.lumped_var)
    sensors = np.tile(scn.sensors[:, None, :], (r, 1, 1))
    noise = np.tile(scn.noise_cov, (r, 1, 1))
    all_present = bool(scn.present.all())
    mean = np.empty((r, k_steps, m, nk))
    cov = np.empty((r, k_steps, m, nk, nk))
    for k in range(k_steps):
        z = scn.measurements[:, k].reshape(r * m, -1)
        if all_present:
            post = filt.update(state, z, sensors, noise)
        else:
            post = masked_update(filt, state, z, sensors, noise, scn.present[:, k].reshape(-1))
        mean[:, k] = post.mean[:, :nk].reshape(r, m, nk)
        cov[:, k] = post.cov[:, :nk, :nk].reshape(r, m, nk, nk)
        pair = to_information(filt.predict(post))
        pair = InformationPair(pair.matrix.reshape(r, m, nx, nx), pair.vector.reshape(r, m, nx))
        fused = ci_fuse(w, pair) if fusion == "ci" else independent_fuse(scn.adjacency, pair)
        state = GaussianState(fused.mean.reshape(r * m, nx), fused.cov.reshape(r * m, nx, nx))
    return NetworkResult(getattr(filt, "name", "filter"), mean, cov)


def masked_update(
    filt: LocalFilter, state: GaussianState, z: Array, sensors: Array, noise: Array, present: Array
) -> GaussianState:
    """Update the rows whose measurement is ``present`` ``(B,)``; the others keep their prior (coasting)."""
    if not present.any():
        return state
    safe_z = np.where(present[:, None], z, 0.0)
    return select(present, filt.update(state, safe_z, sensors, noise), state)


def run_centralized(scn: ScenarioData, filt: LocalFilter) -> NetworkResult:
    """Seed 000 Algorithm 1 on all nodes' measurements stacked; result has M = 1.

    A missing measurement gets a variance of 1e16 and a zero value, which removes it from the update.
    """
    r, k_steps, m = scn.runs, scn.steps, scn.nodes
    nk = filt.kinematic_dim
    md = scn.measurements.shape[-1]
    state = filt.initial_state(scn.x0_estimate, scn.p0, scn.lumped_var)
    sensors = np.broadcast_to(scn.sensors, (r,) + scn.sensors.shape)
    noise = np.zeros((m * md, m * md))
    for i in range(m):
        noise[i * md : (i + 1) * md, i * md : (i + 1) * md] = scn.noise_cov[i]
    mean = np.empty((r, k_steps, 1, nk))
    cov = np.empty((r, k_steps, 1, nk, nk))
    for k in range(k_steps):
        z = scn.measurements[:, k].reshape(r, m * md)
        present = scn.present[:, k]
        if present.all():
            post = filt.update(state, z, sensors, noise)
        else:
            missing = np.repeat(~present, md, axis=1)
            run_noise = np.where(missing[:, :, None] & np.eye(m * md, dtype=bool), 1e16, noise)
            post = filt.update(state, np.where(missing, 0.0, z), sensors, run_noise)
        mean[:, k, 0] = post.mean[:, :nk]
        cov[:, k, 0] = post.cov[:, :nk, :nk]
        state = filt.predict(post)
    return NetworkResult(getattr(filt, "name", "filter"), mean, cov)


def run_filter(
    scn: ScenarioData, name: str, fusion: str = "ci", qbar: float = 1e-6, theta: float | None = None
) -> NetworkResult:
    """Run a filter by name (``dteskf``, ``cekf``, ...) on every run of ``scn``."""
    kind, arch = parse_filter_name(name)
    filt = build_filter(scn, kind, qbar=qbar, theta=theta)
    res = run_distributed(scn, filt, fusion) if arch == "distributed" else run_centralized(scn, filt)
    res.filter = name
    return res


def state_groups(scn: ScenarioData) -> dict[str, list[int]]:
    """The component groups the paper reports: x1/x2 for Experiment 1, p/v for the 3-D plant."""
    return {"x1": [0], "x2": [1]} if scn.plant == "exp1" else {"p": [0, 1, 2], "v": [3, 4, 5]}


def evaluate(scn: ScenarioData, result: NetworkResult) -> dict:
    """Metrics of :func:`zentrack.fusion.metrics.summarize` for a result against the scenario truth."""
    return summarize(result.errors(scn), result.cov, state_groups(scn))
