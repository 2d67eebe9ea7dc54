"""The soak's fault registry (``zentrack.cluster.soak.fault_kinds``, issue 51 item 3): a kind of fault is one entry
there plus the verbs of the backends that apply it. A kind registered here, in the test, flows through the flags,
the schedule, the plan, the windows, the accuracy limits, the criteria and the figure's colour with no other file
edited; a backend without a fault's verbs is refused before the soak starts, naming the fault and the backend
(each backend's verbs: ``test_soak_backends.py``)."""
from __future__ import annotations

import argparse
import re

import numpy as np
import pytest
from matplotlib.colors import to_rgb

from zentrack.cluster.soak import fault_kinds
from zentrack.cluster.soak.accuracy import accuracy_per_fault
from zentrack.cluster.soak.backends import LoopbackBackend
from zentrack.cluster.soak.command import ENGINES, add_arguments, auto_engine
from zentrack.cluster.soak.criteria import publishing_after_fault
from zentrack.cluster.soak.fault_kinds import (
    FOLLOW_DETECTIONS,
    SENSOR,
    SENSOR_LIMITS,
    TRACKER,
    Fault,
    UnknownFault,
    blinds_all,
    brings_back,
    dispatch,
    fault_actions,
    fault_named,
    fault_of,
    flag_length,
    hit_trackers,
    registered,
    sensor_of,
    undo_actions,
    unsupported,
    window_limits,
)
from zentrack.cluster.soak.faults import fault_windows, plan_lines, schedule
from zentrack.cluster.soak.plot import error_figure
from zentrack.cluster.soak.summary import faults_by_kind, undo_kind

#: a kind of fault no backend has: a tracker's disk fills for --fault-s
DISK_FULL = Fault("disk-full", "fill", "free", "--disk-full-every", "fill a tracker's disk this often, s (0: none)",
                  TRACKER, flag_length("fault_s"), (3.0, 1.5), "#8c564b", "fill_disk", "free_disk", "full disk")


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(["--out", "unused", *argv])


def example_target(f: Fault) -> int | str:
    """A target of the kind ``f`` hits: tracker 0, sensor 0's process, or its service."""
    return 0 if f.hits(0) else "sensor-0" if f.target == SENSOR else f.target


def test_the_registry_is_consistent():
    kinds = registered()
    assert len({f.name for f in kinds}) == len(kinds) and len({f.flag for f in kinds}) == len(kinds)
    assert len({(f.action, f.target) for f in kinds}) == len(kinds), "an event names one kind on its target"
    for f in kinds:
        assert fault_actions()[f.action] == f.undo, f"{f.action} is undone by one action whatever its target"
        assert f.undo not in fault_actions() and f.action not in undo_actions()
        assert all(limit >= 1.0 for limit in f.limits) and re.fullmatch("#[0-9a-f]{6}", f.colour)
        assert any(fault_kinds.has_verbs(backend, f) for backend in ENGINES.values()), f"no engine applies {f.name}"
        assert fault_of(f.action, example_target(f)) is f
        assert fault_of(f.undo, example_target(f)) is f
    assert [f.name for f in kinds if f.exits] == ["kill", "truth-kill", "router-kill", "sensor-kill"]
    assert list(window_limits()) == ["kill", "freeze", "cut", "drain", "sensor-kill", "clock-jump", "truth-stall",
                                     "truth-kill", "router-kill"]


def test_what_each_kind_is_judged_as_and_its_limits():
    """The values themselves: a registry edit that moves one is seen here."""
    assert {f.name: (f.action, f.undo, f.flag, f.target, f.limits, f.phase_s) for f in registered()} == {
        "kill": ("kill", "restart", "--kill-every", TRACKER, (2.5, 1.25), 0.0),
        "freeze": ("freeze", "thaw", "--freeze-every", TRACKER, (2.5, 1.25), 0.0),
        "cut": ("cut", "heal", "--cut-every", TRACKER, (2.5, 1.25), 0.0),
        "truth-stall": ("stall", "resume", "--truth-stall-every", "truth", (4.0, 4.0), 15.0),
        "truth-kill": ("kill", "restart", "--truth-kill-every", "truth", (5.0, 5.0), 10.0),
        "router-kill": ("kill", "restart", "--router-every", "router", (5.0, 5.0), 20.0),
        "drain": ("drain", "undrain", "--drain-every", "swarm", (2.5, 1.25), 7.5),
        "sensor-kill": ("kill", "restart", "--sensor-kill-every", SENSOR, (2.0, 1.4), 5.0),
        "clock-jump": ("jump", "followed", "--clock-jump-every", SENSOR, (2.0, 1.4), 12.5)}
    assert fault_of("restart", "router").name == "router-kill" and fault_of("undrain", 4).name == "drain"
    assert brings_back("restart", 3) and brings_back("restart", "truth") and not brings_back("thaw", 3)
    with pytest.raises(UnknownFault, match="'freeze' on router"):
        fault_of("freeze", "router")


