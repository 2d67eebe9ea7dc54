"""Batched in-process network simulator: M nodes x K steps x R Monte Carlo runs in stacked linear algebra.

A local filter (``teskf``, ...) runs paper 0 Algorithm 2 at every node with any registered fusion rule
(:data:`~zentrack.fusion.rules.RULE_REGISTRY`, default CI) and its rounds per step, or, with the fusion rule
``centralized`` (:data:`~zentrack.fusion.defaults.CENTRALIZED`), Algorithm 1 on all measurements stacked
(eq. 15): the names a live run takes (``--filter teskf --fusion ci``).  The state stack is ``(R*M, n)``: every node of every run steps in the same numpy calls, which is
what makes Monte Carlo studies cheap.  Deterministic for a given scenario.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from zentrack.fusion.defaults import CENTRALIZED, DEFAULT_FUSION, DEFAULT_QBAR
from zentrack.fusion.filters import FILTER_REGISTRY, LOCAL_FILTERS, LocalFilter, make_local_filter
from zentrack.fusion.filters.pda_common import ClutterFilter, ParticleState, reseed_cloud
from zentrack.fusion.graphs import within_hops
from zentrack.fusion.isolation import isolated_update
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information
from zentrack.fusion.rules import RULE_REGISTRY, FusionRule, make_rule
from zentrack.truth.simulation.scenario import ScenarioData, state_groups

from .links import IsolatedUpdate, isolated_rows, link_mask, update_isolated_rows
from .metrics import divergence_steps, summarize
from .pcrlb import bound_ratio

Array = np.ndarray

#: the registered fusion rules (built-ins first, then those found in fusion/rules/)
FUSION_RULES: tuple[str, ...] = RULE_REGISTRY.names()
#: the old combined names, distributed (d...) and centralized (c...), of every registered local filter
FILTERS = tuple(f"d{k}" for k in LOCAL_FILTERS) + tuple(f"c{k}" for k in LOCAL_FILTERS)


@dataclass
class NetworkResult:
    """Posterior kinematic estimates of every node at every step: ``mean`` ``(R, K, M, n)``, ``cov`` ``(R, K, M, n, n)``."""

    filter: str
    mean: Array
    cov: Array
    #: per run, the step at which it diverged (-1: never); diverged runs are NaN from that step on
    diverged_at: Array = field(default_factory=lambda: np.zeros(0, dtype=int))

    def errors(self, scn: ScenarioData) -> Array:
        return self.mean - scn.truth[:, :, None, :]


def parse_filter_name(name: str) -> tuple[str, str]:
    """``"dteskf"`` -> ``("teskf", "distributed")``; ``"cekf"`` -> ``("ekf", "centralized")``.

    Any registered filter is accepted, including plug-ins loaded after :data:`FILTERS` was computed.
    """
    if len(name) < 2 or name[0] not in "dc" or name[1:] not in FILTER_REGISTRY:
        raise ValueError(f"unknown filter {name!r}; choose one of {', '.join(FILTER_REGISTRY.names())} (with a "
                         f"fusion rule, or {CENTRALIZED!r})")
    return name[1:], "distributed" if name[0] == "d" else "centralized"


def build_filter(scn: ScenarioData, kind: str, qbar: float = DEFAULT_QBAR, theta: float | None = None,
                 params: dict | None = None) -> LocalFilter:
    return make_local_filter(
        kind, scn.motion_model(), scn.measurement_model(), scn.p0, scn.lumped_var, qbar=qbar, theta=theta,
        params=params,
    )


def select(mask: Array, a: GaussianState, b: GaussianState) -> GaussianState:
    """Row-wise choice: ``a`` where ``mask`` ``(B,)`` is true, else ``b``."""
    return GaussianState(np.where(mask[:, None], a.mean, b.mean), np.where(mask[:, None, None], a.cov, b.cov))


def masked_update(
    filt: LocalFilter, state: GaussianState, z: Array, sensors: Array, noise: Array, present: Array,
    counts: Array | None = None,
) -> GaussianState:
    """Update the rows whose measurement is ``present`` ``(B,)``; the others keep their prior (coasting).
    ``counts``: the scans' return counts when ``z`` holds ragged scans ``(B, Jmax, m)`` (clutter filters)."""
    if not present.any():
        return state
    if counts is not None:
        post = filt.update(state, z, sensors, noise, counts=np.where(present, counts, 0))  # type: ignore[call-arg]
        if getattr(filt, "scanless_rows_unchanged", False):
            return post  # rows without returns are their prior already, with what the filter attached to them
        return _keep_rows(present, post, state)
    safe_z = np.where(present[:, None], z, 0.0)
    return select(present, filt.update(state, safe_z, sensors, noise), state)


