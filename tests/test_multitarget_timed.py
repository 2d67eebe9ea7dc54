"""The many-target tracker over scans at their own times (sensors of their own, issue 52): the maths below the node
(``MultiTargetTracker.step_over``, ``NetworkTracker.local_step_over``, two-point initiation over any interval),
on ``mt-async``'s targets and its truth's synchronous scans."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.fusion.linalg import GaussianState
from zentrack.fusion.models import plant_over
from zentrack.fusion.multitarget import TrackStatus
from zentrack.fusion.multitarget.network import NetworkTracker
from zentrack.fusion.scan import Scan
from zentrack.study.multitarget_runs import node_settings

STEPS = 30


@pytest.fixture(scope="module")
def world():
    cfg = resize(load_scenario_config("mt-async", multitarget=True), None, STEPS)
    spec = cfg.spec
    return cfg.multitarget_data(), node_settings(cfg)[0], lambda dt: plant_over(spec.plant, cfg.ts, dt,
                                                                                dict(spec.plant_params))


def test_scans_on_the_grid_give_the_synchronous_tracks_one_prediction_on(world) -> None:
    """The synchronous run is the special case: a lone tracker's scan of step k taken at its time t_k, in the window
    [t_k, t_(k+1)), gives at t_(k+1) the synchronous tracker's tracks of step k predicted one period: the same
    tracks (status, misses, hits) to rounding, through the same association, life cycle and initiation."""
    data, s, over = world
    sync, timed = NetworkTracker(0, s), NetworkTracker(0, s, over=over)
    ts, compared = data.ts, 0
    for k in range(STEPS - 1):
        scan = data.scan(k, 0)
        sync.local_step(k, scan)
        timed.local_step_over(k + 1, k * ts, (k + 1) * ts, [(k * ts, scan)])
        a, b = sync.tracker.tracks, timed.tracker.tracks
        assert [(t.status, t.misses, t.hits) for t in a] == [(t.status, t.misses, t.hits) for t in b], k
        if a:
            ahead = sync.tracker.local_filter.predict(GaussianState(np.stack([t.mean for t in a]),
                                                                    np.stack([t.cov for t in a])))
            np.testing.assert_allclose(np.stack([t.mean for t in b]), ahead.mean, rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(np.stack([t.cov for t in b]), ahead.cov, rtol=1e-12, atol=1e-9)
            compared += sum(t.status is TrackStatus.CONFIRMED for t in a)
    assert compared >= 4 * (STEPS - 8)  # the four targets, confirmed within a few steps


def test_each_scan_is_taken_at_its_own_time(world) -> None:
    """A confirmed track (a neighbour's, taken over) and two sensors' returns of its target at 0.2 s and 0.7 s into
    the window: the track is predicted to 0.2 s, updated, predicted to 0.7 s, updated and predicted to the window's
    end, each over its own interval (computed here by hand with the filter over that interval); taking both at the
    window's end instead gives another estimate."""
    data, s, over = world
    node = NetworkTracker(0, s, over=over)
    node.local_step_over(0, 0.0, 0.0, [])
    x = data.truth_at(10)[1][0]
    node.tracker.initiator.from_prior(x, np.diag([25.0] * 3 + [4.0] * 3), TrackStatus.CONFIRMED)
    t_from, t_to, times = 10.0, 11.0, (10.2, 10.7)
    z = [x[:3] + x[3:] * (t - t_from) + np.array([3.0, -2.0, 1.0]) for t in times]
    scans = [Scan(1, sensor, z[i][None], data.sensors[sensor], data.noise_cov[sensor]) for i, sensor in enumerate((0, 1))]
    node.local_step_over(1, t_from, t_to, list(zip(times, scans)))
    f = node.tracker.local_filter
    state = f.initial_state(x[None], np.diag([25.0] * 3 + [4.0] * 3))
    t = t_from
    for t_scan, scan in zip(times, scans):
        state = node.interval.filter_for(t_scan - t).predict(state)
        state = f.update(state, scan.returns, scan.pose[None, None], scan.noise_cov[None])
        t = t_scan
    state = node.interval.filter_for(t_to - t).predict(state)
    (track,) = node.tracker.tracks
    np.testing.assert_allclose(track.mean, state.mean[0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(track.cov, state.cov[0], rtol=1e-12, atol=1e-9)
    assert track.hits == [True, True] and track.misses == 0
    late = NetworkTracker(0, s, over=over)  # the same returns taken as if measured at the window's end
    late.local_step_over(0, 0.0, 0.0, [])
    late.tracker.initiator.from_prior(x, np.diag([25.0] * 3 + [4.0] * 3), TrackStatus.CONFIRMED)
    late.local_step_over(1, t_from, t_to, [(t_to, sc) for sc in scans])
    assert np.linalg.norm(late.tracker.tracks[0].mean[:3] - track.mean[:3]) > 1.0


def test_a_target_is_started_from_one_sensors_two_scans_whatever_their_interval(world) -> None:
    """Two-point initiation over the interval between a sensor's scans: a target seen 0.25 s and then 0.5 s apart
    (a 4 Hz sensor, one scan lost) starts a track whose velocity is the difference over that interval."""
    data, s, over = world
    node = NetworkTracker(0, s, over=over)
    x = data.truth_at(0)[1][0]
    pos = lambda t: x[:3] + x[3:] * t  # noqa: E731
    scan = lambda k, t: Scan(k, 0, pos(t)[None], data.sensors[0], data.noise_cov[0])  # noqa: E731
    node.local_step_over(0, 0.0, 0.0, [])
    node.local_step_over(1, 0.0, 1.0, [(0.25, scan(1, 0.25)), (0.75, scan(1, 0.75))])
    (track,) = node.tracker.tracks  # born at 0.75 s of the pair (0.25, 0.75), predicted to 1.0 s
    np.testing.assert_allclose(track.mean[3:6], x[3:], atol=1e-9)
    np.testing.assert_allclose(track.mean[:3], pos(1.0), atol=1e-9)
    assert track.status is TrackStatus.TENTATIVE and track.hits == [True]
    empty = NetworkTracker(0, s, over=over)  # a window no sensor looked in records nothing; an empty scan a miss
    empty.local_step_over(0, 0.0, 0.0, [])
    empty.local_step_over(1, 0.0, 1.0, [(0.25, scan(1, 0.25)), (0.75, scan(1, 0.75))])
    empty.local_step_over(2, 1.0, 2.0, [])
    assert empty.tracker.tracks[0].hits == [True]
    empty.local_step_over(3, 2.0, 3.0, [(2.5, Scan(3, 0, np.zeros((0, 3)), data.sensors[0], data.noise_cov[0]))])
    assert empty.tracker.tracks[0].hits == [True, False] and empty.tracker.tracks[0].misses == 1


def test_a_node_on_the_runs_grid_refuses_a_step_over_times(world) -> None:
    data, s, _ = world
    with pytest.raises(ValueError, match="plant over any interval"):
        NetworkTracker(0, s).local_step_over(0, 0.0, 0.0, [])


def test_a_neighbours_target_is_taken_over_at_the_lists_time_and_predicted_with_the_window(world) -> None:
    """A neighbour's confirmed track in the list of step 1 (valid at 1 s) that this node does not hold joins at the
    next window's start, 1 s, and is predicted with the window to 2 s: once, not once more for a step."""
    from zentrack.fusion.track_to_track import TrackEstimate, TrackId

    data, s, over = world
    node = NetworkTracker(0, s, over=over)
    node.local_step_over(0, 0.0, 0.0, [])
    node.local_step_over(1, 0.0, 1.0, [])
    x, cov = data.truth_at(1)[1][0], np.diag([25.0] * 3 + [4.0] * 3)
    node.fuse({1: [TrackEstimate(TrackId(0, 1, 7), x, cov, "confirmed", 1, 0)]})
    node.local_step_over(2, 1.0, 2.0, [])
    (track,) = node.tracker.tracks
    f = node.tracker.local_filter
    once = f.predict(f.initial_state(x[None], cov))
    np.testing.assert_allclose(track.mean, once.mean[0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(track.cov, once.cov[0], rtol=1e-12, atol=1e-9)
    assert node.ids[track.id] == TrackId(0, 1, 7) and track.status is TrackStatus.CONFIRMED
    assert track.misses == 1  # (no sensor looked in its window: one step more since its holder measured it)
