"""The soak: its seeded schedule, its recovery criterion on constructed data, and the short soak of CI
(70 s, 6 trackers in network namespaces on the patrol scenario; three tracker kills, a freeze and a link cut),
which must pass every criterion and leave nothing behind.

Truth stalls and router restarts blind every tracker at once; in a 2-minute run their transients alone push
the RMSE ratio over its 1.25 limit (measured 1.2-1.44 with two 1 s stalls and a 2 s router restart), so CI
covers them end to end in ``test_stalls.py`` and the 10-minute soak (README) judges them over a long run."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from zentrack.cluster.soak.criteria import publishing_after_fault
from zentrack.cluster.soak.fault_kinds import fault_actions, undo_actions
from zentrack.cluster.soak.faults import schedule


def soak_args(**over) -> argparse.Namespace:
    base = dict(duration=600.0, nodes=10, kill_every=30.0, freeze_every=60.0, cut_every=90.0, fault_s=5.0,
                restart_after=2.0, seed=3, truth_stall_every=120.0, truth_kill_every=0.0, router_every=180.0)
    base.update(over)
    return argparse.Namespace(**base)


def test_fault_schedule_is_seeded_and_paired():
    args = soak_args()
    events = schedule(args)
    assert events == schedule(args)
    assert events != schedule(soak_args(seed=4))
    nodes = [e for e in events if isinstance(e[2], int)]
    kinds = [e[1] for e in nodes]
    assert kinds.count("kill") == kinds.count("restart") == 19
    assert kinds.count("freeze") == kinds.count("thaw") == 9 and kinds.count("cut") == kinds.count("heal") == 6
    stalls = [e for e in events if e[2] == "truth"]
    assert [e[1] for e in stalls] == ["stall", "resume"] * 4
    for (t_stop, _, _), (t_resume, _, _) in zip(stalls[::2], stalls[1::2]):
        assert 0.5 <= t_resume - t_stop <= 3.0
    router = [e[1] for e in events if e[2] == "router"]
    assert router == ["kill", "restart"] * 3
    assert all(0 < t < 600 for t, _, _ in events)


def fault_windows(events):
    """(start, end, target) of every fault in a schedule (of every kind in the registry)."""
    open_at, out = {}, []
    for t, action, target in events:
        if action in fault_actions():
            open_at[target] = t
        else:
            out.append((open_at.pop(target), t, target))
    assert not open_at, "every fault is undone"
    return out


@pytest.mark.parametrize("seed", range(6))
def test_no_tracker_is_under_two_faults_and_services_avoid_tracker_faults(seed):
    windows = fault_windows(schedule(soak_args(seed=seed)))
    for i in range(10):
        mine = sorted((a, b) for a, b, target in windows if target == i)
        for (a1, b1), (a2, _b2) in zip(mine, mine[1:]):
            assert a2 >= b1 + 25, f"tracker {i}: a fault at {a2} s while recovering from {a1}-{b1} s"
    tracker = [(a, b) for a, b, target in windows if isinstance(target, int)]
    service = [(a, b) for a, b, target in windows if isinstance(target, str)]
    for a, b in service:
        assert not any(a <= b2 and a2 <= b for a2, b2 in tracker), f"service fault {a}-{b} s overlaps a tracker fault"
    for (_a1, b1), (a2, _b2) in zip(sorted(service), sorted(service)[1:]):
        assert a2 > b1, "service faults do not overlap each other"


def test_recovery_criterion_fails_a_tracker_that_never_comes_back():
    steps, nodes = 200, 4
    have = np.ones((steps, nodes), dtype=bool)
    faults = [{"t": 5.0, "action": "stall", "node": "truth", "step": 50},
              {"t": 7.0, "action": "resume", "node": "truth", "step": 70}]
    have[50:75, :] = False  # every tracker back 5 steps after the stall ends
    ok = publishing_after_fault(faults, have, steps)
    assert ok["pass"] and ok["worst_steps"] == 5
    have[75:, 2] = False  # tracker 2 never publishes again
    bad = publishing_after_fault(faults, have, steps)
    assert not bad["pass"] and bad["events"][0]["per_node"][2] is None
    have[75:95, 2] = False
    have[95:, 2] = True  # back after 25 steps: over the limit of 20
    late = publishing_after_fault(faults, have, steps)
    assert not late["pass"] and late["events"][0]["steps_to_all_estimating"] == 25


def test_recovery_criterion_waits_for_the_router_before_judging_a_restart():
    steps = 100
    have = np.ones((steps, 3), dtype=bool)
    have[30:62, :] = False  # the router is down from 30 to 55: nobody is heard; node 0 restarts meanwhile
    faults = [{"t": 3.0, "action": "kill", "node": "router", "step": 30},
              {"t": 3.2, "action": "kill", "node": 0, "step": 32},
              {"t": 3.4, "action": "restart", "node": 0, "step": 34},
              {"t": 5.5, "action": "restart", "node": "router", "step": 55}]
    res = publishing_after_fault(faults, have, steps)
    assert res["events"][0]["per_node"] == {}, "nobody can be heard while the router is down: judged later"
    assert res["events"][1]["per_node"] == {0: 7, 1: 7, 2: 7} and res["pass"]
    have[55:80, 0] = False  # the restarted tracker is not back 20 steps after the router
    res = publishing_after_fault(faults, have, steps)
    assert not res["pass"] and res["events"][1]["per_node"][0] == 25


def test_recovery_criterion_leaves_out_a_tracker_under_its_own_fault():
    steps = 100
    have = np.ones((steps, 3), dtype=bool)
    have[30:60, 1] = False  # node 1 is dead from 30 to 60
    faults = [{"t": 3.0, "action": "kill", "node": 1, "step": 30},
              {"t": 4.0, "action": "stall", "node": "truth", "step": 40},
              {"t": 4.5, "action": "resume", "node": "truth", "step": 45},
              {"t": 5.9, "action": "restart", "node": 1, "step": 59}]
    res = publishing_after_fault(faults, have, steps)
    assert res["pass"]
    assert 1 not in res["events"][0]["per_node"] and res["events"][1]["per_node"][1] == 1


def test_recovery_criterion_leaves_out_a_tracker_killed_as_another_thaws():
    """A thaw of node 1 and a kill of node 2 at the same step (the soak's schedule can put them there): node 2's
    outage belongs to its kill, whose restart judges it, not to node 1's thaw."""
    steps = 100
    have = np.ones((steps, 3), dtype=bool)
    have[40:50, 1] = False  # node 1 frozen from 40 to 50, back at once
    have[50:72, 2] = False  # node 2 killed at 50, restarted at 70, back 2 steps later
    faults = [{"t": 4.0, "action": "freeze", "node": 1, "step": 40},
              {"t": 5.0, "action": "thaw", "node": 1, "step": 50},
              {"t": 5.0, "action": "kill", "node": 2, "step": 50},
              {"t": 7.0, "action": "restart", "node": 2, "step": 70}]
    res = publishing_after_fault(faults, have, steps)
    assert res["events"][0]["per_node"] == {0: 0, 1: 0}, res["events"][0]
    assert res["events"][1]["per_node"][2] == 2 and res["pass"]
    have[70:95, 2] = False  # the killed tracker not back 20 steps after its restart: its own event fails
    res = publishing_after_fault(faults, have, steps)
    assert not res["pass"] and res["events"][0]["pass"] and res["events"][1]["per_node"][2] == 25


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0, reason="link cuts use network namespaces, which need root (CI runs as root)")
def test_short_soak(tmp_path):
    out = tmp_path / "soak"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--duration", "70", "--nodes", "6",
                           "--kill-every", "20", "--freeze-every", "35", "--cut-every", "50", "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    assert (out / "report.json").exists(), f"the soak wrote no report (status {proc.returncode}): {proc.stderr[-3000:]}"
    report = json.loads((out / "report.json").read_text())
    failed = {name: c for name, c in report["criteria"].items() if not c["pass"]}
    assert report["pass"] and not failed, failed
    assert proc.returncode == 0, proc.stdout + proc.stderr[-2000:]
    assert "soak passed" in proc.stdout
    crit = report["criteria"]
    assert set(crit) == {"no_crash_no_nan", "rmse_vs_reference", "restarted_error_near_median", "rss_growth",
                         "outputs_complete", "nothing_left_running", "publishing_after_fault", "accuracy_per_fault"}
    actions = [(f["action"], f["node"]) for f in report["faults"]]
    assert sum(a == "kill" and isinstance(n, int) for a, n in actions) == 3
    assert sum(a == "freeze" for a, _ in actions) == 1 and sum(a == "cut" for a, _ in actions) == 1
    assert len(crit["rmse_vs_reference"]["ratio_per_node"]) == 6
    windows = crit["accuracy_per_fault"]["windows"]  # one per fault, each against the reference's same steps
    assert [w["kind"] for w in windows].count("kill") == 3 and len(windows) == 5
    assert all(w["reference_affected_m"] > 0 and w["end"] > w["start"] for w in windows)
    assert report["field"]["first_step_out"] is None  # patrol, the default: its target stays in the field
    assert "| fault | hit | steps |" in proc.stdout and "the fault-free reference run: " in proc.stdout
    assert len(crit["publishing_after_fault"]["events"]) == sum(a in undo_actions() for a, _ in actions)
    assert crit["publishing_after_fault"]["worst_steps"] <= 20
    assert "PASS  publishing_after_fault: " in proc.stdout and "error plot " in proc.stdout
    assert (out / "error.svg").stat().st_size > 5000
    assert (out / "error.png").stat().st_size > 5000 and (out / "recording.rrd").stat().st_size > 10_000
    assert (out / "summary.json").exists() and (out / "reference" / "summary.json").exists()
    artifacts = Path(__file__).resolve().parent.parent / "out" / "artifacts"
    artifacts.mkdir(parents=True, exist_ok=True)
    (artifacts / "soak_error.png").write_bytes((out / "error.png").read_bytes())
    (artifacts / "soak_report.json").write_text(json.dumps(report, indent=1))
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert "zts-" not in names and "ztr-" not in names, "both runs' namespaces are gone"
    links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout.splitlines()
    names = [ln.split(":", 2)[1].strip().split("@")[0] for ln in links if ln.count(":") >= 2]
    # the harness's bridge ``zt<tag>br`` and veths ``zt<tag>v...`` of both runs (tags s and r; zentrack/cluster/engines/netns.py)
    ours = [n for n in names if n in ("ztsbr", "ztrbr") or n.startswith(("ztsv", "ztrv"))]
    assert not ours, f"both runs' bridges and links are gone: {ours}"