def _keep_rows(mask: Array, post: GaussianState, prior: GaussianState) -> GaussianState:
    """Row-wise choice that keeps a particle cloud (a scan-less row's cloud is its prior's, untouched)."""
    chosen = select(mask, post, prior)
    if isinstance(post, ParticleState) and isinstance(prior, ParticleState):
        return ParticleState(chosen.mean, chosen.cov, np.where(mask[:, None, None], post.particles, prior.particles))
    return chosen


def run_distributed(
    scn: ScenarioData, filt: LocalFilter, fusion: str | FusionRule = DEFAULT_FUSION, weights: Array | None = None,
    links: Array | None = None, alone: IsolatedUpdate = isolated_update,
) -> NetworkResult:
    """Paper 0 Algorithm 2 for every node of every run with ``fusion`` (a registered rule name or a rule).

    Each step every node shares its prediction's information pair and the rule combines them
    ``rule.rounds(k)`` times (:meth:`~zentrack.fusion.rules.FusionRule.mix` makes each round's message from
    the last); the last round's result is the next prior.  A node without a measurement (or a relay)
    predicts only.  A rule that exchanges scans (paper 2) has every node update with its own and its
    neighbours' measurements, stacked own first and then by neighbour index, as a tracker does
    (:func:`shared_scan_inputs`); one that also relays scans (``relays_scans``) shares the prior updated with
    the scans of the two-hop neighbourhood instead, while the estimate keeps the one-hop update.
    In a scenario with clutter, a clutter filter (:class:`~zentrack.fusion.filters.pda_common.ClutterFilter`)
    updates with every return of its scan, and a particle filter's cloud is moved onto the fused prior
    (``reseed_cloud``); any other filter gets only the target's return where it was detected (an oracle
    association: a reference, not a clutter tracker).

    ``links`` ``(K, M, M)`` or ``(R, K, M, M)`` booleans (default: every link up): whether node i receives node j's
    messages in the fusion of step k. The rows are renormalised over what arrived; a node with neighbours that
    received none of theirs fused alone, and its next update is an isolated node's
    (``alone``: :func:`~zentrack.fusion.isolation.isolated_update`, as a tracker's; a study passes others).
    """
    if isinstance(fusion, str) and fusion not in RULE_REGISTRY:
        raise ValueError(f"fusion must be one of {RULE_REGISTRY.names()}, got {fusion!r}")
    rule = make_rule(fusion)
    r, m = scn.runs, scn.nodes
    w = scn.weights if weights is None else np.asarray(weights, dtype=float)
    w = rule.network_weights(w, scn.adjacency)
    nx = filt.state_dim

    present = None if links is None else link_mask(links, r, scn.steps, m)
    cut_off = None if present is None else isolated_rows(present, scn.adjacency, r)

    def diffuse(pred: GaussianState, k: int) -> GaussianState:
        rounds = rule.rounds(k)
        if rounds < 1:
            raise ValueError(f"fusion rule {rule.name!r} asked for {rounds} rounds at step {k}; at least 1")
        message = rule.share(1, network_blocks(filt, pred, r, m)).blocks
        arrived = None if present is None else present[k] if present.ndim == 3 else present[:, k]
        if arrived is not None and arrived.all():
            arrived = None  # every message in: the same sums as a run without links
        for rnd in range(1, rounds + 1):
            fused = rule.combine(rnd, w, message) if arrived is None else rule.combine(rnd, w, message, arrived)
            if rnd < rounds:
                message = rule.mix(rnd, w, message, arrived, fused)
        state = GaussianState(fused["state"].mean.reshape(r * m, nx), fused["state"].cov.reshape(r * m, nx, nx))
        if isinstance(pred, ParticleState):  # feedback to a particle filter: its cloud moved onto the fused prior
            return ParticleState(state.mean, state.cov, reseed_cloud(pred.particles, state.mean, state.cov))
        return state

    prior = filt.initial_state(np.repeat(scn.x0_estimate, m, axis=0), scn.p0, scn.lumped_var)
    noise = np.tile(scn.noise_cov, (r, 1, 1))
    md = scn.measurements.shape[-1]
    if rule.exchanges_scans:
        if links is not None:
            raise ValueError(f"fusion rule {rule.name!r} exchanges scans; links are cut for the rules that exchange "
                             "estimates only")
        if scn.has_scans:
            raise ValueError(f"fusion rule {rule.name!r} exchanges scans; the batched simulator forwards one "
                             "return per scan, not cluttered scans")
        scale = np.stack([rule.scan_information(w[i], i) for i in range(m)])
        # relays: the shared prior is updated with every scan within two hops (the estimate with one hop's)
        core = shared_scan_inputs(scn, scale, within_hops(scn.adjacency, 2)) if rule.relays_scans else None
        return _run(scn, filt, prior, m, shared_scan_inputs(scn, scale), diffuse, rule.fuses_posterior, core)

    def sensors_at(k: int) -> Array:
        return np.tile(scn.sensors_at(k)[:, None, :], (r, 1, 1))

    static = sensors_at(0) if scn.sensor_track is None else None
    if scn.scan_returns is not None and scn.scan_counts is not None and takes_scans(filt):
        returns, counts, jmax = scn.scan_returns, scn.scan_counts, scn.scan_returns.shape[3]
        has_sensor = np.tile(scn.roles != "relay", r)

        def scans(k: int) -> StepInputs:
            return (returns[:, k].reshape(r * m, jmax, md), has_sensor, counts[:, k].reshape(r * m),
                    sensors_at(k) if static is None else static, noise)

        return _run(scn, filt, prior, m, scans, diffuse, rule.fuses_posterior)

    def measurements(k: int) -> StepInputs:
        return (scn.measurements[:, k].reshape(r * m, md), scn.present[:, k].reshape(r * m), None,
                sensors_at(k) if static is None else static, noise)

    isolated = None if cut_off is None else lambda k: cut_off[:, k - 1].reshape(r * m) if k > 0 else None
    return _run(scn, filt, prior, m, measurements, diffuse, rule.fuses_posterior, isolated=isolated, alone=alone)


