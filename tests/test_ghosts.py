"""Triangulation ghosts (issue 53 item 4): the centralized tracker of cameras deletes a track that keeps two rays of
other targets and no third (fusion/multitarget/lifecycle.py, RayConfirmationDeleter); a camera node counts a hit
only where two cameras' rays took the track (fusion/multitarget/network.py, make_gnn_tracker); the longest false
life of a run is measured (fusion/multitarget/metrics.py, longest_false_life).

The ghost is built by hand: eight cameras of ``mt-bearing`` see two still targets X and Y, and a confirmed track G
sits where camera 0's ray to X meets camera 2's ray to Y, beyond both targets (so its bearing from those two cameras
is the sharper, and GNN gives it their returns). Without the rule G is held for as long as the run lasts; with it,
G is gone K steps after it was started and X and Y are held throughout.
"""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.config.scenario_config import load_scenario_config
from zentrack.fusion.measurement import bearing
from zentrack.fusion.multitarget import TrackStatus
from zentrack.fusion.multitarget.base import Track
from zentrack.fusion.multitarget.central import make_central_tracker
from zentrack.fusion.multitarget.lifecycle import MissesCovarianceDeleter, RayConfirmationDeleter
from zentrack.fusion.multitarget.metrics import longest_false_life, summarize_run
from zentrack.fusion.multitarget.network import make_gnn_tracker
from zentrack.fusion.multitarget.tracker import MultiTargetTracker
from zentrack.fusion.scan import Scan
from zentrack.study.multitarget_runs import node_settings

K = 5  # mt-bearing's max_misses: the rule's window
SIGMA = 0.005  # rad, mt-bearing's bearing noise
STEPS = 20


def cameras_of_mt_bearing():
    cfg = load_scenario_config("mt-bearing", multitarget=True)
    return node_settings(cfg), cfg.multitarget_data(seed=0).sensors


@pytest.fixture(scope="module")
def cameras():
    return cameras_of_mt_bearing()


def ghost_geometry(sensors: np.ndarray) -> dict[str, np.ndarray]:
    """X and Y, and G where camera 0's ray to X meets camera 2's ray to Y (X, Y 60 % of the way to G)."""
    g = np.array([300.0, 200.0, 150.0])
    x = sensors[0] + 0.6 * (g - sensors[0])
    y = sensors[2] + 0.6 * (g - sensors[2])
    return {"X": x, "Y": y, "G": g}


def look(sensor: int, sensors: np.ndarray, points: list[np.ndarray], noise_var: float, step: int) -> Scan:
    pts = np.array(points)
    z = bearing(pts, np.broadcast_to(sensors[sensor], (len(pts), 1, 3)))
    return Scan(step, sensor, z, sensors[sensor], noise_var * np.eye(2))


def run(tracker: MultiTargetTracker, sensors: np.ndarray, places: dict[str, np.ndarray],
        noise_var: float, seen_by: dict[str, list[int]]) -> list[dict[str, bool]]:
    """Tracks started (confirmed) on every place, then STEPS steps of noise-free scans in which camera i sees the
    places whose ``seen_by`` lists it; per step, which places a confirmed track is within 5 m of."""
    p0 = np.diag([25.0, 25.0, 25.0, 1.0, 1.0, 1.0])
    for p in places.values():
        tracker.initiator.from_prior(np.concatenate([p, np.zeros(3)]), p0, TrackStatus.CONFIRMED)
    held = []
    for k in range(STEPS):
        scans = []
        for i in range(len(sensors)):
            pts = [places[name] for name, who in seen_by.items() if i in who]
            scans.append(look(i, sensors, pts, noise_var, k) if pts else
                         Scan.empty(k, i, sensors[i], noise_var * np.eye(2)))
        tracker.step(k, scans)
        confirmed = np.array([t.mean[:3] for t in tracker.confirmed()]).reshape(-1, 3)
        held.append({name: bool(len(confirmed) and np.linalg.norm(confirmed - p, axis=1).min() < 5.0)
                     for name, p in places.items()})
    return held


def test_the_hand_made_ghost_is_a_ghost(cameras):
    """The geometry: G is on camera 0's ray to X and camera 2's ray to Y, and on no other camera's ray to either."""
    settings, sensors = cameras
    p = ghost_geometry(sensors)
    az = {name: np.array([bearing(pt[None], s[None, None])[0] for s in sensors]) for name, pt in p.items()}  # (M, 2)
    assert np.allclose(az["G"][0], az["X"][0]) and np.allclose(az["G"][2], az["Y"][2])
    for i in range(len(sensors)):
        for target in ("X", "Y"):
            if (i, target) not in ((0, "X"), (2, "Y")):
                assert np.abs(az["G"][i] - az[target][i]).max() > 5 * SIGMA, (i, target)  # other cameras' rays miss G by far


@pytest.mark.parametrize("rule", [True, False])
def test_the_centre_deletes_a_ghost_of_two_rays_and_holds_the_targets(cameras, rule):
    settings, sensors = cameras
    tracker = make_central_tracker(settings)
    assert isinstance(tracker.deleter, RayConfirmationDeleter)
    if not rule:
        tracker.deleter = tracker.deleter.inner  # the K misses alone, as before
    every = list(range(len(sensors)))
    held = run(tracker, sensors, ghost_geometry(sensors), SIGMA**2, {"X": every, "Y": every})
    assert all(h["X"] and h["Y"] for h in held)
    ghost = [h["G"] for h in held]
    if rule:
        assert ghost[:K] == [True] * K and not any(ghost[K + 1:]), ghost
    else:
        assert all(ghost), ghost  # the two rays hold it, step after step


