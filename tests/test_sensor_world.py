"""What a sensor of its own reports of a world with many targets or clutter (issue 52): at its own times, the
targets present and in view interpolated to them, each detected with P_D, measured with its noise, among the
scenario's clutter, drawn by the code that draws the synchronous truth's scans (``sensor_stream.py``)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from zentrack.config import catalogue
from zentrack.config.scenario_config import parse
from zentrack.fusion.measurement import bearing, wrap_angle
from zentrack.truth.simulation.sensor_stream import (
    interpolate,
    multitarget_stream,
    sample_times,
    sensor_stream,
    state_at,
)

#: a return within this distance (m) of a target's position at its scan's time is that target's: 5 m of noise per
#: axis puts a target's own return beyond it with probability 1e-7 (chi-square, 3 dof, 46.5), and the 5 clutter
#: returns a scan scatters over a 2.5 km ball within it with 5 (34 / 2500)^3 = 1.3e-5
MATCH_M = 34.0


def mt_async():
    from zentrack.config.scenario_config import load_scenario_config

    cfg = load_scenario_config("mt-async", multitarget=True)
    return cfg, cfg.multitarget_data()


def scans_of(cfg, data, sensor: int, **change):
    spec = replace(cfg.sensor_timing.stream(sensor), **change)
    return spec, multitarget_stream(data, cfg.multitarget, float(cfg.spec.noise_levels()[sensor]), spec, cfg.seed)


def split(data, scans):
    """Each scan's returns split into the targets' (their errors against the truth at the scan's time) and the
    rest; how many targets were present (all are in view: all round, 2.5 km)."""
    t = np.array([d.t for d in scans])
    truth, present = interpolate(data.truth, data.ts, t, hermite=True)
    errors, clutter, targets = [], [], 0
    for n, d in enumerate(scans):
        live = truth[n, present[n], :3]
        targets += live.shape[0]
        dist = np.linalg.norm(d.returns[:, None, :] - live[None], axis=-1)  # (returns, targets)
        near = dist.min(axis=1, initial=np.inf) <= MATCH_M if live.size else np.zeros(len(d.returns), dtype=bool)
        errors += [d.returns[j] - live[dist[j].argmin()] for j in np.flatnonzero(near)]
        clutter.append(int((~near).sum()))
    return np.array(errors), np.array(clutter), targets


def test_a_many_target_sensor_samples_every_target_at_its_own_times_with_pd_noise_and_poisson_clutter() -> None:
    """Sensor 0 of mt-async (4 Hz, phase 0): 237 scans over 60 s. The targets' returns are the truth at each scan's
    own time plus 5 m of noise per axis (the interpolated truth: taking the last step's instead would add up to
    0.75 s at 10 m/s), detected at P_D = 0.9; the rest is Poisson clutter of mean 5 per scan."""
    cfg, data = mt_async()
    spec, scans = scans_of(cfg, data, 0)
    np.testing.assert_allclose([d.t for d in scans], sample_times(data.steps, data.ts, spec))
    assert len(scans) == 237 and scans[1].t - scans[0].t == pytest.approx(0.25)
    errors, clutter, targets = split(data, scans)
    assert abs(len(errors) / targets - 0.9) < 0.03, len(errors) / targets  # 948 chances: sd 0.01
    assert abs(np.mean(errors**2) / 25.0 - 1) < 0.08, np.mean(errors**2)  # 2560 squares: sd 0.028
    assert abs(np.mean(errors)) < 0.5
    assert abs(clutter.mean() - 5.0) < 0.45 and abs(clutter.var() / clutter.mean() - 1) < 0.3  # Poisson: var = mean
    # at a step's time the interpolation is the step's truth; between, the returns follow the targets' motion
    t, _ = interpolate(data.truth, data.ts, np.array([4.0, 4.5]), hermite=True)
    np.testing.assert_array_equal(t[0], data.truth[4])
    np.testing.assert_allclose(t[1, :, :3], 0.5 * (data.truth[4, :, :3] + data.truth[5, :, :3]), atol=0.01)
    stale = [d.returns for d in scans if d.t % 1.0 >= 0.5]  # against the step before: their errors grow
    before = [data.truth[int(d.t), :, :3] for d in scans if d.t % 1.0 >= 0.5]
    far = [np.linalg.norm(z[:, None] - x[None], axis=-1).min(axis=1) for z, x in zip(stale, before)]
    assert np.median(np.concatenate(far)[np.concatenate(far) < MATCH_M]) > np.median(np.linalg.norm(errors, axis=1))


def test_the_sensors_detection_prob_multiplies_the_scenarios_pd_and_a_target_absent_is_never_seen() -> None:
    cfg, data = mt_async()
    _, scans = scans_of(cfg, data, 2, detection_prob=0.5)  # 1 Hz: 60 scans, 240 chances
    errors, _, targets = split(data, scans)
    assert abs(len(errors) / targets - 0.45) < 0.1, len(errors) / targets
    gone = data.truth.copy()
    gone[30:, 1:] = np.nan  # three targets leave at step 30
    _, present = interpolate(gone, data.ts, np.array([29.0, 29.5, 30.0]), hermite=True)
    assert present.tolist() == [[True] * 4, [True, False, False, False], [True, False, False, False]]


def test_the_same_sensor_draws_the_same_scans_and_another_its_own() -> None:
    cfg, data = mt_async()
    a, b, c = scans_of(cfg, data, 1)[1], scans_of(cfg, data, 1)[1], scans_of(cfg, data, 4)[1]
    assert all(np.array_equal(x.returns, y.returns) and x.t_publish == y.t_publish for x, y in zip(a, b))
    assert not all(x.returns.shape == y.returns.shape and np.allclose(x.returns, y.returns) for x, y in zip(a, c))


@pytest.mark.parametrize(("mode", "clutter_line"), [("fixed", "count = 10"), ("poisson", "density = 40.0")])
def test_a_sensor_in_clutter_reports_its_target_among_the_scenarios_clutter(mode, clutter_line) -> None:
    """fpf-clutter with sensors of their own, 4 Hz (its truth every 0.5 s): each scan holds the target's bearing at
    the scan's time with P_D = 1 (the one return within 5 sigma of it) among clutter uniform over the sensor's window,
    a fixed 10 or Poisson of the window's area times the density."""
    text = (catalogue.text("fpf-clutter") or "").replace('mode = "fixed"', f'mode = "{mode}"')
    text = text.replace("count = 10", clutter_line) + "\n[sensor_timing]\nrate_hz = 4.0\nlag_ms = 300.0\n"
    cfg = parse("fpf-async.toml", text)
    scn = cfg.scenario_data()
    spec = cfg.sensor_timing.stream(1)
    scans = sensor_stream(scn, spec, cfg.seed, 0, cfg.spec.clutter)
    assert len(scans) == 399  # (0 to 99.5 s, its last step, at 4 Hz)
    t = np.array([d.t for d in scans])
    truth = bearing(state_at(scn, 0, t), np.broadcast_to(scn.sensors[1], (t.size, 1, 3)))  # (N, 2)
    sigma = float(np.sqrt(scn.noise_cov[1, 0, 0]))
    az, el = cfg.spec.clutter.windows(scn.nodes)
    nearest = np.array([np.abs(wrap_angle(d.returns - z)).max(axis=1).min() for d, z in zip(scans, truth)])
    # P_D = 1: its target in every scan (the median of the larger of two N(0, sigma^2) errors is 1.05 sigma)
    assert (nearest <= 5 * sigma).all() and np.median(nearest) < 1.3 * sigma
    for d in scans:  # every return within the sensor's window (the target's bearings lie in it)
        assert ((d.returns[:, 1] >= el[1, 0] - 5 * sigma) & (d.returns[:, 1] <= el[1, 1] + 5 * sigma)).all()
    counts = np.array([len(d.returns) for d in scans]) - 1  # less the target's
    if mode == "fixed":
        assert (counts == 10).all()
    else:  # Poisson of the window's area times the density: about 2.2 a scan, the variance its mean
        expected = 40.0 * cfg.spec.clutter.area(scn.nodes)[1]
        assert abs(counts.mean() / expected - 1) < 0.15 and abs(counts.var() / counts.mean() - 1) < 0.3, counts.mean()


def test_the_sensor_process_draws_the_world_of_its_scenario(tmp_path) -> None:
    """``zentrack sensor``'s scans (``truth/sensor.py``, ``simulated``): many targets for mt-async, its position and
    one return's noise; the target among the scenario's clutter for fpf-clutter with sensors of their own."""
    from zentrack.cli import build_parser
    from zentrack.config.run_setup import resolve_setup
    from zentrack.truth.sensor import simulated, stream_spec

    def setup_of(scenario: str):
        argv = ["sensor", "--id", "0", "--scenario", scenario]
        return resolve_setup(build_parser(argv).parse_args(argv))

    s = setup_of("mt-async")
    data = s.multitarget_data
    stream, pose, cov = simulated(s, stream_spec(s, 3))
    ref = multitarget_stream(data, s.multitarget, 5.0, s.sensor_timing.stream(3), s.seed)
    assert len(stream) == len(ref) and all(np.array_equal(a.returns, b.returns) for a, b in zip(stream, ref))
    np.testing.assert_array_equal(pose, data.sensors[3])
    np.testing.assert_array_equal(cov, 25.0 * np.eye(3))
    path = tmp_path / "fpf-async.toml"
    path.write_text((catalogue.text("fpf-clutter") or "") + "\n[sensor_timing]\nrate_hz = 4.0\nlag_ms = 300.0\n")
    stream, pose, cov = simulated(setup_of(str(path)), stream_spec(setup_of(str(path)), 2))
    assert all(len(d.returns) == 11 for d in stream) and cov.shape == (2, 2)  # the target and a fixed 10 of clutter