def takes_scans(filt: LocalFilter) -> bool:
    """Whether ``filt`` updates with every return of a scan (clutter filters, extended-object filters)."""
    return isinstance(filt, ClutterFilter) or bool(getattr(filt, "takes_scans", False))


def network_blocks(filt: LocalFilter, state: GaussianState, runs: int, nodes: int) -> dict[str, InformationPair]:
    """The information blocks every node shares, stacked ``(R, M, n, n)`` / ``(R, M, n)``: the filter's own
    ``information_blocks`` where it has them (paper 4 adds its scan's increment), else ``{"state": ...}``."""
    own = getattr(filt, "information_blocks", None)
    blocks = own(state) if own is not None else {"state": to_information(state)}
    out = {}
    for name, pair in blocks.items():
        n = pair.vector.shape[-1]
        out[name] = InformationPair(pair.matrix.reshape(runs, nodes, n, n), pair.vector.reshape(runs, nodes, n))
    return out


#: one step's filter inputs: measurements, which rows have one, return counts (clutter), sensors, noise
StepInputs = tuple[Array, Array, Array | None, Array, Array]
#: the noise variance of a padded or missing measurement in a stacked update: its information is ~1e-16 of
#: any real one's, so it adds nothing (the same device as the centralized filter's missing measurements)
MISSING_VARIANCE = 1e16