SENSOR_KINDS = {"sensor-kill", "clock-jump"}


@pytest.mark.parametrize("engine, lacks", [("loopback", {"cut", "drain"}), ("netns", {"drain", *SENSOR_KINDS}),
                                           ("compose", {"drain", *SENSOR_KINDS}), ("stack", {"cut", *SENSOR_KINDS})])
def test_each_engine_refuses_the_faults_whose_verbs_its_backend_lacks_before_anything_starts(engine, lacks):
    for fault in registered():
        line = unsupported([fault], engine, ENGINES)
        assert (line is not None) == (fault.name in lacks), (engine, fault.name, line)
        if line is not None:
            assert line.startswith(f"{fault.flag} needs --engine ") and f"--engine {engine} has no {fault.noun}" in line
            assert ENGINES[engine].__name__ in line and f"{fault.verb!r} verb" in line
    assert unsupported([fault_named("cut")], "stack", ENGINES) == (
        "--cut-every needs --engine netns or compose: --engine stack has no link cut (StackBackend has no 'cut' "
        "verb: a swarm task's overlay link is the orchestrator's)")


def test_auto_takes_namespaces_only_for_a_fault_loopback_lacks_and_namespaces_have():
    assert auto_engine([fault_named("kill"), fault_named("freeze"), fault_named("truth-stall")]) == "loopback"
    assert auto_engine([fault_named("kill"), fault_named("cut")]) == "netns"
    assert auto_engine([fault_named("drain")]) == "loopback"  # no namespace drains either: refused as loopback


class _DiskBackend:
    ENGINE = "disks"

    def __init__(self) -> None:
        self.calls: list[tuple[str, str]] = []

    def fill_disk(self, service: str) -> None:
        self.calls.append(("fill_disk", service))

    def free_disk(self, service: str) -> None:
        self.calls.append(("free_disk", service))


