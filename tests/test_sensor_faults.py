"""Faults of a run with sensors of their own (``exp2-async``: six ``zentrack sensor`` processes at 10, 4 and 1 Hz, six
trackers 350 ms behind the run), live through :class:`Cluster`, each judged by what its users meet:

- **the truth stalls, then dies for good**: the trackers need no measurement of the truth's, so
  they track on their sensors' detections throughout, keep their links (no re-opened session) and stop by
  themselves at the run's end; the cluster records them to it and reports the truth's failure;
- **the router stalls, then is killed and restarted**: sensors and trackers reconnect and every tracker tracks again
  within a few steps; each detection published meanwhile is either kept, too old or missing (counted), and none
  moves a sensor's clock estimate (a late one fused at a wrong time);
- **a sensor's link delays and drops** (``tests/impaired_sensor.py``, for 5 s: 30 % lost, the rest 250-750 ms late,
  beyond the 350 ms lag): its tracker counts the late ones too old and the lost ones missing, tracks on its
  neighbours' estimates meanwhile and takes its sensor's detections again as soon as they come in time.

Each fault is timed by the recorder's view of the run (the last step any tracker has published) and every wait
polls a condition under a timeout; every cluster is stopped in a ``with`` block.

Measured (three runs of this module, one beside a busy loop, host load 12 to 22; 76-77 s of tests): the truth's
faults: no session re-opened, every detection came (kept 93-100 %, none missing), RMSE 6.50-7.51 m per tracker,
0-3 single steps without an estimate per tracker. The router's: every tracker published again 0-2 steps after the
stall and 2-7 after the router served again, took its sensor's detections again 2-19 steps after (19: a 1 Hz
sensor's tracker), its largest error over the next 10 steps 6.3-13.6 m; kept + too old + missing = published for
every tracker (10 Hz: 32-63 missing, 0-29 too old). The link's (seeded, the same each run): 16 of 49 lost, counted
missing; 27 too old (25-26 surely late, none in time); tracker 0's RMSE 7.4-7.8 m in the impaired stretch against
7.3 m before and 7.9-8.1 m after, up to 3 steps of 55 without an estimate (warm starts), a detection kept again at once.
See docs/sensors.md ("Faults").
"""
from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_stalls import latest_step, record_until_step, wait_until_listening

from zentrack.cli import build_parser
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import RunSetup, resolve_setup

pytestmark = pytest.mark.slow

NODES = 6
RATES = [10.0, 4.0, 1.0, 10.0, 4.0, 1.0]  # exp2-async's sensors (Hz); tracker i takes sensor i
OFFSETS = [0.12, -0.08, 0.2, -0.15, 0.05, -0.2]  # their clocks against the trackers' (s)
LAG_S, TS = 0.35, 0.1
IMPAIRED = Path(__file__).resolve().parent / "impaired_sensor.py"


def setup(steps: int) -> RunSetup:
    argv = ["run", "--scenario", "exp2-async", "--steps", str(steps), "--out", "unused"]
    return resolve_setup(build_parser(argv).parse_args(argv))


def published(out: Path, sensor: int) -> int:
    """How many detections sensor ``sensor`` put on the wire (its log's last line, over its incarnations)."""
    log = (out / "logs" / f"sensor-{sensor}.log").read_text()
    return sum(int(n) for n in re.findall(r"done, (\d+) detection\(s\) published", log))


def figures(out: Path, summary: dict, reports: dict[int, dict]) -> list[str]:
    return [f"node {i} ({RATES[i]:g} Hz): RMSE {n['rmse_p']:.2f} m, gaps {n['gaps']}, reconnects {n['reconnects']}, "
            f"sensor published {published(out, i)}, detections {reports.get(i, {}).get('detections')}, "
            f"offset {n.get('sensor_offsets_s')}" for i, n in enumerate(summary["nodes"])]


# ---------------------------------------------------------------- (1) the truth stalls, then dies
TRUTH_STEPS, STALL_AT, STALL_S, KILL_AT = 150, 20, 3.0, 60