def shared_scan_inputs(scn: ScenarioData, scale: Array | None = None, adjacency: Array | None = None
                       ) -> Callable[[int], StepInputs]:
    """The stacked update inputs of measurement sharing (paper 2): node i updates with its own measurement
    and its neighbours', own first then by neighbour index, padded to the largest neighbourhood with
    measurements of variance :data:`MISSING_VARIANCE` (as are missing ones). ``scale`` ``(M, M)``: the
    information factor of j's scan at node i (:meth:`~zentrack.fusion.rules.FusionRule.scan_information`;
    its noise covariance is divided by it, 0 drops the scan); None: every scan in full. ``adjacency``: whose
    scans node i has (default the graph's: its neighbours'; relays: :func:`~zentrack.fusion.graphs.within_hops`)."""
    r, m = scn.runs, scn.nodes
    md = scn.measurements.shape[-1]
    scale = np.ones((m, m)) if scale is None else np.asarray(scale, dtype=float)
    adjacency = scn.adjacency if adjacency is None else adjacency
    groups = [[i, *(int(j) for j in np.flatnonzero(adjacency[i]) if j != i)] for i in range(m)]
    smax = max(len(g) for g in groups)
    index = np.array([g + [g[0]] * (smax - len(g)) for g in groups])  # (M, smax), padding repeats node i
    factor = scale[np.arange(m)[:, None], index]  # (M, smax)
    valid = np.array([[s < len(g) for s in range(smax)] for g in groups]) & (factor > 0)
    own_noise = scn.noise_cov[index] / np.where(valid, factor, 1.0)[..., None, None]  # (M, smax, md, md)
    eye = np.eye(md)

    def inputs(k: int) -> StepInputs:
        used = scn.present[:, k][:, index] & valid[None]  # (R, M, smax)
        z = np.where(used[..., None], scn.measurements[:, k][:, index], 0.0).reshape(r * m, smax * md)
        blocks = np.where(used[..., None, None], own_noise[None], MISSING_VARIANCE * eye)  # (R, M, smax, md, md)
        noise = np.zeros((r, m, smax, md, smax, md))
        for s in range(smax):
            noise[:, :, s, :, s, :] = blocks[:, :, s]
        sensors = np.broadcast_to(scn.sensors_at(k)[index][None], (r, m, smax, 3)).reshape(r * m, smax, 3)
        return z, used.any(axis=-1).reshape(r * m), None, sensors, noise.reshape(r * m, smax * md, smax * md)

    return inputs


def run_centralized(scn: ScenarioData, filt: LocalFilter) -> NetworkResult:
    """Paper 0 Algorithm 1 on all nodes' measurements stacked; the result has M = 1.

    A missing measurement gets a variance of :data:`MISSING_VARIANCE` and a zero value, which removes it
    from the update.
    """
    if isinstance(filt, ClutterFilter):
        raise ValueError(f"{filt.name}: clutter filters run per sensor (distributed, 'd' prefix); the paper's "
                         "fusion centre is zentrack.fusion.feedforward.covariance_weighted_fusion")
    if takes_scans(filt):
        raise ValueError(f"{filt.name}: extended-object filters run per sensor (distributed, 'd' prefix); the "
                         "centralized filter (CEOT) is zentrack.study.eot_network (zentrack bench paper4)")
    r, m = scn.runs, scn.nodes
    md = scn.measurements.shape[-1]
    prior = filt.initial_state(scn.x0_estimate, scn.p0, scn.lumped_var)
    static = np.broadcast_to(scn.sensors, (r,) + scn.sensors.shape) if scn.sensor_track is None else None
    noise = np.zeros((m * md, m * md))
    for i in range(m):
        noise[i * md : (i + 1) * md, i * md : (i + 1) * md] = scn.noise_cov[i]
    eye = np.eye(m * md, dtype=bool)
    all_present = bool(scn.present.all())

    def measurements(k: int) -> StepInputs:
        sensors = static if static is not None else np.broadcast_to(scn.sensors_at(k), (r, m, 3))
        z = scn.measurements[:, k].reshape(r, m * md)
        if all_present:
            return z, np.ones(r, dtype=bool), None, sensors, noise
        present = scn.present[:, k]
        missing = np.repeat(~present, md, axis=1)
        noise_k = np.where(missing[:, :, None] & eye, MISSING_VARIANCE, noise)
        return np.where(missing, 0.0, z), np.asarray(present.any(axis=1)), None, sensors, noise_k

    return _run(scn, filt, prior, 1, measurements, None)


