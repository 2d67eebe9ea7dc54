"""Sensors of their own, live (issue 52): ``exp2-async`` shortened to 150 steps through :class:`Cluster`: six
``zentrack sensor`` processes at 10, 4 and 1 Hz with 10-300 ms latencies, a tenth of their detections out of
order and clocks up to 200 ms off, six trackers that take them 350 ms behind the run. Every figure is compared with
what it should be: the RMSE of each tracker against the synchronous run of the same geometry (the same file
without ``[sensor_timing]``: the truth measures every sensor every step) measured in the same test; the clock
offset each tracker estimates against the one its sensor was given, less the bias the estimator has by design
(:class:`~zentrack.node.clock_offset.OffsetEstimator`: a low quantile of ``receive time - stamp``, so the offset
less that quantile of the latency above the least), worked out from the sensor's own simulated stream.

Measured (two runs of this test, 6 trackers, 150 steps; the noise is seeded, so the runs agree to the last digit
shown): RMSE async / sync per tracker 1.31, 1.28, 1.15, 1.15, 1.28, 1.21 (10, 4, 1, 10, 4, 1 Hz). The sensors
make 30 measurements a second where the synchronous run has 60: at the bound, half the information is √2 = 1.41
times the error; fusion with the neighbours keeps every tracker below that, whatever its own sensor's rate.
Estimated offsets: 0.3 to 2.9 ms below the design's, which lies 14 to 35 ms below the configured offsets. Too old:
0 to 2 detections per tracker (4 of 445 received): the reordered ones of the 4 and 1 Hz sensors, a period late.
A sensor restarted mid-run finds the run under way and publishes from the current time on."""
from __future__ import annotations

import re
import time

import numpy as np
import pytest

from zentrack.cli import build_parser
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import RunSetup, resolve_setup
from zentrack.node.detections import CLOCK_QUANTILE, CLOCK_WINDOW
from zentrack.truth.simulation.sensor_stream import sensor_stream

pytestmark = pytest.mark.slow

NODES, STEPS = 6, 150
#: the most a tracker's RMSE may grow against the synchronous run (measured 1.15 to 1.31: half the measurements,
#: √2 at the bound; module docstring)
RMSE_RATIO = 1.6
#: how far below the design's the estimated offset may lie: a detection delivered late (the transport, the sensor's
#: wake-up, a busy host) only ever raises a sample, so only ever lowers the estimate; measured 0.3 to 2.9 ms below
OFFSET_TOL_S = 0.010


def setup(synchronous: bool = False) -> RunSetup:
    argv = ["run", "--scenario", "exp2-async", "--steps", str(STEPS), "--out", "unused"]
    s = resolve_setup(build_parser(argv).parse_args(argv))
    if synchronous:  # the same geometry, run and noise levels, the truth measuring every sensor every step
        s.sensor_timing = None
    return s


def wait_until(timeout: float, condition) -> bool:
    end = time.time() + timeout
    while time.time() < end:
        if condition():
            return True
        time.sleep(0.1)
    return condition()


def run_cluster(out, s: RunSetup) -> tuple[dict, dict[int, dict], dict[str, int | None]]:
    """One run to its end: the summary, each tracker's final report and each sensor process's exit status."""
    with Cluster(s, out) as cluster:
        cluster.start()
        assert cluster.wait(timeout=STEPS * 0.1 * 3 + 60) == 0, "the truth failed"
        sensors = {n: p for n, p in cluster.procs.items() if n.startswith("sensor-")}
        wait_until(15.0, lambda: all(p.poll() is not None for p in sensors.values()))  # each leaves at ctl/stop
        codes = {n: p.poll() for n, p in sensors.items()}
        reports = cluster.node_reports()
        cluster.stop()
        summary = cluster.write_results()
    return summary, reports, codes


def rmse(summary: dict, i: int) -> float:
    return float(summary["nodes"][i]["rmse_p"])


def design_offset(s: RunSetup, sensor: int) -> tuple[float, float]:
    """The offset a tracker estimates for ``sensor`` by design, and that bias: the configured offset less the
    :data:`CLOCK_QUANTILE` quantile (as the estimator takes it) of the last :data:`CLOCK_WINDOW` latencies to
    arrive, above the least latency."""
    spec = s.sensor_streams()[sensor]
    arrived = sorted(sensor_stream(s.scenario, spec, s.seed), key=lambda d: d.t_publish)[-CLOCK_WINDOW:]
    latencies = sorted(d.t_publish - d.t for d in arrived)
    bias = latencies[int(CLOCK_QUANTILE * (len(latencies) - 1))] - spec.latency.low_s
    return spec.offset_s - bias, bias


