"""Trackers on their own clocks, live (issue 52, item 3): ``exp2-async`` (six trackers of sensors of their own, over
Zenoh) with tracker 1's host clock 0.3 s ahead (``faketime -f +0.3s`` through ``Cluster(node_prefix=...)``).
No truth measurement reaches a tracker in such a run, so tracker 1 runs on its own clock: its neighbours 0 and 2
estimate its offset from its round messages, fuse its message of step s + 3 at step s (predicted back over the
estimate's residual) and it theirs of s - 3; the recorder estimates its clock the same way and judges its
estimates at their time of validity (``node/diffusion/neighbour_clocks.py``, ``cluster/recording/estimates.py``).

Every figure is compared within the run: each tracker's RMSE against the median of the three trackers that do not
neighbour tracker 1 (3, 4, 5), its deadline misses against theirs. Measured (12 runs, 4 beside a busy loop; the
limits below): its neighbours' estimates of its offset 0.3-1.1 ms below 0.3 s, its of theirs 0.4-1.0 ms beyond
-0.3 s, the recorder's 0.3-0.5 ms below; RMSE 6.90-7.07 m for tracker 1, 6.64-6.81 m for its neighbours against
7.14-7.25 m. Broken: with the neighbours' clocks taken as synchronised (as before), tracker 1 refused every
neighbour's prior as ``stale`` and tracked on its own bearings alone (182 m, 220 partial rounds of 220), its
neighbours 1.10-1.14 times the reference; judged at step k, its estimates came out 1.15 times the reference. The
prediction over the residual (-0.5 ms here, the bus's least delay) changes nothing measurable in this run
(tests/test_neighbour_clocks.py has the skews where it does)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from zentrack.cli import build_parser
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import resolve_setup

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("faketime") is None, reason="needs faketime (Debian's faketime)")]

STEPS, SKEWED, SKEW = 220, 1, 0.3
NEIGHBOURS, OTHERS = (0, 2), (3, 4, 5)
#: how far below the true offset a neighbour's estimate may lie (the least one-way delay of a round message, and
#: the low quantile of the delays above it); measured 0.4 to 1.1 ms below (see the module's measured figures)
OFFSET_BELOW_S = 0.005
#: the pairs a tracker fuses a step on average, its own included (all three: 3; measured 2.86 to 2.97, a round
#: now and then without a late neighbour; before, tracker 1 fused its own alone: 1.0)
MIN_PAIRS = 2.5
#: the largest RMSE of tracker 1 and its neighbours, each against the median of trackers 3, 4 and 5: measured
#: 0.93-0.98 (tracker 1: 0.966-0.978); judged at step k instead of its estimates' time of validity, tracker 1's
#: came out 1.11-1.16
RMSE_RATIO = 1.05
#: deadline misses tracker 1 or a neighbour may count (its own count: a warm start's step without an estimate,
#: which the seeded 1 Hz sensors of trackers 2 and 5 cause at the same steps in every run, is not one) beyond the
#: most of trackers 3, 4 and 5: measured 0 to 1 beyond, beside a busy loop too, and 4, 4 and 8 (0 for 3, 4 and 5)
#: in a run during which another live test's 13 processes started: a second of starved wake-ups (20-80 ms late)
#: that fell on trackers 0, 1 and 2. A tracker that misses for its clock misses steadily (issue 52: 344 of 395)
EXTRA_MISSES = 10


def setup():
    argv = ["run", "--scenario", "exp2-async", "--steps", str(STEPS), "--out", "unused"]
    return resolve_setup(build_parser(argv).parse_args(argv))


def test_a_tracker_whose_clock_is_300_ms_ahead_is_fused_at_its_time_and_judged_at_it(tmp_path):
    out = tmp_path / "run"
    with Cluster(setup(), out, node_prefix={SKEWED: ["faketime", "-f", f"{SKEW:+g}s"]}) as cluster:
        cluster.start()
        assert cluster.wait(timeout=STEPS * 0.1 * 3 + 60) == 0, "the truth failed"
        cluster.stop()
        summary = cluster.write_results()
    nodes = summary["nodes"]
    rmse = [n["rmse_p"] for n in nodes]
    reference = float(np.median([rmse[i] for i in OTHERS]))
    figures = (f"rmse {[round(r, 2) for r in rmse]}, reference {reference:.2f}, pairs "
               f"{[round(n['mean_pairs_fused'], 2) for n in nodes]}; misses "
               f"{[n['reported_misses'] for n in nodes]} (steps without an estimate "
               f"{[n['steps_without_estimate'] for n in nodes]}); partial rounds "
               f"{[n['messages']['partial_rounds'] for n in nodes]}; neighbour offsets "
               f"{[n.get('neighbour_offsets_s') for n in nodes]}; seen {[n.get('clock_offset_seen_s') for n in nodes]}")
    print(figures)
    assert run_failures(summary, 0.1) == [], (run_failures(summary, 0.1), figures)
    # (a) its neighbours' estimate of its clock, its own of theirs, and the recorder's
    for i in NEIGHBOURS:
        assert SKEW - OFFSET_BELOW_S <= nodes[i]["neighbour_offsets_s"][str(SKEWED)] <= SKEW, figures
        assert -SKEW - OFFSET_BELOW_S <= nodes[SKEWED]["neighbour_offsets_s"][str(i)] <= -SKEW, figures
    assert SKEW - OFFSET_BELOW_S <= nodes[SKEWED]["clock_offset_seen_s"] <= SKEW, figures
    assert all(nodes[i]["clock_offset_seen_s"] == 0.0 for i in (*NEIGHBOURS, *OTHERS)), figures
    assert all(v == 0.0 for i in OTHERS for v in nodes[i]["neighbour_offsets_s"].values()), figures
    # (b) it and its neighbours fuse each other's messages and track as the others do
    for i in (SKEWED, *NEIGHBOURS):
        assert nodes[i]["mean_pairs_fused"] >= MIN_PAIRS, (i, nodes[i]["mean_pairs_fused"], figures)
        assert rmse[i] <= RMSE_RATIO * reference, (i, figures)
    # (c) and miss no more deadlines than they do
    worst = max(nodes[i]["reported_misses"] for i in OTHERS)
    for i in (SKEWED, *NEIGHBOURS):
        assert nodes[i]["reported_misses"] <= worst + EXTRA_MISSES, (i, figures)