def test_a_kind_registered_alone_flows_through_schedule_plan_windows_limits_criteria_and_colour(monkeypatch):
    monkeypatch.setattr(fault_kinds, "KINDS", (*fault_kinds.KINDS, DISK_FULL))
    # its flag, among the soak's, with its help
    args = _parse(["--duration", "200", "--nodes", "4", "--kill-every", "0", "--freeze-every", "0", "--cut-every", "0",
                   "--disk-full-every", "40", "--fault-s", "6"])
    assert args.disk_full_every == 40.0
    # the schedule: every 40 s on the least busy tracker, --fault-s long, each with its undo
    events = schedule(args)
    fills = [e for e in events if e[1] == "fill"]
    assert [t for t, _, _ in fills] == [40.0, 80.0, 120.0, 160.0] and all(isinstance(n, int) for _, _, n in fills)
    assert [t for t, a, _ in events if a == "free"] == [46.0, 86.0, 126.0, 166.0]
    plan = plan_lines(events, args, "disks")
    assert plan[1].split()[:3] == ["40.0", "s", "fill"] and "free at 46.0 s" in plan[1]
    assert plan[-1] == "4 faults; nothing started (--plan)"
    # what a backend with its verbs does; what one without them says, before anything starts
    disks = _DiskBackend()
    assert dispatch(disks, "fill", 2) is None and dispatch(disks, "free", 2) is None
    assert disks.calls == [("fill_disk", "node-2"), ("free_disk", "node-2")]
    line = unsupported([DISK_FULL], "netns", ENGINES)
    assert line == ("--disk-full-every can be applied by no engine: --engine netns has no full disk (NetnsBackend has "
                    "no 'fill_disk' verb)")
    # the applied faults' windows, judged by its own limits
    steps, nodes = 600, 4
    applied = [{"t": 10.0, "action": "fill", "node": 1, "step": 100}, {"t": 16.0, "action": "free", "node": 1, "step": 160},
               {"t": 30.0, "action": "kill", "node": 2, "step": 300}, {"t": 32.0, "action": "restart", "node": 2, "step": 320}]
    windows = fault_windows(applied, steps - 1)
    assert [(w["kind"], w["undo"]) for w in windows] == [("fill", "free"), ("kill", "restart")]
    ref = np.full((steps, nodes), 4.0)
    err = ref.copy()
    err[100:200, 1] = 4.0 * 2.8  # over a kill's 2.5, within its own 3.0
    crit = accuracy_per_fault(windows, err, ref)
    disk = crit["windows"][0]
    assert disk["kind"] == "disk-full" and disk["limits"] == [3.0, 1.5] and disk["pass"] and crit["pass"]
    assert crit["limits"]["disk-full"] == [3.0, 1.5]
    # its end is a fault end for the criteria, and a kind in the summary
    have = np.isfinite(err)
    events_after = publishing_after_fault(applied, have, steps)["events"]
    assert events_after[0]["after"] == "free node-1" and undo_kind("free node-1") == "disk-full"
    assert faults_by_kind({"criteria": {"publishing_after_fault": {"events": events_after}}})["disk-full"]["count"] == 1
    assert not brings_back("free", 1)
    # the figure: its span in its colour, labelled with its undo
    fig = error_figure(err, applied, 0.1, "test")
    spans = {p.get_label(): to_rgb(p.get_facecolor()) for p in fig.axes[1].patches}
    assert spans["fill \u2192 free"] == to_rgb(DISK_FULL.colour) and spans["kill \u2192 restart"] == to_rgb("#d62728")


def test_a_registered_kind_reaches_the_command_line_and_its_plan(monkeypatch, capsys):
    """``zentrack soak --plan`` with a kind registered alone and a verb given to the loopback backend."""
    from zentrack.cli import main

    monkeypatch.setattr(fault_kinds, "KINDS", (*fault_kinds.KINDS, DISK_FULL))
    argv = ["soak", "--duration", "100", "--nodes", "4", "--kill-every", "0", "--freeze-every", "0", "--cut-every", "0",
            "--disk-full-every", "30", "--out", "unused", "--plan"]
    assert main(argv) == 2  # no engine has its verbs: refused in one line before anything starts
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--disk-full-every" in err[0] and "LoopbackBackend has no 'fill_disk' verb" in err[0], err
    for verb in ("fill_disk", "free_disk"):
        monkeypatch.setattr(LoopbackBackend, verb, lambda self, service: None, raising=False)
    assert main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [ln.split()[2] for ln in lines[1:-1]] == ["fill"] * 2 and lines[-1] == "2 faults; nothing started (--plan)"


# ---------------------------------------------------------------- faults of sensors of their own (issue 52)
#: exp2-async's six sensors: their rates, and tracker S takes sensor S
RATES = {0: 10.0, 1: 4.0, 2: 1.0, 3: 10.0, 4: 4.0, 5: 1.0}
TAKERS = {s: [s] for s in RATES}


def _sensor_args(argv: list[str]) -> argparse.Namespace:
    args = _parse(["--nodes", "6", "--kill-every", "0", "--freeze-every", "0", "--cut-every", "0", *argv])
    args.nodes, args.sensor_rates, args.sensor_takers = 6, RATES, TAKERS
    return args