def test_sensors_of_their_own_track_live_as_close_to_the_synchronous_run_as_their_rates_allow(tmp_path):
    sync, _, _ = run_cluster(tmp_path / "sync", setup(synchronous=True))
    s = setup()
    summary, reports, codes = run_cluster(tmp_path / "async", s)
    assert run_failures(summary, 0.1) == [] and run_failures(sync, 0.1) == [], (run_failures(summary, 0.1),
                                                                                run_failures(sync, 0.1))
    assert codes == {f"sensor-{i}": 0 for i in range(NODES)}, codes  # each sensor left 0 at the run's stop
    for i in range(NODES):
        assert (tmp_path / "async" / "logs" / f"sensor-{i}.log").exists()
    lines = []
    for i in range(NODES):
        report = reports[i]
        det = report["detections"]
        ratio = rmse(summary, i) / rmse(sync, i)
        expected, bias = design_offset(s, i)
        offset = report["sensor_offsets_s"][str(i)]
        lines.append(f"node {i}: {s.sensor_streams()[i].rate_hz:g} Hz, RMSE {rmse(summary, i):.2f} / sync "
                     f"{rmse(sync, i):.2f} = {ratio:.2f}; det_rx {det['det_rx']}, too_old {det['too_old']}, "
                     f"out_of_order {det['out_of_order']}; offset {offset:+.4f} s, configured "
                     f"{s.sensor_streams()[i].offset_s:+.3f}, by design {expected:+.4f} (bias {bias * 1e3:.1f} ms)")
        assert report["meas_rx"] == 0, report  # the truth sent this tracker no measurement of its own
        # (a 1 Hz sensor sends 15 in 15 s; the reordered tenth of them comes a period late, after the lag)
        assert det["det_rx"] >= 0.8 * STEPS * 0.1 * s.sensor_streams()[i].rate_hz, lines[-1]
        assert det["too_old"] <= max(2, 0.15 * det["det_rx"]), lines[-1]
        assert expected - OFFSET_TOL_S <= offset <= expected + 0.001, lines[-1]
        assert abs(offset - s.sensor_streams()[i].offset_s) <= bias + OFFSET_TOL_S, lines[-1]
        assert ratio <= RMSE_RATIO, lines[-1]
    print("\n".join(lines))
    assert [n["sensor_offsets_s"] for n in summary["nodes"]] == [reports[i]["sensor_offsets_s"] for i in range(NODES)]
    assert [n["detections"] for n in summary["nodes"]] == [reports[i]["detections"] for i in range(NODES)]
    total = {k: sum(reports[i]["detections"][k] for i in range(NODES)) for k in ("det_rx", "too_old")}
    assert total["too_old"] <= 0.1 * total["det_rx"], total
    assert np.median([rmse(summary, i) / rmse(sync, i) for i in range(NODES)]) <= 1.5


def test_a_sensor_restarted_mid_run_resumes_at_the_current_time(tmp_path):
    # 12 s: on a loaded host the restarted sensor's process came up 6.5 s after the restart command, after the end
    # of a 6 s run (run 45 of docs/testing.md), and waited for a start that never came
    steps = 120
    argv = ["run", "--scenario", "exp2-async", "--steps", str(steps), "--out", "unused"]
    s = resolve_setup(build_parser(argv).parse_args(argv))
    with Cluster(s, tmp_path / "run") as cluster:
        cluster.start()
        assert wait_until(60.0, lambda: cluster.pump(0.1) or cluster.recorder.steps_reached() >= 15)
        cluster.restart("sensor-3")  # killed (SIGKILL) and started again while the run goes on
        assert cluster.wait(timeout=steps * 0.1 * 3 + 60) == 0
        proc = cluster.procs["sensor-3"]
        assert wait_until(15.0, lambda: proc.poll() is not None) and proc.returncode == 0
        reports = cluster.node_reports()
        cluster.stop()
        summary = cluster.write_results()
    log = (tmp_path / "run" / "logs" / "sensor-3.log").read_text()
    skipped = [int(m.group(1)) for m in re.finditer(r"joined the run under way; (\d+) detection", log)]
    assert len(skipped) == 1 and skipped[0] >= 10, log[-2000:]  # (restarted after step 15: 1.85 s into the run)
    det = reports[3]["detections"]
    # 10 Hz for the run: one detection a step; the new incarnation publishes every one from the current time on, the
    # old one published some of those past, and the ones due while no sensor ran (its start-up) are lost
    assert steps - skipped[0] - 2 <= det["det_rx"] <= steps - 1 and det["too_old"] <= 2, (det, skipped)
    assert reports[3]["meas_rx"] == 0 and run_failures(summary, 0.25) == [], run_failures(summary, 0.25)
