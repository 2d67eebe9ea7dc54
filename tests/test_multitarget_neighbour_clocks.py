"""A many-target tracker on its own clock against its neighbours' (issue 52, item 3): ``mt-async``'s node 0 under its
real schedule with an injected clock, handed neighbour 1's track lists as a neighbour whose clock is ``o`` off
publishes them (``node/track_lists/admission.py``, ``node/diffusion/neighbour_clocks.py``); the per-track
prediction over an interval (``NetworkTracker.predicted_over``); and the recorder judging a list at its time of
validity (``cluster/recording/track_lists.py``). tests/test_multitarget_async_live.py runs it live, with one
tracker's host clock off."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from zentrack.cluster.recording.track_lists import TrackLists
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.fusion.models import plant_over
from zentrack.fusion.multitarget.network import NetworkTracker
from zentrack.fusion.track_to_track import TrackEstimate, TrackId
from zentrack.node.schedule import NodeSchedule
from zentrack.node.track_lists.payload import list_allowance_s, tracker_settings
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Start
from zentrack.transport.track_messages import TrackList
from zentrack.truth.simulation.sensor_stream import multitarget_truth_at

T0, STEPS, KEYS = 1000.0, 40, Keys("w")
#: the list's way from neighbour 1 (s): what its clock samples carry on top of the offset
DELAY = 0.002
P0, V = np.array([100.0, -50.0, 200.0]), np.array([10.0, 2.0, -1.0])


def setup():
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    return resolve_setup(p.parse_args(["--scenario", "mt-async", "--steps", str(STEPS)]))


def node_0():
    """Node 0 of mt-async taking its own sensor, its neighbours' clocks estimated; its clock is ``now[0]``."""
    s = setup()
    timing = s.sensor_timing
    cfg = s.node_config(0)
    cfg.detections = {"lag_ms": timing.lag_ms, "clock": "estimated", "sensors": [
        {"sensor": 0, "rate_hz": timing.stream(0).rate_hz, "offset_s": None,
         "min_latency_s": timing.stream(0).latency.low_s}]}
    cfg.validate()
    now = [T0 - 0.5]
    node = NodeSchedule.track_lists(KEYS, cfg, lambda: now[0], lambda ch, b: None)
    node.handle(Message("alive", KEYS.alive("truth"), b"put", now[0]))
    node.handle(Message("start", KEYS.start, Start(T0, 1.0, STEPS, "realtime", tuple(range(8)), 0.5,
                                                   np.zeros(6)).encode(), now[0]))
    return node, now, cfg


def target_at(t: float) -> TrackEstimate:
    """One confirmed track of a target moving at V, exactly where it is ``t`` s after t0 (true time)."""
    return TrackEstimate(TrackId(0, 1, 7), np.concatenate([P0 + V * t, V]), np.diag([4.0] * 3 + [1.0] * 3))


def send_list(node, now, k: int, offset: float, t_valid: float | None = None) -> None:
    """Neighbour 1, whose clock is ``offset`` ahead of node 0's, publishes its list of its step k when its clock
    says ``t0 + k + lag``: its track is where the target is at its step's time on its clock (``k - offset`` on
    node 0's, the true time); node 0 receives it DELAY later."""
    lag = node.payload.ctx.timing.budget
    t_pub = T0 + k + lag  # (its clock)
    now[0] = t_pub - offset + DELAY
    lst = TrackList.of(k, k * 1.0 if t_valid is None else t_valid, 1, [target_at(k - offset)], t_pub)
    node.payload.intake.track_list(Message("tracks", KEYS.tracks(1), lst.encode(), now[0]),
                                   node.payload.ctx.timing.k_now(now[0]))


@pytest.mark.parametrize("offset, shift", [(0.3, 0), (-0.3, 0), (-0.6, -1), (0.0, 0), (1.2, 1)])
def test_a_neighbours_list_is_taken_for_the_step_of_its_time_and_predicted_to_it(offset, shift) -> None:
    """A neighbour 0.3 s ahead or behind: its list of step k is node 0's of step k, predicted over the offset (back,
    when it is behind: it is waited for, ``list_allowance_s``, 0.4 s here); 0.6 s behind, its list of step k - 1 is
    node 0's of step k, predicted 0.4 s forward; 1.2 s ahead, its list of k + 1 predicted 0.2 s forward; a clock
    within the dead band, as it is. Each time the entry is where the target is at node 0's step time, to the
    micrometre, less the list's delay (2 ms: the estimate of the offset is low by it)."""
    node, now, cfg = node_0()
    assert list_allowance_s(cfg.ts, cfg.deadline_frac) == pytest.approx(0.4)
    intake, clocks = node.payload.intake, node.payload.clocks
    for k in range(2, 20):
        send_list(node, now, k, offset)
    assert clocks.report()["1"] == pytest.approx(offset - DELAY if abs(offset) > 0.01 else 0.0, abs=1e-9)
    assert clocks.shift(1) == shift
    for k in range(2 - shift, 20 - shift):  # node 0's steps (each list held for it)
        held = intake.lists.get(k)[1]
        [entry] = held
        assert entry.step == k and entry.id == TrackId(0, 1, 7)
        behind = DELAY if abs(offset) > 0.01 else 0.0  # (the estimate is low by the delay: the entry that early)
        np.testing.assert_allclose(entry.mean[:3], P0 + V * (k - behind), atol=1e-6)
        moved = abs(offset - shift)  # how far it was predicted: its covariance grows by the process noise of that
        grown = np.trace(entry.cov) - np.trace(target_at(0.0).cov)
        assert (grown > np.trace(entry.cov) * 1e-4) if moved > 0.01 else grown >= 0.0


