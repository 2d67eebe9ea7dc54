"""Many targets with sensors of their own, live (issue 52): ``mt-async`` shortened to 30 steps (the four targets
meet at 25 s) through :class:`Cluster`: eight ``zentrack sensor`` processes at 4, 2 and 1 Hz with 10-300 ms
latencies, a tenth of their scans a period later still and clocks up to 200 ms off, each applying P_D, its noise and
Poisson clutter to the targets in view at its own times; eight many-target trackers that take them 350 ms behind
the run, each scan at its own time, and fuse their track lists every second.

Tracker 1's host clock runs 0.3 s ahead (``faketime -f +0.3s``): it makes its windows and lists on its own clock,
its neighbours 0 and 2 estimate its offset from its lists' publication times and take its list of step k as theirs
of step k predicted over the offset, it theirs predicted back (``node/track_lists/admission.py``); the recorder
judges its lists at their time of validity.

Every figure is compared with what it should be. The reference of each tracker's GOSPA (and of its localisation
part) is the synchronous network of the same file without ``[sensor_timing]`` (the truth scanning every sensor every
second), computed here in process: a lockstep run of it equals that exactly (``tests/test_multitarget_live.py``),
and live realtime runs of the full minute gave the same figures to the last digit shown (docs/sensors.md).

Measured (four runs of this test, one beside a busy loop, on a host shared with a CI run at load average 15-21;
the noise is seeded, so the runs agree within the timing: what comes too old): GOSPA async / sync per tracker
0.83-1.02 (the 1 Hz and 2 Hz trackers nearest 1: as many scans as a synchronous tracker, later), localisation part
0.41-0.80 of the synchronous one (20 scans a second over the network where it has 8); every scan its sensor
measured to the last window kept or counted too old, too old 0-8 (the reordered tenth of the 2 and 1 Hz sensors: a
period late is beyond the 350 ms lag); no deadline missed. 41-53 s of run, 51-71 s in all."""
from __future__ import annotations

import shutil
import time

import numpy as np
import pytest

from zentrack.cli import build_parser
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import RunSetup, resolve_setup
from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.fusion.multitarget.metrics import summarize_run
from zentrack.study.multitarget_runs import node_settings, run_distributed
from zentrack.truth.simulation.sensor_stream import multitarget_truth_at

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("faketime") is None, reason="needs faketime (Debian's faketime)")]

NODES, STEPS = 8, 30
#: tracker 1's host clock is this far ahead (s); its neighbours on the ring
SKEWED, SKEW, NEIGHBOURS = 1, 0.3, (0, 2)
#: the most the position error of tracker 1 may be against the median of the trackers that do not neighbour it
#: (3-7), each judged at its lists' time of validity over steps 10-29 (:func:`position_rms`): measured 1.00; with
#: its neighbours' lists fused as if on one clock (as before), 1.18
SKEWED_RATIO = 1.1
#: the steps :func:`position_rms` judges (from the first confirmed tracks' tenth step)
SETTLED = 10
#: how far below the true offset an estimate may lie: the low quantile (a fifth) of the delays of the lists it saw,
#: one a second, so the least of about six in this run; measured 0.4-2.0 ms below idle, up to 4.0 ms for a skewed
#: pair and 8.9 ms for a synchronised one beside a busy loop (beyond the 10 ms dead band once, it is applied down
#: to 5 ms: ``node/clock_offset.py``)
OFFSET_BELOW_S = 0.015
#: the most a tracker's GOSPA may be against the synchronous network's (measured 0.83-1.02, module docstring: the
#: runs vary only in what comes too old; a tracker that took its scans at the window's end measured 1.53)
RATIO = 1.15
#: the most a tracker's localisation part may be against the synchronous network's (measured 0.41-0.80; with half
#: its sensor's scans lost, 1.16; scans taken at the window's end, 3.15)
LOC_RATIO = 1.0
#: deadline misses allowed over the network (measured 0; a step 0.55 s slower every fifth step: 48)
MISSES = 2


def setup() -> RunSetup:
    argv = ["run", "--scenario", "mt-async", "--steps", str(STEPS), "--out", "unused"]
    return resolve_setup(build_parser(argv).parse_args(argv))


def wait_until(timeout: float, condition) -> bool:
    end = time.time() + timeout
    while time.time() < end:
        if condition():
            return True
        time.sleep(0.1)
    return condition()


def synchronous_gospa() -> tuple[list[float], list[float]]:
    """Each tracker's GOSPA and its localisation part in the synchronous network of the same file (the in-process
    network)."""
    cfg = resize(load_scenario_config("mt-async", multitarget=True), None, STEPS)
    data = cfg.multitarget_data()
    views = run_distributed(data, node_settings(cfg), cfg).views
    truth = [([int(i) for i in data.truth_at(k)[0]], data.truth_at(k)[1][:, :3]) for k in range(STEPS)]
    runs = [summarize_run(view, truth, data.gospa_cutoff) for view in views]
    return [r.gospa for r in runs], [r.localisation for r in runs]


