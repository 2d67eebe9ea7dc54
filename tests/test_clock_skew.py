"""Clock skew, end to end (realtime exp2, 6 trackers over Zenoh): a tracker whose host clock is 0.3 s ahead or
behind the run's schedule (``faketime``, through ``Cluster(node_prefix=...)``, the ``--node-prefix`` of
``zentrack run``) estimates its offset and keeps the schedule; beyond the tolerance one log line names the clock.

Before the fix, such a tracker refused every measurement as ``stale`` or ``future`` and never published again.
Every figure compared is a ratio against a clean run measured in the same test, or against the clean trackers of
the same run."""
from __future__ import annotations

import shutil
import time

import numpy as np
import pytest

from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import ok_line, run_failures
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.truth.simulation.simulate import simulate

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("faketime") is None, reason="needs faketime (Debian's faketime)")]

NODES, STEPS = 6, 200
#: node 1 ahead, node 4 behind: on exp2's ring their neighbourhoods (0, 2 and 3, 5) do not overlap
SKEWS = {1: 0.3, 4: -0.3}


def setup(steps: int = STEPS) -> RunSetup:
    scn = simulate(builtin_spec("exp2", nodes=NODES, steps=steps), runs=1, seed=8)
    return RunSetup.from_data(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")


def faketime(skew: float) -> list[str]:
    """The prefix of a node whose wall clock is ``skew`` s off (docs/networks.md, "Clocks"): its monotonic clock
    left alone, as on a real host, and libfaketime's monotonic fix off. Without the first, a timed wait under
    libfaketime 0.9.10 never returns; without the second, every handover of Python's GIL between Zenoh's
    threads and the node's takes about a millisecond and the node falls behind. (``Cluster`` now sets both for
    any prefixed node, ``PREFIX_ENV``; the restart test below relies on that with ``faketime`` as such.)"""
    return ["env", "FAKETIME_DONT_FAKE_MONOTONIC=1", "FAKETIME_FORCE_MONOTONIC_FIX=0", "faketime", "-f", f"{skew:+g}s"]


def run_cluster(out, steps: int = STEPS, skews: dict[int, float] | None = None) -> tuple[dict, np.ndarray]:
    """One run to its end: the summary and, per step and node, whether an estimate updated from a measurement
    came (published, not coasted)."""
    prefix = {i: faketime(s) for i, s in (skews or {}).items()}
    with Cluster(setup(steps), out, node_prefix=prefix) as cluster:
        cluster.start()
        cluster.wait(timeout=steps * 0.1 * 3 + 60)
        cluster.stop()
        summary = cluster.write_results()
        have = np.isfinite(cluster.recorder.part.mean).all(axis=-1)
        measured = have & ~cluster.recorder.flags["coasted"]
    return summary, measured


def rmse(summary: dict, i: int) -> float:
    node = summary["nodes"][i]
    return node[next(k for k in node if k.startswith("rmse_"))]


def test_a_tracker_whose_clock_is_off_by_300_ms_keeps_the_schedule_and_its_neighbours_error(tmp_path):
    clean, _ = run_cluster(tmp_path / "clean")
    skewed, measured = run_cluster(tmp_path / "skewed", skews=SKEWS)
    for i, skew in SKEWS.items():
        frac = measured[:, i].mean()
        assert frac >= 0.95, f"node {i} ({skew:+} s) updated from a measurement on {frac:.0%} of steps: {skewed['nodes'][i]}"
        offset = skewed["nodes"][i]["clock_offset_s"]
        assert offset == pytest.approx(skew, abs=0.005), offset  # the whole estimate (before issue 52: 10 ms less)
        log = (tmp_path / "skewed" / "logs" / f"node-{i}.log").read_text()
        assert f"node {i}: clock offset established" in log
    others = [i for i in range(NODES) if i not in SKEWS]
    assert all(skewed["nodes"][i]["clock_offset_s"] == 0.0 for i in others), [n["clock_offset_s"] for n in skewed["nodes"]]
    ratios = [rmse(skewed, i) / rmse(clean, i) for i in others]
    # (each of them neighbours a skewed tracker; before the fix, the skewed ones only coasted: 1.08 each)
    assert np.median(ratios) <= 1.05 and max(ratios) <= 1.15, (ratios, [rmse(clean, i) for i in others])
    for i in SKEWS:  # the skewed trackers themselves track as well as in the clean run
        assert rmse(skewed, i) <= 1.5 * rmse(clean, i), (i, rmse(skewed, i), rmse(clean, i))


def test_beyond_the_tolerance_one_log_line_names_the_clock(tmp_path):
    skewed, _ = run_cluster(tmp_path / "run", steps=60, skews={2: 0.8})
    log = (tmp_path / "run" / "logs" / "node-2.log").read_text()
    lines = [line for line in log.splitlines() if "exceeds ±0.5 s" in line]
    assert len(lines) == 1 and "node 2: clock offset +0.8 s against the run's schedule exceeds ±0.5 s" in lines[0], log[-3000:]
    assert skewed["nodes"][2]["clock_exceeded"] and skewed["nodes"][2]["clock_offset_s"] == 0.5


#: restart test: steps, the step the skewed tracker is killed after, and the deadline misses its restart may add to
#: the worst clean tracker's. Measured (4 runs of 400 steps, node 1 at +0.3 s killed at step 100 and restarted 0-5
#: steps later): 0 misses counted by the restarted tracker and by every clean one, with the fix; 393 and 397
#: (a fusion overrun at nearly every step, both incarnations) with `faketime -f +0.3s` before it. A fresh process's
#: first steps (imports, first calls) can make an estimate or a round late on a loaded host: 3 of those are allowed.
RESTART_STEPS, KILL_AFTER, RESTART_MISSES = 250, 60, 3
#: steps from the restart command to the restarted tracker's first estimate: a Python process started under
#: faketime, its session and its warm start. Measured 2 alone and 3 beside a busy loop; in whole suites the outage
#: from the kill reached 36 and 41 steps (runs 44 and stop 62's CI of docs/testing.md), at least 5 of them before
#: the restart command: up to 31 (36 - 5) from it. Not a bound on recovery (the soaks judge that): that it came back.
START_STEPS = 40


def wait_until(cluster: Cluster, done, timeout: float, what: str) -> None:
    """Record until ``done()``; TimeoutError naming ``what`` after ``timeout`` s."""
    end = time.time() + timeout
    while time.time() < end:
        cluster.recorder.drain(0.1)
        if done():
            return
    raise TimeoutError(f"{what}: not within {timeout:.0f} s")


def test_a_skewed_tracker_restarted_mid_run_counts_only_the_deadlines_it_missed(tmp_path):
    """Issue 52, item 6: a tracker killed and restarted under ``faketime -f +0.3s`` warm-starts, estimates its offset
    and tracks, but counted a deadline miss at nearly every step (344 of 395) while the run printed "run OK".
    Two causes: under libfaketime's defaults its timed waits never returned, so it woke only when a message came
    (``Cluster`` now keeps a prefixed tracker's monotonic clock real); and its corrected clock ran the dead band
    (10 ms) ahead of the run's, every deadline test 10 ms early (``node/clock_offset.py`` now applies the whole
    estimate)."""
    victim, skew = 1, 0.3
    out = tmp_path / "run"
    with Cluster(setup(RESTART_STEPS), out, node_prefix={victim: ["faketime", "-f", f"{skew:+g}s"]}) as cluster:
        cluster.start()
        def have(k: int, nodes) -> bool:
            return bool(np.isfinite(cluster.recorder.part.mean[k, nodes]).all())

        wait_until(cluster, lambda: have(KILL_AFTER, victim), 120, f"node {victim}'s step {KILL_AFTER}")
        cluster.kill(victim)
        others = [i for i in range(NODES) if i != victim]  # a restart, not a pause: the others go on without it
        killed = time.time()
        wait_until(cluster, lambda: have(KILL_AFTER + 5, others), 30, f"step {KILL_AFTER + 5}")
        down_steps = (time.time() - killed) / 0.1  # (the run's period)
        cluster.restart(victim)
        cluster.wait(timeout=RESTART_STEPS * 0.1 * 3 + 60)
        cluster.stop()
        summary = cluster.write_results()
    node, clean = summary["nodes"][victim], [summary["nodes"][i] for i in others]
    assert node["restarts_seen"] == 1 and node["warm_starts"] >= 1 and node["cold_restarts"] == 0, node
    # the deadlines it counts: the clean trackers' worst, and a few for the restart itself
    worst_clean = max(n["reported_misses"] for n in clean)
    assert node["reported_misses"] <= worst_clean + RESTART_MISSES, (node["reported_misses"], worst_clean,
                                                                      [m for m in summary["miss_notes"] if m["node"] == victim][:10])
    # the summary is honest: its misses are the steps it was dead for, which the closing line names
    gap = node["steps_without_estimate"]
    print(f"restart: dead {gap} steps, {down_steps:.1f} of them before the restart command")
    assert 5 <= gap <= down_steps + START_STEPS and node["outages"], (gap, down_steps, node["gaps"], node["outages"])
    assert gap <= node["deadline_misses"] <= gap + RESTART_MISSES, (node["deadline_misses"], gap)
    assert run_failures(summary, 0.1) == []
    line = ok_line(summary, out)
    assert f"node {victim} sent no estimate through" in line and "came back" in line, line
    # its offset is the whole estimate, established anew by each incarnation (before: +0.290, the dead band less)
    log = (out / "logs" / f"node-{victim}.log").read_text()
    assert log.count(f"node {victim}: clock offset established +0.30") == 2, log[-3000:]
    assert node["clock_offset_s"] == pytest.approx(skew, abs=0.005), node["clock_offset_s"]
    # it tracks as the clean trackers do (measured: 1.04x their median)
    assert rmse(summary, victim) <= 1.5 * np.median([rmse(summary, i) for i in others]), \
        (rmse(summary, victim), [rmse(summary, i) for i in others])
    # its clock is the run's: its estimates' latency (stamped on that clock) is the clean trackers' (before: +10 ms)
    clean_p50 = float(np.median([n["latency_ms"]["p50"] for n in clean]))
    assert node["latency_ms"]["p50"] <= clean_p50 + 3.0, (node["latency_ms"], clean_p50)