def test_trackers_of_sensors_of_their_own_track_through_the_truths_stall_and_death(tmp_path):
    out = tmp_path / "run"
    with Cluster(setup(TRUTH_STEPS), out) as cluster:
        cluster.start()
        record_until_step(cluster, STALL_AT, timeout=90)
        stalled = latest_step(cluster)
        cluster.signal_process("truth", signal.SIGSTOP)
        cluster.pump(STALL_S)
        cluster.signal_process("truth", signal.SIGCONT)
        record_until_step(cluster, KILL_AT, timeout=60)
        gone = latest_step(cluster)
        cluster.signal_process("truth", signal.SIGKILL)  # for good: no stop will come
        code = cluster.wait(timeout=TRUTH_STEPS * TS * 3 + 60)
        nodes = {i: cluster.procs[f"node-{i}"].poll() for i in range(NODES)}
        reports = cluster.node_reports()
        cluster.stop()
        summary = cluster.write_results()
    lines = figures(out, summary, reports)
    print("\n".join([f"truth stalled at step {stalled}, killed at {gone}; wait returned {code}", *lines]))
    assert code == -signal.SIGKILL, "the run reports the truth's failure (zentrack run exits non-zero)"
    truth_log = (out / "logs" / "truth.log").read_text()
    assert "skipping missed steps" in truth_log, truth_log[-2000:]  # it stalled
    # every tracker left by itself at the run's end, having tracked to it (recorded to it: nothing not judged)
    assert nodes == dict.fromkeys(range(NODES), 0), nodes
    for i in range(NODES):
        assert "the run is over and the truth is gone" in (out / "logs" / f"node-{i}.log").read_text()
    assert summary["network"]["steps"] == TRUTH_STEPS and run_failures(summary, 0.05) == [], run_failures(summary, 0.05)
    have = cluster.recorder.have()
    for i, n in enumerate(summary["nodes"]):
        assert n["reconnects"] == 0, lines[i]  # its links were never re-opened: the truth is not needed to track
        assert have[stalled:, i].mean() >= 0.95, lines[i]  # estimates through every fault of the truth
        assert all(b - a < 3 for a, b in n["gaps"]), lines[i]
        det = reports[i]["detections"]
        # its sensor's detections, all along: every one came (none missing), kept but for the few too old (a
        # reordered tenth comes a period late, and more on a loaded host)
        assert det["det_rx"] + det["too_old"] == published(out, i) and det["missing"] == 0, lines[i]
        assert det["det_rx"] >= 0.75 * published(out, i), lines[i]
        assert n["rmse_p"] <= RMSE_LIMIT_M, lines[i]


#: a tracker's RMSE over the run with the truth's faults (m): measured 6.50-7.51 (test_sensors_live's fault-free
#: 150-step runs: 6.8-7.3); test_sensors_live's limit against the synchronous run is 1.6 times, 12 m here
RMSE_LIMIT_M = 12.0


def accounted(out: Path, reports: dict[int, dict], i: int) -> tuple[int, int]:
    """Tracker ``i``'s sensor's detections: how many it published, and how many the tracker accounts for (kept, too
    old or missing)."""
    det = reports[i]["detections"]
    return published(out, i), det["det_rx"] + det["too_old"] + det["missing"]


def offset_ok(summary: dict, i: int, below_s: float = 0.05) -> bool:
    """Whether tracker ``i``'s estimate of its sensor's clock offset is where the stream puts it, not moved by
    detections that came late (each is only a larger sample; had the estimate followed them, every detection
    after would be fused that much later than it was measured): below the configured offset by the quantile bias
    of the least latency (14 to 35 ms, tests/test_sensors_live.py; measured here 14 to 24 ms for the 10 Hz
    sensors), by at most ``below_s``: a tenth of the delays of the fault."""
    return OFFSETS[i] - below_s <= summary["nodes"][i]["sensor_offsets_s"][str(i)] <= OFFSETS[i] + 0.001


# ---------------------------------------------------------------- (2) the router stalls, then restarts
ROUTER_STEPS, ROUTER_STALL_AT, ROUTER_STALL_S, ROUTER_KILL_AT, ROUTER_DOWN_S = 150, 20, 3.0, 80, 2.0
#: steps from the router's return until every tracker publishes again: measured 0-8 (module docstring); the
#: synchronous runs' limit (tests/test_stalls.py, RECOVERY_STEPS), which a loaded suite came near (22 once)
BACK_STEPS = 20


