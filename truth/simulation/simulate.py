"""One or more simulated runs of a scenario: :func:`simulate` draws R independent runs of a
:class:`~zentrack.truth.simulation.scenario_spec.ScenarioSpec` (truth states, every node's measurements, initial
estimates) into a :class:`~zentrack.truth.simulation.scenario.ScenarioData`. Run r uses its own child of
``SeedSequence(seed)``, so it is identical whatever R is.

A scenario with a recorded ``trajectory`` (issue 34) has one truth for every run: the selected target's recorded
states (:func:`recorded_path`), the same path each run with that run's own measurement noise and initial
estimate (drawn from ``p0`` around the recorded state at step 0). The target must be present at every step
(one segment of its reports covering every scan time, inside the region): otherwise a ValueError in one line
names the scenario, the target and the first step it is absent. A patrol ``trajectory``
(:mod:`~zentrack.truth.simulation.patrol`) draws each run's path from a seed stream of its own.
"""
from __future__ import annotations

import numpy as np

from zentrack.fusion.measurement import wrap_angle
from zentrack.fusion.models import NONLINEAR_TRUTH, make_measurement, make_plant
from zentrack.fusion.motion_ca import apply_acceleration_schedule

from .clutter import generate_clutter_scans
from .eot_scenario import simulate_extent
from .patrol import PatrolSpec, patrol_paths
from .recorded.recording import RecordingSpec, recorded_targets
from .scenario import ScenarioData
from .scenario_spec import ScenarioSpec, check_roles, default_roles, graph_weights

Array = np.ndarray

#: the clutter draws of run r come from child r of ``SeedSequence(seed + CLUTTER_SEED_OFFSET)``: a stream of
#: their own, so adding clutter to a scenario leaves its truth and target returns as they were
CLUTTER_SEED_OFFSET = 1_000_003


def _rows_times(mat: Array, rows: Array) -> Array:
    """``rows @ mat.T`` computed row by row with element-wise products (independent of the batch size)."""
    return (rows[:, None, :] * mat[None, :, :]).sum(axis=-1)


def recorded_path(spec: ScenarioSpec, ts: float) -> Array:
    """The states ``(K, 6)`` (ENU position and velocity) of the one target ``spec.trajectory`` selects, at the
    scenario's ``K`` steps ``ts`` apart; ValueError (one line naming the scenario, the target and the first absent
    step) unless exactly one target matches and it is present at every step."""
    rec = spec.trajectory
    assert isinstance(rec, RecordingSpec)
    steps = spec.steps
    where = f"{spec.name}: [trajectory] {rec.source}"
    wanted = rec.select[0] if len(rec.select) == 1 else list(rec.select)
    got = recorded_targets(rec, steps, ts)
    if len(got.ids) > 1:
        raise ValueError(f"{where}: select {wanted!r} matches {len(got.ids)} targets ({', '.join(got.ids)}): "
                         "select one by its id")
    if not got.ids:
        if got.stats.get("targets_read", 0) == 0:
            why = "no report of it within the steps"
        elif got.stats.get("still_targets", 0):
            why = f"it stays within min_extent {rec.min_extent:g} m: at anchor, moored or parked"
        else:
            why = "outside the region or silent at every step"
        raise ValueError(f"{where}: target {wanted!r} is absent from step 0 (of {steps}; {why}): choose "
                         "[trajectory] start and [scenario] steps within its track")
    absent = np.flatnonzero(~got.alive[:, 0])
    if absent.size:
        k = int(absent[0])
        raise ValueError(f"{where}: target {got.labels[0]!r} ({got.ids[0]}) is absent at step {k} of {steps} "
                         f"(t = {rec.start + k * ts:g} s after the recording's first report: no report within "
                         "max_gap, or outside the region): choose [trajectory] start and [scenario] steps within its "
                         "track")
    return np.asarray(got.truth[:, 0], dtype=float)


def trajectory_paths(spec: ScenarioSpec, runs: int, seed: int, ts: float) -> Array | None:
    """Every run's path ``(runs, K, 6)`` when ``spec`` has a ``trajectory`` (a recording's: the same in every run;
    a patrol's: run r's own), else None (the plant simulates the truth)."""
    if spec.trajectory is None:
        return None
    if isinstance(spec.trajectory, PatrolSpec):
        return patrol_paths(spec.trajectory, runs, spec.steps, ts, seed)
    return np.broadcast_to(recorded_path(spec, ts)[None], (runs, spec.steps, 6))


