"""The posterior Cramér–Rao bound of a scenario (study/pcrlb.py ``scenario_bound``) and RMSE / sqrt(bound)."""
from __future__ import annotations

import numpy as np

from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.models import make_plant
from zentrack.study.pcrlb import bound_ratio, scenario_bound
from zentrack.study.simulator import evaluate, run_filter
from zentrack.truth.simulation.simulate import simulate


def _kalman_covariances(a, q, h, r_list, p0, present):
    """The Kalman filter's posterior covariance recursion, written out: predict, then one update per sensor that
    measured (independent noise: informations add)."""
    out, p = [], None
    for k in range(present.shape[0]):
        p = p0 if k == 0 else a @ p @ a.T + q
        info = np.linalg.inv(p)
        for s, r in enumerate(r_list):
            if present[k, s]:
                info = info + h.T @ np.linalg.inv(r) @ h
        p = np.linalg.inv(info)
        out.append(p)
    return np.array(out)


def test_the_bound_is_the_kalman_covariance_on_a_linear_gaussian_model_with_missing_measurements():
    scn = simulate(builtin_spec("exp1", nodes=3, steps=60), runs=2, seed=5)
    scn.present = scn.present.copy()
    scn.present[0, 10:20, 1] = False  # node 1 misses ten scans in run 0
    scn.present[1, 5, :] = False  # and nobody measures at step 5 of run 1
    plant = make_plant(scn.plant, scn.ts, scn.plant_params)
    bound = scenario_bound(scn)
    for run in range(2):
        expected = _kalman_covariances(plant.A, plant.Q, scn.linear_matrix, list(scn.noise_cov), scn.p0,
                                       scn.present[run])
        np.testing.assert_allclose(bound[run], expected, rtol=1e-9, atol=1e-12)
    assert not np.allclose(bound[0], bound[1])  # the missing scans show


def test_more_sensors_never_raise_the_bound():
    scn = simulate(builtin_spec("exp2", nodes=5, steps=80), runs=2, seed=1)
    bounds = [scenario_bound(scn, list(range(n))) for n in (1, 2, 3, 5)]
    for fewer, more in zip(bounds, bounds[1:]):
        gap = np.linalg.eigvalsh(fewer - more)  # Loewner order: fewer sensors, larger bound
        assert gap.min() >= -1e-9 * np.abs(fewer).max(), gap.min()
    assert np.trace(bounds[0][:, -1, :3, :3], axis1=1, axis2=2).min() > \
        10 * np.trace(bounds[-1][:, -1, :3, :3], axis1=1, axis2=2).max()  # one bearing sensor alone: far worse


def test_centralized_filters_sit_at_the_bound_and_the_diffusion_filter_above_it():
    """Paper 0 Experiment 2, RMSE_p / sqrt(bound) per run: the centralized UKF about 1, single-round CI
    diffusion (DTESKF) clearly above. Ratios below 1 would mean the bound is wrong."""
    scn = simulate(builtin_spec("exp2", nodes=10, steps=300), runs=4, seed=0)
    bound = scenario_bound(scn)
    central = bound_ratio(run_filter(scn, "cukf").errors(scn), bound, [0, 1, 2])
    diffusion = bound_ratio(run_filter(scn, "dteskf").errors(scn), bound, [0, 1, 2])
    assert np.all((central > 0.85) & (central < 1.3)), central
    assert np.all(diffusion > 1.4 * central), (diffusion, central)
    metrics = evaluate(scn, run_filter(scn, "dteskf"), bound)
    np.testing.assert_allclose(metrics["bound_ratio"]["p"], diffusion)


def test_with_nonlinear_dynamics_the_bound_uses_the_jacobian_along_each_run():
    """pcrlb_per_run with F given as a function: F(x) constant is the linear recursion; the ship's F(x_k) along
    each run is what scenario_bound uses for paper 3's plants, and it differs between runs."""
    from zentrack.config.scenario_config import load_scenario_config
    from zentrack.fusion.models import make_measurement
    from zentrack.study.pcrlb import pcrlb_per_run

    scn = simulate(builtin_spec("exp2", nodes=3, steps=30), runs=2, seed=3)
    plant = make_plant(scn.plant, scn.ts, scn.plant_params)
    args = (scn.sensors, plant.A, plant.Q, scn.p0, scn.noise_cov)
    linear = pcrlb_per_run(scn.truth, *args)
    as_function = pcrlb_per_run(scn.truth, scn.sensors, lambda x: np.broadcast_to(plant.A, (len(x), 6, 6)),
                                *args[2:])
    np.testing.assert_allclose(as_function, linear, rtol=1e-12)

    cfg = load_scenario_config("seckf-turn")
    ship = simulate(cfg.spec, runs=3, seed=1, ts=cfg.ts)
    motion = make_plant(ship.plant, ship.ts, ship.plant_params)
    bound = scenario_bound(ship)
    track = ship.sensor_track
    for r in range(3):  # the recursion written out for one run with the Jacobian at its own true states
        p = ship.p0
        for k in range(ship.steps):
            if k:
                f = motion.jacobian(ship.truth[r, k - 1][None])[0]
                p = f @ p @ f.T + motion.Q
            h = make_measurement(ship.measurement).jacobian(ship.truth[r, k][None], track[k][None])[0]
            h = h.reshape(-1, 5)
            p = np.linalg.inv(np.linalg.inv(p) + h.T @ np.linalg.inv(ship.noise_cov[0]) @ h)
        np.testing.assert_allclose(bound[r, -1], p, rtol=1e-6, atol=1e-9 * np.abs(p).max())
    assert not np.allclose(bound[0, -1], bound[1, -1])
