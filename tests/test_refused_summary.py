"""A run whose trackers refused messages says so: the summary's per-kind counts and the closing line."""
from __future__ import annotations

from pathlib import Path

from zentrack.cluster.recording.core import refused_counts
from zentrack.common.run_summary import ok_line


def _node(rejected: dict, dropped: dict, conflicts: int) -> dict:
    return {"messages": {"rejected": rejected, "dropped": dropped, "conflicts": conflicts, "gated": 7}}


def test_refusals_are_summed_per_kind_and_named_in_the_closing_line():
    nodes = [_node({"early": 300, "duplicate": 1}, {"meas/undecodable": 2000}, 4),
             _node({"early": 290}, {}, 0), _node({}, {}, 0)]
    refused = refused_counts(nodes)
    assert refused == {"dropped meas/undecodable": 2000, "early": 590, "conflicts": 4, "duplicate": 1}
    line = ok_line({"network": {"refused": refused}}, Path("out/run"))
    assert line.startswith("run OK, but the trackers refused 2595 message(s) (2000 dropped meas/undecodable, 590 early")
    assert "summary written to out/run/summary.json" in line


def test_a_clean_run_closes_with_a_bare_ok():
    assert refused_counts([_node({}, {}, 0)]) == {}
    assert ok_line({"network": {"refused": {}}}, Path("o")) == "run OK: summary written to o/summary.json"
