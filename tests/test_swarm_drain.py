"""A swarm node drain as a soak fault (``zentrack soak --engine stack --drain-every``), without an engine: the
schedule, the node the drain picks (``zentrack.cluster.engines.swarm``), and how a drain recorded once per tracker it
moved is judged (each tracker like a kill, the network limit compounding over the trackers moved at once). The
real engine runs it in ``tests/test_docker.py`` (deploy/stack-test.sh, the two-node variant)."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from zentrack.cluster.engines import swarm
from zentrack.cluster.engines.swarm import SwarmNode, pick_drain
from zentrack.cluster.soak.accuracy import accuracy_per_fault
from zentrack.cluster.soak.criteria import drains_applied, publishing_after_fault, verdict_lines
from zentrack.cluster.soak.fault_kinds import fault_named
from zentrack.cluster.soak.faults import RECOVERY_S, fault_windows, schedule, trackers_faulted_near


def args(**over) -> argparse.Namespace:
    base = dict(duration=300.0, nodes=6, kill_every=0.0, freeze_every=0.0, cut_every=0.0, fault_s=5.0,
                restart_after=2.0, seed=1, truth_stall_every=0.0, truth_kill_every=0.0, router_every=0.0,
                drain_every=60.0, drain_s=12.0)
    base.update(over)
    return argparse.Namespace(**base)


def test_drains_are_scheduled_on_the_swarm_fault_s_long_at_their_phase():
    events = schedule(args())
    starts = [t for t, action, target in events if action == "drain"]
    assert starts == [60.0 + fault_named("drain").phase_s + 60.0 * k for k in range(4)]
    assert all(target == "swarm" for _, _, target in events)
    ends = [t for t, action, _ in events if action == "undrain"]
    assert [b - a for a, b in zip(starts, ends)] == [12.0] * 4  # --drain-s, not --fault-s
    assert not [e for e in schedule(args(drain_every=0.0)) if e[1] == "drain"]


def _node(name: str, role: str = "worker", availability: str = "active", status: str = "ready") -> SwarmNode:
    return SwarmNode(f"id-{name}", name, role, availability, status)


def test_a_drain_takes_the_active_ready_worker_holding_the_most_trackers(monkeypatch):
    slots = {"id-vm": [0, 1, 2, 3], "id-w1": [4], "id-w2": [5, 6], "id-w3": [7, 8, 9], "id-w4": [10, 11, 12]}
    monkeypatch.setattr(swarm, "tracker_slots", lambda stack, node_id: slots[node_id])
    nodes = [_node("vm", role="manager"), _node("w1"), _node("w2"), _node("w3", availability="drain"),
             _node("w4", status="down")]
    node, trackers = pick_drain("zt", nodes)
    assert node is not None and node.hostname == "w2" and trackers == [5, 6]  # not the manager, drained or down
    slots["id-w1"] = [4, 5]
    node, trackers = pick_drain("zt", nodes)
    assert node is not None and node.hostname == "w1"  # a tie: the first by host name
    assert pick_drain("zt", [_node("vm", role="manager")]) == (None, [])


def test_the_swarms_nodes_are_read_from_node_ls(monkeypatch):
    listing = ("5l2x * vm Ready Active Leader\n"  # `*`: this engine's node
               "i1vl ztsw1 Ready Drain\n"
               "nvds ztsw2 Down Active\n")

    def fake_docker(*argv, **_kw):
        assert argv[:2] == ("node", "ls")
        return listing.replace("5l2x * vm", "5l2x vm")  # the format prints no `*`

    monkeypatch.setattr(swarm, "docker", fake_docker)
    assert swarm.swarm_nodes() == [SwarmNode("5l2x", "vm", "manager", "active", "ready"),
                                   SwarmNode("i1vl", "ztsw1", "worker", "drain", "ready"),
                                   SwarmNode("nvds", "ztsw2", "worker", "active", "down")]


def _faults(*events):
    return [{"t": step / 10, "action": action, "node": node, "step": step} for step, action, node in events]


def test_a_drain_is_judged_per_tracker_moved_like_a_kill_with_the_network_limit_compounded():
    steps, nodes = 300, 8
    ref = np.full((steps, nodes), 5.0)
    err = ref.copy()
    moved = [2, 5, 7]  # one drain moved three trackers: recorded once per tracker, as the soak does
    drain = _faults(*[(100, "drain", i) for i in moved], *[(150, "undrain", i) for i in moved])
    err[100:130, moved] = np.nan  # stopped on the drained node, started on another
    err[130:191, moved] = 10.0  # rejoined at 2x to the window's end (40 steps after the undrain): within a kill's 2.5x
    err[100:191, [0, 1, 3, 4, 6]] = 5.0 * 1.6  # the rest miss three neighbours: 1.6x, within 1.25 ** 3
    crit = accuracy_per_fault(fault_windows(drain, steps - 1), err, ref)
    assert [(w["kind"], w["node"]) for w in crit["windows"]] == [("drain", i) for i in moved]
    for w in crit["windows"]:
        assert w["limits"] == [pytest.approx(fault_named("kill").limits[0]), pytest.approx(fault_named("kill").limits[1] ** 3)]
        assert w["ratio_affected"] == pytest.approx(2.0) and w["ratio_network"] == pytest.approx(1.6)
    assert crit["pass"]
    err[130:191, 5] = 15.0  # one moved tracker rejoins at 3x: its window fails, the others pass
    crit = accuracy_per_fault(fault_windows(drain, steps - 1), err, ref)
    assert [w["pass"] for w in crit["windows"]] == [True, False, True] and not crit["pass"]


def test_every_tracker_a_drain_moved_must_publish_again_within_the_limit_after_the_node_is_back():
    steps, nodes = 300, 6
    have = np.ones((steps, nodes), dtype=bool)
    have[100:135, [1, 4]] = False  # both moved trackers publish again 15 steps after the undrain at 120
    drain = _faults((100, "drain", 1), (100, "drain", 4), (120, "undrain", 1), (120, "undrain", 4))
    crit = publishing_after_fault(drain, have, steps)
    assert crit["pass"] and crit["worst_steps"] == 15
    have[100:150, 4] = False  # tracker 4 30 steps after it: over the 20-step limit
    crit = publishing_after_fault(drain, have, steps)
    assert not crit["pass"] and crit["events"][-1]["after"] == "undrain node-4"
    assert crit["events"][-1]["per_node"][4] == 30


def test_a_drain_passes_over_a_worker_holding_a_tracker_under_another_fault(monkeypatch):
    slots = {"id-w1": [1, 4], "id-w2": [2], "id-w3": [3, 5]}
    monkeypatch.setattr(swarm, "tracker_slots", lambda stack, node_id: slots[node_id])
    nodes = [_node("w1"), _node("w2"), _node("w3")]
    assert pick_drain("zt", nodes)[0].hostname == "w1"
    node, trackers = pick_drain("zt", nodes, avoid={4})  # tracker 4 is frozen: w1 is passed over
    assert node is not None and node.hostname == "w3" and trackers == [3, 5]
    assert pick_drain("zt", nodes, avoid={1, 2, 5}) == (None, [])


def test_a_soak_that_asked_for_drains_and_made_none_fails_drains_applied():
    why = "every active worker holds a tracker under another fault ([3])"
    crit = drains_applied([{"node": None, "trackers": [], "skipped": why}])
    assert not crit["pass"] and crit["skipped"] == [why]
    assert verdict_lines({"drains_applied": crit}) == [f"FAIL  drains_applied: 0 node drains moved 0 trackers, "
                                                       f"1 skipped ({why})"]
    crit = drains_applied([{"node": None, "trackers": [], "skipped": why}, {"node": "ztsw1", "trackers": [1, 4]}])
    assert crit["pass"] and crit["applied"] == 1 and crit["moved"] == 2


def test_a_drain_avoids_the_trackers_the_schedule_hits_near_it():
    events = [(20.0, "kill", 2), (22.0, "restart", 2), (30.0, "freeze", 3), (35.0, "thaw", 3),
              (32.5, "drain", "swarm"), (37.5, "undrain", "swarm"), (70.0, "kill", 5), (72.0, "restart", 5),
              (90.0, "freeze", 1)]  # never thawed: lasts to the end
    assert RECOVERY_S == 25.0
    assert trackers_faulted_near(events, 32.5, 37.5) == {2, 3}  # 5's kill starts 32.5 s after the undrain
    assert trackers_faulted_near(events, 50.0, 55.0) == {3, 5}  # 2 was back 28 s before; 1's freeze 35 s after
    assert trackers_faulted_near(events, 66.0, 70.0) == {1, 5}  # a fault never undone counts from its start


def test_the_stack_backend_drains_no_worker_holding_a_tracker_the_schedule_hits_near_the_drain(monkeypatch):
    from zentrack.cluster.soak import stack_backend
    backend = object.__new__(stack_backend.StackBackend)  # its engine-free parts: the drain plan and the drains
    backend.stack, backend.drained, backend.drains, backend._state_at = "zt", {}, [], 0.0
    calls = []
    monkeypatch.setattr(stack_backend, "swarm_nodes", lambda: [_node("w1"), _node("w2")])
    monkeypatch.setattr(stack_backend, "set_availability", lambda node, a: calls.append((a, node.hostname)))
    slots = {"id-w1": [1, 4], "id-w2": [2]}
    monkeypatch.setattr(swarm, "tracker_slots", lambda stack, node_id: slots[node_id])
    backend.plan_drains([(30.0, "freeze", 4), (35.0, "thaw", 4), (32.5, "drain", "swarm"), (37.5, "undrain", "swarm"),
                         (92.5, "drain", "swarm"), (97.5, "undrain", "swarm"), (110.0, "kill", 1),
                         (112.0, "restart", 1), (115.0, "kill", 2), (117.0, "restart", 2),
                         (152.5, "drain", "swarm"), (157.5, "undrain", "swarm")])
    assert backend.act("drain", "swarm") == [2] and calls[-1] == ("drain", "w2")  # w1 holds tracker 4, frozen
    assert backend.act("undrain", "swarm") == [2] and calls[-1] == ("active", "w2")
    assert backend.act("drain", "swarm") == [] and calls[-1] == ("active", "w2")  # 1 and 2 are killed soon after
    assert "another fault hits near it ([1, 2])" in backend.drains[-1]["skipped"]
    assert backend.act("undrain", "swarm") == [] and calls[-1] == ("active", "w2")  # nothing to make active
    assert backend.act("drain", "swarm") == [1, 4] and calls[-1] == ("drain", "w1")  # nothing near: the most