def _run(
    scn: ScenarioData,
    filt: LocalFilter,
    prior: GaussianState,
    per_run: int,
    inputs: Callable[[int], StepInputs],
    diffuse: Callable[[GaussianState, int], GaussianState] | None,
    fuse_posterior: bool = False,
    core_inputs: Callable[[int], StepInputs] | None = None,
    isolated: Callable[[int], Array | None] | None = None,
    alone: IsolatedUpdate = isolated_update,
) -> NetworkResult:
    """The step loop shared by both architectures, with a divergence guard per run.  With ``fuse_posterior``
    (a rule with ``fuses_posterior``) the posteriors are fused and the result predicted; else the
    predictions are fused. With ``core_inputs`` (relayed scans) what is fused comes from the prior updated
    with those inputs; the recorded estimate from the prior updated with ``inputs``. ``isolated(k)``: the rows
    whose update at step k is an isolated node's, ``alone`` (None: none).

    A run whose estimates stop being finite (or exceed 1e12) is marked diverged: its outputs from that step
    on are NaN, and its rows restart from the initial prior so the other runs' linear algebra is unaffected.
    """
    r, k_steps = scn.runs, scn.steps
    nk = filt.kinematic_dim
    mean = np.empty((r, k_steps, per_run, nk))
    cov = np.empty((r, k_steps, per_run, nk, nk))
    diverged_at = np.full(r, -1)
    initial = prior.copy()
    state = prior
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for k in range(k_steps):
            post = _update(filt, state, inputs(k), None if isolated is None else isolated(k), alone)
            mean[:, k] = post.mean[:, :nk].reshape(r, per_run, nk)
            cov[:, k] = post.cov[:, :nk, :nk].reshape(r, per_run, nk, nk)
            core = post if core_inputs is None else _update(filt, state, core_inputs(k))
            shared = core if fuse_posterior else filt.predict(core)
            try:
                state = diffuse(shared, k) if diffuse is not None else shared
            except np.linalg.LinAlgError:
                shared = _guard(shared, initial, per_run, diverged_at, k, check_inverse=True)
                state = diffuse(shared, k) if diffuse is not None else shared
            if fuse_posterior:
                state = filt.predict(state)
            state = _guard(state, initial, per_run, diverged_at, k)
    for run in np.flatnonzero(diverged_at >= 0):
        mean[run, diverged_at[run] :] = np.nan
        cov[run, diverged_at[run] :] = np.nan
    return NetworkResult(getattr(filt, "name", "filter"), mean, cov, diverged_at)


def _update(filt: LocalFilter, state: GaussianState, step_inputs: StepInputs, isolated: Array | None = None,
            alone: IsolatedUpdate = isolated_update) -> GaussianState:
    z, present, counts, sensors, noise_k = step_inputs
    if counts is not None:
        return masked_update(filt, state, z, sensors, noise_k, present, counts)
    post = filt.update(state, z, sensors, noise_k) if present.all() else masked_update(
        filt, state, z, sensors, noise_k, present)
    if isolated is None:
        return post
    return update_isolated_rows(filt, state, post, step_inputs[0], sensors, noise_k, present & isolated, alone)