def test_a_list_remapped_when_the_offset_moves_by_a_period_takes_the_held_ones_place() -> None:
    """A neighbour's clock estimated 0.55 s ahead (its step k is node 0's k), then 0.65 s (k + 1 is node 0's k: the
    shift moves once the offset leaves its period by the hysteresis): its next list maps to a step it already gave
    a list for, and takes its place, no duplicate refused."""
    node, now, _ = node_0()
    intake, clocks = node.payload.intake, node.payload.clocks
    for k in range(2, 12):
        send_list(node, now, k, 0.55)
    assert clocks.shift(1) == 0 and 1 in intake.lists.get(11)
    for n in range(200):  # its clock moves on: enough samples that the window's low quantile is 0.65 s
        clocks.observe(1, T0 + n, T0 + n + 0.65, ("moved", n))
    assert clocks.shift(1) == 1
    send_list(node, now, 12, 0.65)  # node 0's step 11, held already from its list of step 11
    [entry] = intake.lists.get(11)[1]
    np.testing.assert_allclose(entry.mean[:3], P0 + V * 11, atol=0.05)
    assert intake.sender_step[(11, 1)] == 12


def test_a_list_that_says_another_time_than_its_step_is_refused() -> None:
    node, now, _ = node_0()
    with pytest.raises(WireError) as err:
        send_list(node, now, 3, 0.3, t_valid=3.5)
    assert err.value.reason == "schema" and "valid at 3.5" in str(err.value)


@pytest.mark.parametrize("dt", [0.3, -0.3, 0.7])
def test_entries_predicted_over_an_interval_move_with_their_velocity_and_lose_information(dt) -> None:
    """``predicted_over``: the mean moved by ``V dt`` (either way), the covariance grown whichever way (the process
    noise of ``|dt|``: an estimate carried back is no surer), the ids, statuses and misses kept, the step set."""
    s = setup()
    cfg = s.node_config(0)
    network = NetworkTracker(0, tracker_settings(cfg),
                             over=lambda d: plant_over(cfg.plant, cfg.ts, d, cfg.plant_params))
    a, b = target_at(2.0), TrackEstimate(TrackId(3, 2, 1), np.array([0.0, 0, 0, -5, 0, 0]), np.eye(6), "tentative", 4,
                                         misses=2)
    got = network.predicted_over([a, b], dt, 9)
    np.testing.assert_allclose(got[0].mean, np.concatenate([P0 + V * (2.0 + dt), V]), atol=1e-9)
    np.testing.assert_allclose(got[1].mean[:3], [-5 * dt, 0, 0], atol=1e-9)
    for before, after in zip((a, b), got):
        assert (after.id, after.status, after.misses, after.step) == (before.id, before.status, before.misses, 9)
        assert np.all(np.linalg.eigvalsh(after.cov[3:, 3:] - before.cov[3:, 3:]) > 0)  # the velocity's noise
    assert network.predicted_over([], dt, 9) == []
    with pytest.raises(ValueError, match="over="):
        NetworkTracker(0, tracker_settings(cfg)).predicted_over([a], dt, 9)


def test_the_recorder_judges_a_tracker_on_its_own_clock_at_its_lists_time_of_validity() -> None:
    """Lists holding every target exactly where it is 0.3 s before each step (a tracker whose clock is 0.3 s ahead):
    judged at their time of validity, GOSPA 0; judged at the step (a run on one clock), the targets' 0.3 s of
    motion (3 m at 10 m/s)."""
    data = setup().multitarget_data
    judged = {}
    for at_validity in (True, False):
        part = TrackLists(data, at_validity=at_validity)
        for k in range(5, 20):
            states, present = multitarget_truth_at(data, np.array([k - 0.3]))
            ids = np.flatnonzero(present[0])
            tracks = [TrackEstimate(TrackId(0, 2, int(i)), states[0, i], np.eye(6)) for i in ids]
            part.keep(TrackList.of(k, float(k), 2, tracks, T0 + k), 2, clock_offset=0.3)
        judged[at_validity] = part.step_errors()[5:20, 2]
    assert np.all(judged[True] < 1e-6), judged[True]
    assert np.all(judged[False] > 2.5), judged[False]