def test_after_the_routers_stall_and_restart_every_tracker_tracks_again_and_counts_what_it_lost(tmp_path):
    out = tmp_path / "run"
    ends = []
    with Cluster(setup(ROUTER_STEPS), out, router=True) as cluster:
        cluster.start()
        record_until_step(cluster, ROUTER_STALL_AT, timeout=90)
        step, t_stop = latest_step(cluster), time.time()
        cluster.signal_process("router", signal.SIGSTOP)
        cluster.pump(ROUTER_STALL_S)  # the recorder is a client of the router too: it hears nothing meanwhile
        cluster.signal_process("router", signal.SIGCONT)
        ends.append((step, step + round((time.time() - t_stop) / TS)))
        record_until_step(cluster, ROUTER_KILL_AT, timeout=60)
        step, t_kill = latest_step(cluster), time.time()
        cluster.signal_process("router", signal.SIGKILL)
        cluster.pump(ROUTER_DOWN_S)
        cluster.restart_process("router")
        serving = wait_until_listening(cluster, timeout=30.0)  # its own start-up is not the trackers' recovery
        ends.append((step, step + round((serving - t_kill) / TS)))
        assert cluster.wait(timeout=ROUTER_STEPS * TS * 3 + 60) == 0
        reports = cluster.node_reports()
        cluster.stop()
        summary = cluster.write_results()
    lines = figures(out, summary, reports)
    have, coasted = cluster.recorder.have(), cluster.recorder.flags["coasted"]
    err = cluster.recorder.step_errors()
    waits = {}
    for i in range(NODES):
        for _, end in ends:
            back = next((k for k in range(end, ROUTER_STEPS) if have[k, i]), ROUTER_STEPS)
            measured = next((k for k in range(end, ROUTER_STEPS) if have[k, i] and not coasted[k, i]), ROUTER_STEPS)
            waits.setdefault(i, []).append((back - end, measured - end))
    print("\n".join([f"router stalled at steps {ends[0]}, down at {ends[1]}; steps until each tracker published, "
                     f"updated from a detection again: {waits}", *lines,
                     "largest error once back (m): " + ", ".join(f"{np.nanmax(err[e + BACK_STEPS:e + BACK_STEPS + 10], axis=0).round(1)}"
                                                                 for _, e in ends)]))
    for i in range(NODES):
        for (published_again, measured_again), (_, end) in zip(waits[i], ends):
            assert published_again <= BACK_STEPS, lines[i]
            # updated from its sensor's detections again: the next one after the reconnection, a lag later (a 1 Hz
            # sensor's tracker waits up to 10 steps for it)
            assert measured_again <= BACK_STEPS + (1 / RATES[i] + LAG_S) / TS, lines[i]
            # tracking again: within its usual error once its estimate has taken a few detections (the next 10 steps)
            assert np.nanmax(err[end + BACK_STEPS:end + BACK_STEPS + 10, i]) <= RECOVERED_M, lines[i]
        sent, counted = accounted(out, reports, i)
        # what was published while the router was gone: lost (missing) or late (too old), and counted
        assert counted == sent, lines[i]
        # lost while the router was down, late from its stall: with the 0.1 s re-dial a 4 Hz sensor's stall came
        # late (13 too old) and only its 2 s down were lost (8 missing; run 44 of docs/testing.md)
        held = reports[i]["detections"]["missing"] + reports[i]["detections"]["too_old"]
        assert held >= 0.5 * RATES[i] * (ROUTER_STALL_S + ROUTER_DOWN_S) - 1, lines[i]
        # held 2-3 s by the router: a tenth of that is 0.2 s; within 0.1 s (once 51 ms below in a whole suite, run 42
        # of docs/testing.md: the last 6.4 s of samples, after the restart, on a loaded host). A slower sensor's
        # few samples: its bias varies
        assert offset_ok(summary, i, below_s=0.1) or RATES[i] < 10, lines[i]
    assert run_failures(summary, 0.1) == [], run_failures(summary, 0.1)


#: the largest error of a tracker over the 10 steps after BACK_STEPS (m): measured 6.3-13.6; a tracker that does not
#: take its detections again is 128-237 m off then (a broken build that drops them once stale), and a coasted estimate
#: right after the outage up to 200 m (inside its covariance)
RECOVERED_M = 40.0


# ---------------------------------------------------------------- (3) a sensor's link delays and drops
LINK_STEPS, IMPAIRED_FROM_S, IMPAIRED_TO_S, DELAY_MS, JITTER_MS, DROP = 150, 5.0, 10.0, 500.0, 250.0, 0.3