def simulate(spec: ScenarioSpec, runs: int = 1, seed: int = 0, ts: float = 0.1) -> ScenarioData:
    """Draw ``runs`` independent runs of ``spec``; run r is reproducible from (seed, r) alone."""
    spec.validate()
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    if spec.extent is not None:
        return simulate_extent(spec, runs, seed, ts)
    plant = make_plant(spec.plant, ts, spec.plant_params)
    meas = make_measurement(spec.measurement, spec.linear_matrix)
    n, k_steps, m_nodes, m = plant.dim, spec.steps, spec.nodes, meas.dim
    path = trajectory_paths(spec, runs, seed, ts)
    x0 = np.broadcast_to(np.asarray(spec.x0 if path is None else path[:, 0], dtype=float), (runs, n))
    process_noise = np.empty((runs, k_steps, n))
    meas_noise = np.empty((runs, k_steps, m_nodes, m))
    x0_est = np.empty((runs, n))
    noise_factor = getattr(plant, "noise_factor", None)  # a rank-deficient Q (ca9) has its own square root
    l_q = np.linalg.cholesky(plant.Q) if noise_factor is None else noise_factor
    l_p0 = np.linalg.cholesky(spec.p0)
    stds = spec.noise_levels()
    scale = float(stds[0]) if spec.noise_stds is None else stds[:, None]
    for r, child in enumerate(np.random.SeedSequence(seed).spawn(runs)):
        rng = np.random.default_rng(child)
        process_noise[r] = rng.standard_normal((k_steps, l_q.shape[1])) @ l_q.T
        meas_noise[r] = scale * rng.standard_normal((k_steps, m_nodes, m))
        x0_est[r] = x0[r] + l_p0 @ rng.standard_normal(n)
    truth = np.empty((runs, k_steps, n))
    lumped = np.empty((runs, k_steps, plant.lumped_dim))
    x = x0.copy()
    for k in range(k_steps):
        if path is not None:  # the recorded or patrol path
            x = path[:, k].copy()
        elif spec.accel_schedule is not None:
            x = apply_acceleration_schedule(x, spec.accel_schedule, k * ts)
        truth[:, k] = x
        lumped[:, k] = plant.true_lumped(x, k)
        if path is not None:
            continue
        if spec.plant in NONLINEAR_TRUTH:
            x = plant.f(x) + process_noise[:, k]
        else:  # row-wise products (not BLAS) so run r's truth is bit-identical whatever R is
            x = _rows_times(plant.A, x) + _rows_times(plant.B, lumped[:, k]) + process_noise[:, k]
    sensors = np.asarray(spec.sensors, dtype=float)
    track = spec.sensor_track(k_steps, ts)
    flat_truth = truth.reshape(runs * k_steps, n)
    if track is None:
        z = meas.h(flat_truth, np.broadcast_to(sensors, (runs * k_steps,) + sensors.shape))
    else:
        z = meas.h(flat_truth, np.broadcast_to(track, (runs,) + track.shape).reshape(runs * k_steps, m_nodes, 3))
    z = z.reshape(runs, k_steps, m_nodes, m) + meas_noise
    if spec.measurement == "bearing":
        z = wrap_angle(z)
    adj, weights = graph_weights(spec)
    roles = default_roles(m_nodes) if spec.roles is None else check_roles(spec.roles, m_nodes)
    present = np.ones((runs, k_steps, m_nodes), dtype=bool)
    present[:, :, roles == "relay"] = False  # after every draw: the random numbers do not depend on roles
    noise_cov = (stds**2)[:, None, None] * np.eye(m)
    scan_returns = scan_counts = scan_target = None
    if spec.clutter is not None:
        drawn = generate_clutter_scans(truth, sensors, noise_cov[0], spec.clutter, seed + CLUTTER_SEED_OFFSET)
        relay = roles == "relay"
        drawn.counts[:, :, relay] = 0
        drawn.target_index[:, :, relay] = -1
        returns = np.where(np.arange(drawn.returns.shape[3])[:, None] < drawn.counts[..., None, None],
                           drawn.returns, 0.0)
        # the target's return where it was detected: what one-return filters and the evaluation use
        found = drawn.target_index >= 0
        picked = np.take_along_axis(returns, np.maximum(drawn.target_index, 0)[..., None, None], axis=3)[..., 0, :]
        z = np.where(found[..., None], picked, 0.0)
        present = found
        scan_returns, scan_counts, scan_target = returns, drawn.counts, drawn.target_index
    return ScenarioData(
        name=spec.name,
        plant=spec.plant,
        plant_params=dict(spec.plant_params),
        measurement=spec.measurement,
        ts=ts,
        truth=truth,
        lumped=lumped,
        sensors=sensors,
        measurements=z,
        present=present,
        noise_cov=noise_cov,
        adjacency=adj,
        weights=weights,
        x0_estimate=x0_est,
        p0=np.asarray(spec.p0, dtype=float),
        lumped_var=spec.lumped_var,
        seed=seed,
        linear_matrix=None if spec.linear_matrix is None else np.asarray(spec.linear_matrix, dtype=float),
        roles=roles,
        scan_returns=scan_returns,
        scan_counts=scan_counts,
        scan_target=scan_target,
        sensor_track=track,
    )