@pytest.mark.slow
def test_short_secure_soak(tmp_path):
    """Secure mode under faults: kills and restarts of trackers and of the router, every link mutual TLS through
    the router's access control (certificates made by the soak)."""
    out = tmp_path / "soak"
    conf = tmp_path / "zenoh.json5"  # a user's Zenoh file: every process of both runs merges it (gossip off)
    conf.write_text("{scouting: {gossip: {enabled: false}}}")
    # exp2, as before patrol became the default: its target stays inside the ring for these 60 s (it leaves at 96 s),
    # and on patrol a 4-tracker ring's whole-run ratio sits at the 1.25 limit (1.29 measured on a loaded host)
    proc = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--scenario", "exp2", "--secure", "--duration", "60", "--nodes", "4",
                           "--kill-every", "20", "--freeze-every", "0", "--cut-every", "0", "--router-every", "25",
                           "--zenoh-config", str(conf), "--out", str(out)], capture_output=True, text=True, timeout=600)
    report = json.loads((out / "report.json").read_text())
    failed = {name: c for name, c in report["criteria"].items() if not c["pass"]}
    assert report["pass"] and not failed, failed
    assert proc.returncode == 0 and "soak passed" in proc.stdout, proc.stdout + proc.stderr[-2000:]
    assert report["secure"] is True
    actions = [(f["action"], f["node"]) for f in report["faults"]]
    assert ("kill", "router") in actions and sum(a == "kill" and isinstance(n, int) for a, n in actions) == 2
    logs = out / "logs"
    assert "mutual TLS as node-0" in (logs / "node-0.log").read_text()
    assert "access control on" in (logs / "router.log").read_text()
    for folder in (logs, out / "reference" / "logs"):
        for name in ("router", "truth", "node-0", "node-3"):
            lines = [line for line in (folder / f"{name}.log").read_text().splitlines() if "zenoh session" in line]
            assert lines and all("gossip off" in line for line in lines), (folder, name)