def test_a_sensors_delayed_and_lossy_link_is_counted_too_old_and_missing_and_its_tracker_recovers(tmp_path):
    out, report = tmp_path / "run", tmp_path / "impaired.json"
    # sensor 0 is the impaired process below (the truth waits for its token as for any sensor's)
    (out / "logs").mkdir(parents=True)
    with Cluster(setup(LINK_STEPS), out, external_sensors={0}, truth_args=["--wait-for", "sensor-0"]) as cluster, \
            open(out / "logs" / "sensor-0.log", "ab") as log:
        sensor = subprocess.Popen([sys.executable, str(IMPAIRED), str(report), str(IMPAIRED_FROM_S),
                                   str(IMPAIRED_TO_S), str(DELAY_MS), str(JITTER_MS), str(DROP), "7", "--", "sensor",
                                   "--id", "0", *cluster.sensors.run_args()],
                                  stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        try:
            cluster.start()
            assert cluster.wait(timeout=LINK_STEPS * TS * 3 + 60) == 0
            assert sensor.wait(timeout=30) == 0, (out / "logs" / "sensor-0.log").read_text()[-2000:]
            reports = cluster.node_reports()
            cluster.stop()
            summary = cluster.write_results()
        finally:
            if sensor.poll() is None:
                sensor.kill()
                sensor.wait()
    sent = json.loads(report.read_text())["detections"]
    impaired = [d for d in sent if d["impaired"]]
    lost = [d for d in impaired if d["left"] is None]
    # a detection is too old once it comes after its window [t_(k-1), t_k) was taken, at t_k + lag: surely when
    # it left more than the lag and a period after it was measured, never when it left within the lag (give or take
    # the estimate of the sensor's clock and the transport, 50 ms)
    late = [d for d in impaired if d["left"] is not None and d["left"] - d["t"] > LAG_S + TS + 0.05]
    timely = [d for d in impaired if d["left"] is not None and d["left"] - d["t"] < LAG_S - 0.05]
    det = reports[0]["detections"]
    err = cluster.recorder.step_errors()
    have, coasted = cluster.recorder.have(), cluster.recorder.flags["coasted"]
    a, b = round(IMPAIRED_FROM_S / TS), round(IMPAIRED_TO_S / TS)
    rmse = {name: np.sqrt(np.nanmean(err[s, :] ** 2, axis=0)).round(2)
            for name, s in (("before", slice(10, a)), ("impaired", slice(a + 5, b + 5)), ("after", slice(b + 10, None)))}
    first_kept = next((k for k in range(b, LINK_STEPS) if have[k, 0] and not coasted[k, 0]), LINK_STEPS)
    lines = figures(out, summary, reports)
    print("\n".join([f"sensor 0: {len(sent)} published, {len(impaired)} in the impaired {IMPAIRED_TO_S - IMPAIRED_FROM_S:g} s: "
                     f"{len(lost)} lost, {len(late)} surely too old, {len(timely)} in time; tracker 0 {det}; "
                     f"its first detection kept {first_kept - b} steps after; RMSE per tracker {rmse}", *lines]))
    assert len(sent) == published(out, 0) and len(lost) >= 5 and len(late) >= 10, "the impairment happened"
    assert det["missing"] == len(lost), lines[0]  # each lost one counted missing, no more
    assert len(late) <= det["too_old"] <= len(impaired) - len(lost) - len(timely) + 2, lines[0]
    assert det["det_rx"] + det["too_old"] + det["missing"] == len(sent), lines[0]
    assert offset_ok(summary, 0), lines[0]  # the late ones did not move its clock estimate
    # degraded gracefully: an estimate at nearly every step (its neighbours' fused; each lone detection in time
    # after 6 steps without one warm-starts it, a step without an estimate), its error not far above the usual
    assert have[a:b + 5, 0].mean() >= 0.9 and rmse["impaired"][0] <= 2 * max(rmse["before"][0], 5.0), lines[0]
    # and recovered: its sensor's detections taken again as soon as they come in time, its error back
    assert first_kept - b <= 1 + (LAG_S + TS) / TS, lines[0]
    assert rmse["after"][0] <= 1.5 * max(rmse["before"][0], 5.0), lines[0]
    assert run_failures(summary, 0.05) == [], run_failures(summary, 0.05)