def _guard(
    state: GaussianState, initial: GaussianState, per_run: int, diverged_at: Array, k: int, check_inverse: bool = False
) -> GaussianState:
    diag = np.diagonal(state.cov, axis1=-2, axis2=-1)
    bad = ~(np.abs(state.mean).max(axis=-1) < 1e12) | ~(diag.min(axis=-1) > 0) | ~(diag.max(axis=-1) < 1e24)
    if check_inverse:
        for i in np.flatnonzero(~bad):
            try:
                np.linalg.cholesky(state.cov[i])
            except np.linalg.LinAlgError:
                bad[i] = True
    if not bad.any():
        return state
    runs = np.unique(np.flatnonzero(bad) // per_run)
    newly = runs[diverged_at[runs] < 0]
    diverged_at[newly] = k
    rows = (np.repeat(diverged_at >= 0, per_run))
    return select(rows, initial, state)


def run_filter(
    scn: ScenarioData, name: str, fusion: str | FusionRule = DEFAULT_FUSION, qbar: float = DEFAULT_QBAR,
    theta: float | None = None, params: dict | None = None,
) -> NetworkResult:
    """Run local filter ``name`` (``teskf``, ...) on every run of ``scn`` with ``fusion``: a registered rule name,
    a :class:`~zentrack.fusion.rules.FusionRule`, or :data:`~zentrack.fusion.defaults.CENTRALIZED` (one centre
    with every measurement). The old combined names are read too (``dteskf``: teskf with ``fusion``; ``cteskf``:
    teskf centralized). ``params``: the filter's parameters besides ``qbar``/``theta``."""
    if name in FILTER_REGISTRY:
        kind, arch = name, "centralized" if isinstance(fusion, str) and fusion == CENTRALIZED else "distributed"
    else:
        kind, arch = parse_filter_name(name)
        if arch == "distributed" and isinstance(fusion, str) and fusion == CENTRALIZED:
            raise ValueError(f"{name!r} is distributed; the centralized {kind} is {kind!r} with fusion {CENTRALIZED!r}")
    filt = build_filter(scn, kind, qbar=qbar, theta=theta, params=params)
    res = run_distributed(scn, filt, fusion) if arch == "distributed" else run_centralized(scn, filt)
    res.filter = name
    return res


def scene_extent(scn: ScenarioData) -> Array:
    """Per run, the size of the scene in the first state group's units: the diameter of the set of true
    positions and sensor positions (3-D plants), or of the true values (Experiment 1), at least 3 prior
    standard deviations. A position error beyond it means the filter has lost the target."""
    idx = next(iter(state_groups(scn).values()))
    pos = scn.truth[..., idx]  # (R, K, d)
    if len(idx) == 3:
        sensors = scn.sensors if scn.sensor_track is None else scn.sensor_track.reshape(-1, 3)
        pos = np.concatenate([pos, np.broadcast_to(sensors, (pos.shape[0],) + sensors.shape)], axis=1)
    span = np.linalg.norm(pos.max(axis=1) - pos.min(axis=1), axis=-1)
    prior = 3.0 * np.sqrt(np.trace(scn.p0[np.ix_(idx, idx)]))
    return np.maximum(span, prior)


def evaluate(scn: ScenarioData, result: NetworkResult, bound: Array | None = None) -> dict:
    """Metrics of :func:`zentrack.study.metrics.summarize` for a result against the scenario truth. A run is
    diverged from the first step at which the simulator found non-finite values, or at which its position error
    exceeded the scene (:func:`scene_extent`, :func:`~zentrack.study.metrics.divergence_steps`). With the
    scenario's per-run ``bound`` (:func:`~zentrack.study.pcrlb.scenario_bound`), ``bound_ratio`` gives per group
    and run RMSE / sqrt(bound) (:func:`~zentrack.study.pcrlb.bound_ratio`; inf for a run whose numbers
    stopped being finite)."""
    err = result.errors(scn)
    groups = state_groups(scn)
    idx = next(iter(groups.values()))
    lost = divergence_steps(err, scene_extent(scn), idx)
    out = summarize(err, result.cov, groups, result.diverged_at, lost)
    if bound is not None:
        finite = np.isfinite(err).all(axis=(1, 2, 3))
        out["bound_ratio"] = {g: np.where(finite, bound_ratio(np.nan_to_num(err), bound, ix), np.inf).tolist()
                              for g, ix in groups.items()}
    return out
