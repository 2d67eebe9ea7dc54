"""Clock skew, end to end (realtime exp2, 6 trackers over Zenoh): a tracker whose host clock is 0.3 s ahead or
behind the run's schedule (``faketime``, through ``Cluster(node_prefix=...)``, the ``--node-prefix`` of
``zentrack run``) estimates its offset and keeps the schedule; beyond the tolerance one log line names the clock.

Before the fix, such a tracker refused every measurement as ``stale`` or ``future`` and never published again.
Every figure compared is a ratio against a clean run measured in the same test."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from zentrack.cluster.run.cluster import Cluster
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.node.clock_offset import DEAD_BAND_S
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
    threads and the node's takes about a millisecond and the node falls behind."""
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
        assert offset == pytest.approx(skew - np.sign(skew) * DEAD_BAND_S, abs=0.03), offset
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
