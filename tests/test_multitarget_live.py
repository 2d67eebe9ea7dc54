"""Many-target runs live: ``zentrack run`` on a [targets] scenario, one multi-target tracker per OS process,
track lists over Zenoh.

- A lockstep run gives exactly what the in-process network of the bench computes on the same scans
  (``zentrack.study.multitarget_runs.run_distributed``): same confirmed tracks, same network ids, same estimates;
  with point sensors (GNN nodes, and PMBM nodes: ``--tracker pmbm``), and with bearing-only sensors whose nodes
  exchange their scans and triangulate.
- A realtime run in which a tracker is killed and restarted, and a forger publishes hostile track lists: the
  restarted tracker takes its neighbours' tracks back (the recorder's ``recovery_steps``, at most 20), the
  hostile lists are refused and counted by the neighbours, and the run ends OK.
"""
from __future__ import annotations

import argparse
import importlib.util
import time
from dataclasses import replace

import msgpack
import numpy as np
import pytest
import zenoh
from forger import attacker_config

from zentrack.cli import main
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.config.scenario_multitarget import shares_scans
from zentrack.fusion.track_to_track import TrackEstimate, TrackId
from zentrack.study.multitarget_runs import node_settings, run_distributed
from zentrack.transport.track_messages import TrackList

pytestmark = pytest.mark.slow
#: the recorded scenarios read AIS from tracktable-data (`pip install 'zentrack[real]'`; CI installs it)
needs_real_data = pytest.mark.skipif(importlib.util.find_spec("tracktable_data") is None,
                                     reason="tracktable-data is not installed (pip install 'zentrack[real]')")


def setup_of(*flags: str):
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    return resolve_setup(p.parse_args(["--scenario", "mt-crossing", *flags]))


@pytest.mark.parametrize(("scenario", "tracker", "least"), [
    ("mt-crossing", "gnn", 8 * 4 * (25 - 7)),  # point sensors: every node holds the 4 targets once confirmed
    ("mt-crossing", "pmbm", 8 * 4 * (25 - 2)),  # PMBM nodes sharing scans: existence instead of M of N
    ("mt-bearing", "gnn", 8 * 6 * (25 - 12)),  # bearing sensors, scans exchanged: the 6 targets once triangulated
    # real ships (AIS) as truth, seen by a mixed network: bearing-only cameras and point radars
    pytest.param("ais-nyharbor", "gnn", 10 * 15 * (25 - 10), marks=needs_real_data),
])
def test_a_lockstep_run_tracks_exactly_as_the_in_process_network(scenario, tracker, least, tmp_path, capsys):
    steps = 25
    assert main(["run", "--scenario", scenario, "--steps", str(steps), "--timing", "lockstep", "--tracker", tracker,
                 "--out", str(tmp_path)]) == 0
    assert "run OK" in capsys.readouterr().out
    rows = np.load(tmp_path / "tracks.npz")
    cfg = resize(load_scenario_config(scenario, multitarget=True), None, steps)
    share = shares_scans(tracker, None)  # (PMBM nodes step on their neighbours' scans too)
    expected = run_distributed(cfg.multitarget_data(),
                               [replace(s, tracker=tracker, share_scans=share) for s in node_settings(cfg)], cfg)
    compared = 0
    for node, view in enumerate(expected.views):
        for k, (ids, positions) in enumerate(view):
            mine = (rows["step"] == k) & (rows["node"] == node) & rows["confirmed"]
            live = {TrackId(int(b), int(n), int(s)): x[:3] for b, n, s, x in
                    zip(rows["born"][mine], rows["id_node"][mine], rows["serial"][mine], rows["state"][mine])}
            assert set(live) == set(ids), (node, k)
            for track_id, position in zip(ids, positions):
                np.testing.assert_allclose(live[track_id], position, rtol=0, atol=1e-6)
            compared += len(ids)
    print(f"{scenario}: {compared} confirmed track-steps equal")
    assert compared >= least, compared


def forge_lists(session: zenoh.Session, key: str, sender: int, k: int, honest: TrackEstimate) -> int:
    """Hostile lists on ``key`` for step k: NaN in a mean, a track id twice, 300 tracks, garbage bytes."""
    doc = msgpack.unpackb(TrackList.of(k, float(k), sender, [honest], time.time()).encode(), raw=False)
    nan = {**doc, "tracks": [{**doc["tracks"][0], "x": {**doc["tracks"][0]["x"],
                                                          "data": np.full(6, np.nan).tobytes()}}]}
    payloads = [msgpack.packb(nan), msgpack.packb({**doc, "tracks": doc["tracks"] * 2}),
                msgpack.packb({**doc, "tracks": doc["tracks"] * 300}), b"\xc1\xc1 not msgpack"]
    for payload in payloads:
        session.put(key, payload)
    return len(payloads)


def test_a_restarted_tracker_takes_its_tracks_back_and_hostile_lists_are_refused(tmp_path):
    setup = setup_of("--steps", "55", "--period", "0.3")
    victim, forged_as = 3, 4
    with Cluster(setup, tmp_path) as cluster:
        cluster.start()
        rec = cluster.recorder
        assert rec is not None
        end = time.time() + 60
        while rec.steps_reached() < 20 and time.time() < end:
            rec.drain(0.1)
        assert rec.steps_reached() >= 20, "the run did not reach step 20"
        cluster.kill(victim)
        cluster.pump(2.0)
        cluster.restart(victim)
        session = zenoh.open(attacker_config(cluster.endpoint))
        try:
            cluster.pump(1.0)
            honest = TrackEstimate(TrackId(0, forged_as, 0), np.zeros(6), np.eye(6), "confirmed", 0)
            forged = 0
            for _ in range(3):
                forged += forge_lists(session, cluster.keys.tracks(forged_as), forged_as, rec.steps_reached(), honest)
                cluster.pump(0.5)
        finally:
            session.close()
        assert cluster.wait(120) == 0
        summary = cluster.write_results()
    nodes = {n["node"]: n for n in summary["nodes"]}
    # the victim's gap is the kill, the 2 s down and its start (longer on a loaded host); every other node has none
    assert all(not n["gaps"] for i, n in nodes.items() if i != victim), [n["gaps"] for n in nodes.values()]
    assert len(nodes[victim]["gaps"]) == 1 and not run_failures(summary, 0.5), run_failures(summary, 0.5)
    back = nodes[victim]["recoveries"]
    assert back and back[0]["covered_before"] >= 3, back
    assert back[0]["recovery_steps"] is not None and back[0]["recovery_steps"] <= 20, back
    rows = np.load(tmp_path / "tracks.npz")  # at the last step its tracks carry the network's ids, as its neighbour's
    final = {n: {(int(b), int(i), int(s)) for b, i, s, c, node, k in zip(rows["born"], rows["id_node"], rows["serial"],
                                                                        rows["confirmed"], rows["node"], rows["step"])
                 if c and node == n and k == rows["step"].max()} for n in (victim - 1, victim)}
    assert len(final[victim]) >= 3 and final[victim] == final[victim - 1], final
    refused = sum(sum(nodes[j]["messages"]["rejected"].values()) for j in (3, 5))  # node 4's neighbours
    assert refused >= forged // 2, (refused, forged)  # node 3 may have missed some while it restarted
    assert summary["network"]["gospa_mean"] < 25.0