def test_a_target_only_two_cameras_see_keeps_its_track(cameras):
    """Two rays that no other track's gate holds: a target, not a ghost."""
    settings, sensors = cameras
    tracker = make_central_tracker(settings)
    held = run(tracker, sensors, {"Z": np.array([100.0, -300.0, 200.0])}, SIGMA**2, {"Z": [0, 1]})
    assert all(h["Z"] for h in held)


def track(step: int, birth: int, seen: dict[int, int], alone: dict[int, int]) -> Track:
    t = Track(0, np.zeros(6), np.eye(6), birth, step, TrackStatus.CONFIRMED)
    t.detected_by, t.detected_alone_by = dict(seen), dict(alone)
    return t


@pytest.mark.parametrize("seen, alone, deleted", [
    ({0: 20, 2: 20}, {}, True),                       # two cameras' rays, both another track's too: a ghost
    ({0: 20, 2: 20}, {0: 20}, True),                  # one ray of its own is not two
    ({0: 20, 2: 20}, {0: 19, 2: 16}, False),          # two rays nothing else explains
    ({0: 20, 2: 20}, {0: 19, 2: 15}, True),           # ... within the last K steps only
    ({0: 20, 2: 20, 5: 16}, {}, False),               # a third ray within K steps
    ({0: 20, 2: 20, 5: 15}, {}, True),                # one K + 1 steps ago does not count
    ({0: 20, 9: 18}, {}, False),                      # a point sensor's return
    ({}, {}, False),                                  # no return at all: the K misses decide (here: not yet)
])
def test_the_rule_counts_rays_within_k_steps(seen, alone, deleted):
    rule = RayConfirmationDeleter(MissesCovarianceDeleter(K), bearing_sensors=range(8), window=K)
    assert rule.should_delete(track(20, 0, seen, alone)) is deleted
    assert rule.should_delete(track(20, 16, seen, alone)) is False  # younger than K steps: not yet judged


def test_the_rule_refuses_a_window_or_ray_count_below_one():
    for kwargs in ({"window": 0}, {"window": K, "min_rays": 0}):
        with pytest.raises(ValueError):
            RayConfirmationDeleter(MissesCovarianceDeleter(K), range(8), **kwargs)


def test_longest_false_life_counts_the_longest_run_of_one_false_id():
    truth = [{"a": [0.0, 0.0]}] * 6
    tracks = [{1: [1.0, 0.0], 2: [500.0, 0.0]},   # 2 false
              {1: [1.0, 0.0], 2: [500.0, 0.0]},   # 2 false
              {1: [1.0, 0.0], 2: [2.0, 0.0]},     # 2 near, but a takes 1: still false
              {1: [900.0, 0.0], 2: [2.0, 0.0]},   # 2 takes a: 1 false, 2's run ends at 3
              {1: [900.0, 0.0]},
              {3: [900.0, 0.0]}]                  # another id: a new run
    assert longest_false_life(tracks, truth, cutoff=50.0) == 3
    assert summarize_run(tracks, truth, cutoff=50.0).longest_false == 3
    assert longest_false_life([{}] * 3, [{"a": [0.0, 0.0]}] * 3, cutoff=50.0) == 0


def camera_node(settings, sensors, place: np.ndarray) -> MultiTargetTracker:
    """Node 0's tracker of ``mt-bearing`` (its own and its neighbours' scans) holding one confirmed track at
    ``place``."""
    tracker = make_gnn_tracker(settings[0], sensor=0)
    tracker.initiator.from_prior(np.concatenate([place, np.zeros(3)]), np.diag([25.0] * 3 + [1.0] * 3),
                                 TrackStatus.CONFIRMED)
    return tracker


@pytest.mark.parametrize("cameras, held_to_the_end", [([0, 1], True), ([1], False)])
def test_a_camera_nodes_hit_needs_two_cameras_rays(cameras, held_to_the_end):
    """One ray has no range: a camera node whose track only one camera's rays take counts misses and gives the
    track up after K steps; two cameras' rays hold it. A point sensor's node counts its one return (below)."""
    settings, sensors = cameras_of_mt_bearing()
    place = np.array([100.0, -300.0, 200.0])
    tracker = camera_node(settings, sensors, place)
    assert tracker.min_hit_sensors == 2
    alive = []
    for k in range(STEPS):
        scans = [look(i, sensors, [place], SIGMA**2, k) if i in cameras else
                 Scan.empty(k, i, sensors[i], SIGMA**2 * np.eye(2)) for i in (7, 1, 0)]  # the neighbours', then its own
        tracker.step(k, scans)
        alive.append(len(tracker.tracks))
    if held_to_the_end:
        assert alive == [1] * STEPS
    else:
        assert alive[:K - 1] == [1] * (K - 1) and alive[K - 1:] == [0] * (STEPS - K + 1), alive


def test_a_point_node_and_the_centre_count_one_sensors_return():
    cfg = load_scenario_config("mt-crossing", multitarget=True)
    assert make_gnn_tracker(node_settings(cfg)[0]).min_hit_sensors == 1
    settings, _ = cameras_of_mt_bearing()
    assert make_central_tracker(settings).min_hit_sensors == 1  # (its ghosts: the third-ray rule)