def test_a_sensor_kind_hits_sensor_processes_and_judges_the_trackers_that_take_them():
    assert fault_of("kill", "sensor-2").name == "sensor-kill" and fault_of("restart", "sensor-2").name == "sensor-kill"
    assert fault_of("kill", 2).name == "kill" and fault_of("kill", "truth").name == "truth-kill"
    assert fault_of("jump", "sensor-5").name == "clock-jump" and fault_of("followed", "sensor-5").name == "clock-jump"
    with pytest.raises(UnknownFault):
        fault_of("jump", 3)  # a clock jump is a sensor's, never a tracker's
    assert sensor_of("sensor-12") == 12 and sensor_of("sensor-x") is None and sensor_of(3) is None
    assert not blinds_all("sensor-1") and not blinds_all(1) and blinds_all("truth") and blinds_all("router")
    assert hit_trackers({"node": "sensor-2"}, 6) == [2]  # by default tracker S takes sensor S
    assert hit_trackers({"node": "sensor-2", "trackers": [1, 2, 3]}, 6) == [1, 2, 3]
    assert hit_trackers({"node": 4}, 6) == [4] and hit_trackers({"node": "router"}, 3) == [0, 1, 2]
    assert brings_back("restart", "sensor-1") and not brings_back("followed", "sensor-1")


def test_a_clock_jump_lasts_until_its_trackers_follow_its_sensors_clock():
    """The window of a clock step is its sensor's: FOLLOW_DETECTIONS detections (the intake's offset estimate, a
    low quantile of the last 64 samples, moves to the stepped clock at the 61st) and a margin."""
    assert FOLLOW_DETECTIONS == 61
    length = fault_named("clock-jump").length(_sensor_args([]))
    assert [length(f"sensor-{s}") for s in (0, 1, 2)] == [7.1, 16.25, 62.0]
    with pytest.raises(ValueError, match="no sensor"):
        length("sensor-9")
    assert fault_named("sensor-kill").length(_sensor_args(["--restart-after", "3"]))("sensor-1") == 3.0


def test_the_schedule_picks_sensors_whose_fault_ends_in_time_and_keeps_their_trackers_from_two_faults():
    args = _sensor_args(["--duration", "120", "--kill-every", "20", "--sensor-kill-every", "20",
                         "--clock-jump-every", "30"])
    events = schedule(args)
    assert events == schedule(args) and events != schedule(_sensor_args(["--duration", "120", "--kill-every", "20",
                                                                         "--sensor-kill-every", "20",
                                                                         "--clock-jump-every", "30", "--seed", "5"]))
    jumps = [(t, target) for t, a, target in events if a == "jump"]
    followed = {target: t for t, a, target in events if a == "followed"}
    assert [t for t, _ in jumps] == [42.5, 72.5, 102.5]
    for t, target in jumps:  # each jump's window is its sensor's, and ends 5 s before the soak does
        assert followed[target] - t == pytest.approx(FOLLOW_DETECTIONS / RATES[sensor_of(target)] + 1.0, abs=0.02)
        assert followed[target] < 115.0
    assert sensor_of(jumps[-1][1]) in (0, 3), "at 102.5 s only a 10 Hz sensor's window ends in time"
    kills = [(t, target) for t, a, target in events if a == "kill" and isinstance(target, str)]
    assert [t for t, _ in kills] == [25.0, 45.0, 65.0, 85.0, 105.0]
    # the trackers' faults and the sensors' of the sensors they take: never two at once on one tracker while
    # another is free (here always one is)
    spans: dict[int, list[tuple[float, float]]] = {}
    began: dict[int | str, float] = {}
    for t, action, target in events:
        if action in fault_actions():
            began[target] = t
        else:
            tracker = target if isinstance(target, int) else sensor_of(target)
            spans.setdefault(tracker, []).append((began.pop(target), t))
    for tracker, mine in spans.items():
        mine.sort()
        for (a1, b1), (a2, _b2) in zip(mine, mine[1:]):
            assert a2 >= b1, f"tracker {tracker}: a fault at {a2} s while under one from {a1} to {b1} s"
    plan = plan_lines(events, args, "loopback")
    assert any(line.split()[2:4] == ["jump", jumps[0][1]] and "followed at" in line for line in plan), plan
    assert any(line.split()[2:4] == ["kill", kills[0][1]] and "restart at 27.0 s" in line for line in plan), plan