def position_rms(out, seen: dict[int, float]) -> dict[int, float]:
    """Each tracker's RMS distance (m) of its confirmed tracks from the nearest target within 20 m, over steps
    :data:`SETTLED` on, each list judged at its time of validity on the truth's clock (``k ts`` less the tracker's
    clock offset ``seen``, as the recorder estimated it)."""
    rec, data = np.load(out / "tracks.npz"), setup().multitarget_data
    errors: dict[int, list[float]] = {i: [] for i in range(NODES)}
    for i in range(NODES):
        for k in range(SETTLED, STEPS):
            states, present = multitarget_truth_at(data, np.array([k * data.ts - seen[i]]))
            truth = states[0, present[0], :3]
            mine = (rec["step"] == k) & (rec["node"] == i) & rec["confirmed"]
            for p in rec["state"][mine, :3]:
                d = float(np.linalg.norm(truth - p, axis=1).min())
                errors[i] += [d * d] if d < 20.0 else []
    return {i: float(np.sqrt(np.mean(e))) for i, e in errors.items()}


def test_many_target_trackers_of_sensors_of_their_own_track_as_well_as_the_synchronous_network(tmp_path):
    s = setup()
    streams = s.sensor_streams()
    with Cluster(s, tmp_path, node_prefix={SKEWED: ["faketime", "-f", f"{SKEW:+g}s"]}) as cluster:
        cluster.start()
        assert cluster.wait(timeout=STEPS * 3 + 60) == 0, "the truth failed"
        sensors = {n: p for n, p in cluster.procs.items() if n.startswith("sensor-")}
        wait_until(15.0, lambda: all(p.poll() is not None for p in sensors.values()))  # each leaves at ctl/stop
        codes = {n: p.poll() for n, p in sensors.items()}
        reports = cluster.node_reports()
        cluster.stop()
        summary = cluster.write_results()
    assert run_failures(summary, 0.1) == [], run_failures(summary, 0.1)
    assert codes == {f"sensor-{i}": 0 for i in range(NODES)}, codes
    sync, sync_loc = synchronous_gospa()
    nodes = {n["node"]: n for n in summary["nodes"]}
    lines = []
    for i in range(NODES):
        n, det = nodes[i], reports[i]["detections"]
        scans = int(np.floor(((STEPS - 1) - streams[i].phase_s) * streams[i].rate_hz)) + 1  # (to its last window)
        lines.append(f"node {i}: {streams[i].rate_hz:g} Hz, GOSPA {n['gospa']:.2f} / sync {sync[i]:.2f} = "
                     f"{n['gospa'] / sync[i]:.2f}, its parts loc {n['localisation']:.1f} (/ sync "
                     f"{n['localisation'] / sync_loc[i]:.2f}), missed {n['missed']:.1f}, false {n['false']:.1f}; "
                     f"det_rx {det['det_rx']} too_old {det['too_old']} of {scans}; update ms p50 "
                     f"{n['update_ms']['p50']:.2f}")
        assert reports[i]["meas_rx"] == 0, reports[i]  # the truth sent this tracker no scan of its own
        assert n["detections"] == det and set(n["sensor_offsets_s"]) == {str(i)}
        assert scans - 3 <= det["det_rx"] + det["too_old"] <= scans, lines[-1]  # (its first ones: before the start)
        assert det["too_old"] <= max(3, 0.2 * scans), lines[-1]  # the reordered tenth, and a few of the start
        assert n["gospa"] <= RATIO * sync[i], lines[-1]
        assert n["localisation"] <= LOC_RATIO * sync_loc[i], lines[-1]
    print("\n".join(lines))
    offsets = f"neighbour offsets {[nodes[i]['neighbour_offsets_s'] for i in range(NODES)]}, seen " \
              f"{[nodes[i]['clock_offset_seen_s'] for i in range(NODES)]}"
    print(offsets)
    for i in NEIGHBOURS:  # its neighbours' estimates of its clock, its of theirs, the recorder's
        assert SKEW - OFFSET_BELOW_S <= nodes[i]["neighbour_offsets_s"][str(SKEWED)] <= SKEW, offsets
        assert -SKEW - OFFSET_BELOW_S <= nodes[SKEWED]["neighbour_offsets_s"][str(i)] <= -SKEW, offsets
    assert SKEW - OFFSET_BELOW_S <= nodes[SKEWED]["clock_offset_seen_s"] <= SKEW, offsets
    assert all(nodes[i]["clock_offset_seen_s"] == 0.0 for i in range(NODES) if i != SKEWED), offsets
    assert all(-OFFSET_BELOW_S <= v <= 0.0 for i in range(NODES) if i not in (SKEWED, *NEIGHBOURS)
               for v in nodes[i]["neighbour_offsets_s"].values()), offsets
    rms = position_rms(tmp_path, {i: nodes[i]["clock_offset_seen_s"] for i in range(NODES)})
    reference = float(np.median([rms[i] for i in range(NODES) if i not in (SKEWED, *NEIGHBOURS)]))
    print(f"position rms {[round(rms[i], 2) for i in range(NODES)]} m, reference {reference:.2f}")
    assert rms[SKEWED] <= SKEWED_RATIO * reference, (rms, reference)
    assert summary["network"]["deadline_misses"] <= MISSES, summary["network"]
    assert np.mean([nodes[i]["gospa"] for i in range(NODES)]) <= np.mean(sync)
