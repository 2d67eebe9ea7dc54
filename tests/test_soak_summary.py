"""The figures of a finished soak by fault kind and process type (``zentrack.cluster.soak.summary``)."""
from __future__ import annotations

import pytest

from zentrack.cluster.soak.summary import fault_lines, faults_by_kind, loss_lines, undo_kind, usage_lines


@pytest.mark.parametrize(("after", "kind"), [("restart node-3", "kill"), ("thaw node-10", "freeze"),
                                             ("heal node-0", "cut"), ("resume truth", "truth-stall"),
                                             ("restart truth", "truth-kill"), ("restart router", "router-kill")])
def test_each_fault_end_names_the_kind_of_fault_it_ended(after, kind):
    assert undo_kind(after) == kind


@pytest.mark.parametrize("after", ["explode node-1", "restart", ""])
def test_an_unknown_fault_end_is_refused(after):
    with pytest.raises(ValueError, match="unknown fault end"):
        undo_kind(after)


def test_faults_by_kind_count_each_kind_and_its_recovery_steps():
    ends = [("restart node-1", 7), ("restart node-2", None), ("restart node-4", 12), ("resume truth", 9),
            ("restart router", 13)]
    report = {"criteria": {"publishing_after_fault": {"events": [{"after": a, "steps_to_all_estimating": s}
                                                                 for a, s in ends]}}}
    kinds = faults_by_kind(report)
    assert list(kinds) == ["kill", "router-kill", "truth-stall"]
    assert kinds["kill"] == {"count": 3, "recovery_steps": [7, None, 12], "median": 9.5, "max": 12, "never": 1}
    lines = fault_lines(report)
    assert lines[0] == "kill: 3 ended, every live tracker publishing again after 9.5 steps (median), 12 at worst, 1 never"
    assert faults_by_kind({"criteria": {}}) == {}


def test_usage_and_loss_lines_give_each_run_and_type():
    usage = {"faulty": {"node": {"t_s": [0, 60, 120], "rss_mib": [None, 100.0, 104.0], "cpu_cores": [0.2, 0.6, 0.4]}}}
    assert usage_lines(usage) == ["faulty node: RSS 100.0 -> 104.0 MiB per process (first -> last minute), "
                                  "CPU 0.400 cores median, 0.600 peak"]
    misses = {"reference": {"deadline_misses": 3, "notes": [{}, {}], "unexplained": 1,
                            "gaps": [{"node": 0, "steps": [[10, 12], [20, 20]], "estimates_lost": 2}]}}
    assert loss_lines(misses) == ["reference: 3 deadline misses, 2 noted by the trackers, 4 tracker-steps without an "
                                  "estimate, 2 estimates lost on the way, 1 unexplained"]
