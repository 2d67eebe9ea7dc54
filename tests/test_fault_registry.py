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
    TRACKER,
    Fault,
    UnknownFault,
    brings_back,
    dispatch,
    fault_actions,
    fault_named,
    fault_of,
    flag_length,
    registered,
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


def test_the_registry_is_consistent():
    kinds = registered()
    assert len({f.name for f in kinds}) == len(kinds) and len({f.flag for f in kinds}) == len(kinds)
    assert len({(f.action, f.target) for f in kinds}) == len(kinds), "an event names one kind on its target"
    for f in kinds:
        assert fault_actions()[f.action] == f.undo, f"{f.action} is undone by one action whatever its target"
        assert f.undo not in fault_actions() and f.action not in undo_actions()
        assert all(limit >= 1.0 for limit in f.limits) and re.fullmatch("#[0-9a-f]{6}", f.colour)
        assert any(fault_kinds.has_verbs(backend, f) for backend in ENGINES.values()), f"no engine applies {f.name}"
        assert fault_of(f.action, 0 if f.hits(0) else f.target) is f
        assert fault_of(f.undo, 0 if f.hits(0) else f.target) is f
    assert [f.name for f in kinds if f.exits] == ["kill", "truth-kill", "router-kill"]
    assert list(window_limits()) == ["kill", "freeze", "cut", "drain", "truth-stall", "truth-kill", "router-kill"]


def test_what_each_kind_is_judged_as_and_its_limits():
    """The values themselves: a registry edit that moves one is seen here."""
    assert {f.name: (f.action, f.undo, f.flag, f.target, f.limits, f.phase_s) for f in registered()} == {
        "kill": ("kill", "restart", "--kill-every", TRACKER, (2.5, 1.25), 0.0),
        "freeze": ("freeze", "thaw", "--freeze-every", TRACKER, (2.5, 1.25), 0.0),
        "cut": ("cut", "heal", "--cut-every", TRACKER, (2.5, 1.25), 0.0),
        "truth-stall": ("stall", "resume", "--truth-stall-every", "truth", (4.0, 4.0), 15.0),
        "truth-kill": ("kill", "restart", "--truth-kill-every", "truth", (5.0, 5.0), 10.0),
        "router-kill": ("kill", "restart", "--router-every", "router", (5.0, 5.0), 20.0),
        "drain": ("drain", "undrain", "--drain-every", "swarm", (2.5, 1.25), 7.5)}
    assert fault_of("restart", "router").name == "router-kill" and fault_of("undrain", 4).name == "drain"
    assert brings_back("restart", 3) and brings_back("restart", "truth") and not brings_back("thaw", 3)
    with pytest.raises(UnknownFault, match="'freeze' on router"):
        fault_of("freeze", "router")


@pytest.mark.parametrize("engine, lacks", [("loopback", {"cut", "drain"}), ("netns", {"drain"}),
                                           ("compose", {"drain"}), ("stack", {"cut"})])
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
