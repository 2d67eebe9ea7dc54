"""Issue 36, soaks that measure: the patrol scenario stays in the sensors' field for any duration (exp2's target
leaves it, and the soak refuses it in one line), the per-fault accuracy windows judge the trackers a fault hit
against the reference at the same steps, and a tracker's deadline misses reach the recorder with the step, the
phase and how late (the wire note is checked field by field)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from schedule_net import Net, ests, run_steps

from zentrack.cluster.soak.accuracy import accuracy_per_fault, check_field, error_growth, field_exit, window_table
from zentrack.cluster.soak.fault_kinds import fault_named
from zentrack.cluster.soak.faults import fault_windows
from zentrack.cluster.soak.misses import miss_lines, miss_report
from zentrack.config.scenario_config import load_scenario_config
from zentrack.config.scenario_parse import parse
from zentrack.transport.codec import WireError
from zentrack.transport.messages import EstimateMessage
from zentrack.transport.miss_notes import MAX_MISS_NOTES, MissNote, unpack_notes
from zentrack.truth.simulation.simulate import simulate


def _truth(name: str, steps: int, runs: int = 1, seed: int = 0):
    cfg = load_scenario_config(name)
    return simulate(dataclasses.replace(cfg.spec, steps=steps), runs=runs, seed=seed, ts=cfg.ts)


def test_patrol_stays_in_the_field_for_an_hour_and_exp2_leaves_it_within_minutes():
    hour = _truth("patrol", 36_000)
    where = field_exit(hour.truth[0], hour.sensors)
    assert where["first_step_out"] is None and where["max_distance_m"] < 0.8 * where["radius_m"], where
    speed = np.linalg.norm(hour.truth[..., 3:], axis=-1)
    assert 12 < speed.mean() < 18
    exp2 = _truth("exp2", 6000)
    where = field_exit(exp2.truth[0], exp2.sensors)
    assert where["radius_m"] == pytest.approx(400.0) and where["first_step_out"] is not None
    assert where["first_step_out"] < 3000 and where["max_distance_m"] > 1000


def test_a_patrol_run_is_the_same_whatever_the_number_of_runs():
    one, three = _truth("patrol", 500, runs=1, seed=4), _truth("patrol", 500, runs=3, seed=4)
    assert np.array_equal(one.truth[0], three.truth[0])
    assert np.array_equal(one.measurements[0], three.measurements[0])
    assert not np.array_equal(three.truth[0], three.truth[1]), "each run its own process noise"


@pytest.mark.parametrize(("line", "key"), [('kind = "loop"', "trajectory.kind"), ("speed = -1.0", "trajectory.speed"),
                                           ("wobble = 1.0", "trajectory.wobble"), ("sigma_a = -2.0", "trajectory.sigma_a")])
def test_a_bad_patrol_is_one_line_naming_the_key(line, key):
    from zentrack.config.catalogue import text

    doc = text("patrol")
    assert doc is not None
    head, rest = doc.split("[trajectory]\n")
    section, tail = rest.split("[graph]")
    name = line.split(" = ")[0]
    kept = [ln for ln in section.splitlines() if not ln.startswith(f"{name} ")]
    bad = head + "[trajectory]\n" + "\n".join([line, *kept]) + "\n[graph]" + tail
    with pytest.raises(ValueError) as err:
        parse("bad.toml", bad)
    assert key in str(err.value) and "\n" not in str(err.value)


def test_the_soak_refuses_a_scenario_whose_target_leaves_the_field_before_anything_starts(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--scenario", "exp2", "--duration", "200",
                           "--cut-every", "0", "--out", str(tmp_path / "soak")], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "leaves the sensors' field" in lines[0] and "--unobserved" in lines[0], lines
    assert not (tmp_path / "soak" / "report.json").exists()


def test_many_targets_coming_and_going_are_not_refused_as_one_target_leaving():
    """A many-target run's truth is (steps, targets, state): read as one target's runs, a real network's aircraft
    far out at step 0 refused the hour of adsb-paris-radar as "its target leaves at step 0"."""
    from zentrack.config.run_setup import scenario_setup

    data = scenario_setup("mt-50", steps=20).run_data
    far = dataclasses.replace(data, truth=data.truth.copy())
    far.truth[0, 0, :2] = 1e5  # one target 100 km out at the first step
    assert check_field(far, unobserved=False) is None
    with pytest.raises(ValueError, match="leaves the sensors' field"):  # one target leaving is still refused
        check_field(_truth("exp2", 6000), unobserved=False)


def _faults(*events):
    return [{"t": s * 0.1, "action": a, "node": n, "step": s} for s, a, n in events]


def test_a_fault_window_fails_when_the_tracker_it_hit_is_worse_than_its_kinds_limit():
    steps, nodes = 400, 4
    ref = np.full((steps, nodes), 5.0)
    err = ref.copy()
    err[100:160, 2] = 5.0 * (fault_named("kill").limits[0] + 0.5)  # the killed tracker rejoins badly
    err[100:120, 2] = np.nan  # down until its restart
    err[300:330, :] = 8.0  # a truth stall: every tracker 1.6x, inside its limit
    faults = _faults((100, "kill", 2), (120, "restart", 2), (300, "stall", "truth"), (310, "resume", "truth"))
    crit = accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)
    kill, stall = crit["windows"]
    assert (kill["kind"], kill["affected"], kill["start"], kill["end"]) == ("kill", [2], 100, 160)
    assert kill["ratio_affected"] > fault_named("kill").limits[0] and not kill["pass"] and not crit["pass"]
    assert kill["ratio_network"] == pytest.approx(1.0)  # the median over 4 trackers hardly moves
    assert stall["kind"] == "truth-stall" and stall["affected"] == [0, 1, 2, 3] and stall["pass"]
    assert 1.3 < stall["ratio_network"] < 2.0
    table = window_table(crit)
    assert len(table) == 4 and "FAIL" in table[2] and "| truth-stall | truth |" in table[3]
    err[100:160, 2] = 6.0  # the same rejoin within the limit
    assert accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)["pass"]
    err[300:330, 1] = 50.0  # a freeze during the stall: the stall's window judges it
    inside = _faults((300, "stall", "truth"), (305, "freeze", 1), (310, "resume", "truth"), (320, "thaw", 1))
    crit = accuracy_per_fault(fault_windows(inside, steps - 1), err, ref)
    stall, freeze = crit["windows"]
    assert freeze["overlaps"] == ["truth-stall"] and not freeze["judged"] and freeze["pass"]
    assert freeze["ratio_affected"] > fault_named("freeze").limits[0] and "in truth-stall" in window_table(crit)[3]


def test_a_killed_trackers_absence_is_not_counted_as_a_change_of_the_networks_accuracy():
    steps = 300
    ref = np.tile([2.0, 4.0, 6.0, 8.0], (steps, 1))  # node 0 the best: without it the median moves from 5 to 6 m
    err = ref.copy()
    err[100:150, 0] = np.nan
    faults = _faults((100, "kill", 0), (110, "restart", 0))
    kill, = accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)["windows"]
    assert kill["ratio_network"] == pytest.approx(1.0) and kill["ratio_affected"] == pytest.approx(1.0)
    assert kill["reference_network_m"] == pytest.approx(np.sqrt((50 * 36 + 1 * 25) / 51), rel=1e-6)


def test_trackers_hit_by_overlapping_faults_are_set_aside_from_each_others_network_figure():
    steps, nodes = 300, 8
    ref = np.full((steps, nodes), 5.0)
    err = ref.copy()
    err[100:160, [1, 2, 3, 4]] = 40.0  # four trackers hit at once: the median over all eight moves 4.5x
    faults = _faults((100, "kill", 1), (105, "freeze", 2), (108, "cut", 3), (109, "kill", 4), (110, "restart", 1),
                     (115, "thaw", 2), (118, "heal", 3), (119, "restart", 4))
    crit = accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)
    for w in crit["windows"]:  # each fault's network figure: the trackers no other fault hit, unchanged
        assert w["set_aside"] == sorted({1, 2, 3, 4} - {w["node"]}) and w["ratio_network"] == pytest.approx(1.0)
        assert w["ratio_affected"] == pytest.approx(8.0) and not w["pass"]
    err[100:160, [1, 2, 3, 4]] = 10.0  # the trackers hit within their limit: every window passes
    assert accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)["pass"]
    # the rest of the network misses four trackers at once: each window's network limit is its kind's times the
    # three overlapping faults' (1.25 ** 4 = 2.44); at 1.4x every window passes, at 2.6x every one fails
    err[100:160, [0, 5, 6, 7]] = 7.0
    crit = accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)
    assert all(w["limits"][1] == pytest.approx(fault_named("kill").limits[1] ** 4) for w in crit["windows"])
    assert crit["pass"] and all(w["ratio_network"] == pytest.approx(1.4) for w in crit["windows"])
    err[100:160, [0, 5, 6, 7]] = 13.0
    crit = accuracy_per_fault(fault_windows(faults, steps - 1), err, ref)
    assert not crit["pass"] and all(not w["pass"] and w["ratio_network"] == pytest.approx(2.6) for w in crit["windows"])
    apart = _faults((100, "kill", 1), (110, "restart", 1), (250, "freeze", 2), (255, "thaw", 2))
    err = ref.copy()
    err[100:160, :] = 7.0  # a fault alone: the network 1.4x, over its kind's limit
    crit = accuracy_per_fault(fault_windows(apart, steps - 1), err, ref)
    assert [w["set_aside"] for w in crit["windows"]] == [[], []]
    assert [w["limits"][1] for w in crit["windows"]] == [fault_named("kill").limits[1], fault_named("freeze").limits[1]]
    assert not crit["windows"][0]["pass"] and crit["windows"][1]["pass"] and not crit["pass"]


def test_error_growth_says_how_far_a_fault_free_run_drifts():
    ref = np.tile(np.linspace(5.0, 500.0, 1000)[:, None], (1, 3))
    g = error_growth(ref, 0.1)
    assert g["first_m"] < 40 and g["last_m"] > 450 and g["growth"] > 10 and g["window_s"] == pytest.approx(10.0)


def test_miss_notes_round_trip_on_an_estimate_and_bad_fields_are_wire_errors():
    notes = (MissNote(12, "skipped", "await_meas", 340.5, 4, 900.0, 0.0), MissNote(13, "late_estimate", "fusing", 2.0))
    msg = EstimateMessage(13, 1.3, 1, np.zeros(6), np.eye(6), 5.0, miss_notes=notes)
    back = EstimateMessage.decode(msg.encode(), 1)
    assert back.miss_notes == notes
    assert EstimateMessage.decode(EstimateMessage(13, 1.3, 1, np.zeros(6), np.eye(6), 5.0).encode(), 1).miss_notes == ()
    good = notes[0].pack()
    for i, bad in [(0, -1), (1, "asleep"), (2, "Await Meas"), (3, float("nan")), (3, -1.0), (4, 0), (5, 1e12), (6, "1")]:
        wrong = list(good)
        wrong[i] = bad
        with pytest.raises(WireError):
            unpack_notes([wrong])
    with pytest.raises(WireError):
        unpack_notes([good] * (MAX_MISS_NOTES + 1))


def test_a_frozen_tracker_notes_its_skip_with_the_phase_and_how_late_it_woke():
    net = Net()
    net.start()
    run_steps(net, 0, 9)
    node = net.nodes[0]
    node.timeout()  # the process loop asks how long to wait, then is frozen for 10 steps
    net.frozen = {0}
    run_steps(net, 10, 19)
    net.frozen = set()
    log = run_steps(net, 20, 24)
    notes = [n for i, m in ests(log) if i == 0 for n in m.get("miss_notes", [])]
    assert notes, "the skip reaches the next estimate"
    k, kind, phase, late_ms, steps, idle_ms, _ = notes[0]
    assert kind == "skipped" and phase == "await_meas" and 10 <= k <= 11 and steps >= 9
    assert late_ms > 800 and idle_ms > 800  # frozen about a second
    assert node.payload.counters.misses >= steps


def test_the_miss_report_explains_each_missed_step_of_a_run():
    summary = {"network": {"deadline_misses": 7}, "miss_notes": [
        {"node": 1, "step": 40, "kind": "skipped", "phase": "await_meas", "late_ms": 120.0, "steps": 2,
         "idle_ms": 150.0, "work_ms": 0.0},
        {"node": 2, "step": 90, "kind": "late_estimate", "phase": "await_meas", "late_ms": 3.0, "steps": 1,
         "idle_ms": 0.0, "work_ms": 40.0}],
        "nodes": [{"node": 0, "deadline_misses": 3, "gaps": [[0, 2]], "estimates_lost": 0},
                  {"node": 1, "deadline_misses": 2, "gaps": [[40, 41]], "estimates_lost": 0},
                  {"node": 2, "deadline_misses": 2, "gaps": [], "estimates_lost": 0}]}
    summary["miss_notes"].append(dict(summary["miss_notes"][0], kind="overran", steps=1))  # step 40 overran, then skipped
    summary["nodes"][1]["deadline_misses"] = 3
    rep = miss_report(summary)
    assert [g["node"] for g in rep["gaps"]] == [0] and rep["unexplained"] == 1  # node 2: one miss nobody noted
    assert "frozen or starved" in rep["notes"][0]["why"] and "40.0 ms update" in rep["notes"][1]["why"]
    lines = miss_lines(rep, "reference")
    assert lines[0].startswith("reference: 7 deadline misses, 3 noted") and "1 unexplained" in lines[0]
    assert any("node 0: no estimate at steps 0-2" in ln for ln in lines)


def test_usage_is_binned_per_process_type_and_a_restart_counts_from_its_new_pid():
    import os

    from zentrack.cluster.soak.usage import cpu_seconds, usage_by_type

    assert cpu_seconds(os.getpid()) > 0 and cpu_seconds(2**22 + 12345) is None
    rss = {"node-0": [(0.0, 100.0, 1), (70.0, 110.0, 1)], "node-1": [(0.0, 120.0, 2), (70.0, 130.0, 2)],
           "truth": [(0.0, 80.0, 3)]}
    cpu = {"node-0": [(0.0, 1.0, 1), (30.0, 7.0, 1), (70.0, 0.5, 9)],  # killed and restarted: pid 9 from 0.5 s
           "node-1": [(0.0, 2.0, 2), (30.0, 5.0, 2), (70.0, 17.0, 2)]}
    use = usage_by_type(rss, cpu)
    assert use["node"]["t_s"] == [0.0, 60.0] and use["node"]["rss_mib"] == [110.0, 120.0]
    assert use["node"]["cpu_cores"] == [pytest.approx(9.0 / 60), pytest.approx(12.0 / 60)]
    assert use["truth"] == {"t_s": [0.0], "rss_mib": [80.0], "cpu_cores": [0.0]}
