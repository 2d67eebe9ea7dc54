"""The verdict on a run whose trackers were cut off for a stretch (issue 30, item 1): outages and coasted
stretches per node, no failure for a node that came back, a closing line that names them."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from zentrack.common.outages import node_outages, partition_notes
from zentrack.common.run_summary import ok_line, run_failures


def _flags(steps: int, missing=(), coasted=()) -> tuple[np.ndarray, np.ndarray]:
    have, coast = np.ones(steps, dtype=bool), np.zeros(steps, dtype=bool)
    for a, b in missing:
        have[a:b + 1] = False
    for a, b in coasted:
        coast[a:b + 1] = True
    return have, coast


def _node(i: int, steps: int, missing=(), coasted=(), published: int | None = None) -> dict:
    have, coast = _flags(steps, missing, coasted)
    return {"node": i, "steps_without_estimate": int((~have).sum()), "gaps": [], "estimates_lost": 0,
            "estimates_published": int(have.sum()) if published is None else published,
            **node_outages(have, coast)}


def test_a_stretch_cut_off_then_back_is_an_outage_and_a_late_start_or_a_blip_is_not():
    have, coast = _flags(300, missing=[(0, 9), (100, 199), (250, 252)], coasted=[(40, 60)])
    out = node_outages(have, coast)
    assert out == {"outages": [[100, 199]], "coasted_stretches": [[40, 60]], "missing_at_end": 0}
    # never came back: the last stretch reaches the run's end
    have, coast = _flags(300, missing=[(100, 299)])
    assert node_outages(have, coast) == {"outages": [], "coasted_stretches": [], "missing_at_end": 200}
    # a relay coasts on every step by design: not reported
    have, coast = _flags(300, coasted=[(0, 299)])
    assert node_outages(have, coast)["coasted_stretches"] == []


def test_a_node_that_came_back_is_not_failed_and_the_closing_line_says_what_happened():
    steps = 300
    summary = {"network": {"steps": steps, "refused": {}},
               "nodes": [_node(0, steps, coasted=[(81, 130)]), _node(1, steps),
                         _node(3, steps, missing=[(81, 183)]), _node(4, steps, missing=[(81, 183)])]}
    assert run_failures(summary, 0.1) == []
    line = ok_line(summary, Path("out"))
    assert line.startswith("run OK, but ") and line.endswith("summary written to out/summary.json"), line
    assert "nodes 3, 4 sent no estimate through steps 81-183 (103 steps) and came back" in line, line
    assert "node 0 coasted through steps 81-130 (50 steps)" in line, line
    assert partition_notes({"nodes": [_node(1, steps)]}) == []


def test_a_node_that_never_came_back_still_fails():
    steps = 300
    summary = {"network": {"steps": steps, "refused": {}}, "nodes": [_node(2, steps, missing=[(100, 299)])]}
    failures = run_failures(summary, 0.1)
    assert len(failures) == 1 and failures[0].startswith("node 2 published no estimate for 200 of 300"), failures


def test_a_tracker_that_received_no_detection_from_its_sensors_fails():
    """Sensors of their own: a tracker whose sensors never reached it coasts on every step and publishes every
    one; the estimate checks pass it, this one does not."""
    steps = 100
    fed, starved = _node(0, steps), _node(1, steps)
    fed["detections"] = {"det_rx": 90, "too_old": 0}
    starved["detections"] = {"det_rx": 0, "too_old": 0}
    summary = {"network": {"steps": steps, "refused": {}}, "nodes": [fed, starved, _node(2, steps)]}
    failures = run_failures(summary, 0.1)
    assert len(failures) == 1 and failures[0].startswith("node 1 received no detection from its sensors in 100 "), \
        failures
    starved["detections"]["det_rx"] = 1
    assert run_failures(summary, 0.1) == []