def test_a_sensor_fault_window_is_judged_on_its_trackers_and_set_aside_from_overlapping_ones():
    steps, nodes = 600, 6
    applied = [{"t": 10.0, "action": "jump", "node": "sensor-1", "step": 100, "trackers": [1]},
               {"t": 26.3, "action": "followed", "node": "sensor-1", "step": 263},
               {"t": 20.0, "action": "kill", "node": "sensor-4", "step": 200, "trackers": [4]},
               {"t": 22.0, "action": "restart", "node": "sensor-4", "step": 220}]
    windows = fault_windows(sorted(applied, key=lambda f: f["step"]), steps - 1)
    assert [(w["kind"], w["node"], w.get("trackers")) for w in windows] == [("jump", "sensor-1", [1]),
                                                                         ("kill", "sensor-4", [4])]
    ref = np.full((steps, nodes), 4.0)
    err = ref.copy()
    err[100:304, 1] = 4.0 * 1.8  # the tracker whose sensor's clock jumped: 1.8x its reference's error
    crit = accuracy_per_fault(windows, err, ref)
    jump, kill = crit["windows"]
    assert jump["kind"] == "clock-jump" and jump["affected"] == [1] and jump["ratio_affected"] == pytest.approx(1.8)
    assert jump["set_aside"] == [4] and jump["limits"] == [SENSOR_LIMITS[0], SENSOR_LIMITS[1] ** 2]
    assert kill["kind"] == "sensor-kill" and kill["set_aside"] == [1] and kill["ratio_affected"] == 1.0
    assert jump["pass"] and kill["pass"] and crit["pass"]
    err[100:304, 1] = 4.0 * 2.2  # beyond the affected limit of a sensor fault (2.0)
    assert not accuracy_per_fault(windows, err, ref)["windows"][0]["pass"]
    err[100:304, 1] = 4.0 * 1.8
    # a sensor fault's end is judged like any other fault's: every tracker publishes again; none blinds them all
    have = np.isfinite(err)
    events_after = publishing_after_fault(sorted(applied, key=lambda f: f["step"]), have, steps)["events"]
    assert [e["after"] for e in events_after] == ["restart sensor-4", "followed sensor-1"]
    assert all(len(e["per_node"]) == nodes and e["steps_to_all_estimating"] == 0 for e in events_after)
    assert [undo_kind(e["after"]) for e in events_after] == ["sensor-kill", "clock-jump"]
    fig = error_figure(err, applied, 0.1, "test")  # each in its own colour, the sensor kill named apart
    spans = {p.get_label(): to_rgb(p.get_facecolor()) for p in fig.axes[1].patches}
    assert spans["jump \u2192 followed"] == to_rgb(fault_named("clock-jump").colour)
    assert spans["kill \u2192 restart"] == to_rgb(fault_named("sensor-kill").colour)


def test_a_clock_jump_has_no_undo_verb_its_window_just_ends():
    class Jumps:
        ENGINE = "jumps"

        def __init__(self) -> None:
            self.calls: list[str] = []

        def jump_clock(self, service: str) -> None:
            self.calls.append(service)

    backend = Jumps()
    jump = fault_named("clock-jump")
    assert jump.undo_verb == "" and fault_kinds.has_verbs(backend, jump)
    assert dispatch(backend, "jump", "sensor-3") is None and dispatch(backend, "followed", "sensor-3") is None
    assert backend.calls == ["sensor-3"], "the clock stays back: nothing is done at its window's end"


@pytest.mark.parametrize("flag", ["--sensor-kill-every", "--clock-jump-every"])
def test_a_sensor_fault_is_refused_in_one_line_for_a_scenario_whose_truth_measures(flag, capsys, tmp_path):
    from zentrack.cli import main

    out = tmp_path / "soak"
    assert main(["soak", "--duration", "60", "--cut-every", "0", flag, "20", "--out", str(out), "--plan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0] and "scenario patrol has no sensors of their own" in err[0], err
    assert not out.exists()
    argv = ["soak", "--scenario", "exp2-async", "--duration", "60", "--kill-every", "0", "--freeze-every", "0",
            "--cut-every", "0", flag, "20", "--out", str(out), "--plan"]
    assert main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) >= 3 and all("sensor-" in line for line in lines[1:-1]), lines
    assert main([*argv[:-1], "--engine", "compose", "--plan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--engine compose has no sensor" in err[0] and "needs --engine loopback" in err[0], err
