"""Sensors of their own in secure mode, live (issue 52): ``exp2-async`` shortened to 80 steps through
:class:`Cluster` with ``secure``: six ``zentrack sensor`` processes, each a mutual-TLS client of the router as
``sensor-<s>``, six trackers that may read only the sensors they take. Judged against the same run without
secure mode, measured in the same test: every tracker takes its sensor's detections and tracks as well.

Meanwhile an insider holding sensor 0's certificate (a session in this process) puts detections stamped 1000 s
ahead, which a tracker refuses and counts as ``future``, on ``det/1`` (sensor 1's key) and garbage on ``prior/1``
(tracker 1's), then the same detections on its own ``det/0``: the router drops the first two silently, so
tracker 1 and its neighbours count nothing, and the recorder sees only what came on ``det/0``, which tracker 0
refuses as ``future``, one count each (the forger's session and its own key work: the others were dropped by the
router, not lost).

Measured (12 runs of this test, 5 at 80 steps and 7 at 100, 5 of them beside a busy loop, on a host shared with
other test runs): RMSE secure / plain per tracker 0.95 to 1.04; every tracker received every detection its sensor
published (80, 32 and 8 of the 10, 4 and 1 Hz sensors at 80 steps), the too old ones as many as without secure
mode within 3; tracker 0 refused the insider's 5 detections as ``future``, no other tracker refused any.
"""
from __future__ import annotations

import queue
import re
import time

import msgpack
import numpy as np
import pytest
import zenoh

from zentrack.cli import build_parser
from zentrack.cluster.deployment.certs import make_certificates
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import RunSetup, resolve_setup
from zentrack.transport.detection_messages import Detection
from zentrack.transport.secure import Identity
from zentrack.transport.zsession import build_config

pytestmark = pytest.mark.slow

NODES, STEPS = 6, 80
#: forged detections on each key (below the intake's FOLLOW_FORWARD run, so that tracker 0 never follows them)
FORGED = 5
#: the most a tracker's RMSE may grow in secure mode against the same run without it: measured 0.95 to 1.04
#: (module docstring); a host loaded by other runs moves one run's error against another's by up to a fifth
#: (measured: a plain run beside load 15 that missed 63 steps, 1.05 to 1.24 times a secure run's)
RMSE_RATIO = 1.25
#: the least share of its sensor's detections that reaches a tracker (measured: module docstring), and that it
#: keeps (the rest older than the lag: a tenth of each sensor's scans is held a period, beyond the 1 Hz sensors' lag)
RECEIVED, KEPT = 0.95, 0.6


def setup() -> RunSetup:
    argv = ["run", "--scenario", "exp2-async", "--steps", str(STEPS), "--out", "unused"]
    return resolve_setup(build_parser(argv).parse_args(argv))


def wait_until(timeout: float, condition) -> bool:
    end = time.time() + timeout
    while time.time() < end:
        if condition():
            return True
        time.sleep(0.1)
    return condition()


FORGED_SEQ = 10**9  # the forger's sequence numbers: far above the genuine sensors'


def forged(seen: list) -> list[tuple[str, int | bytes]]:
    """The forger's messages among what the recorder saw: (key, sequence number) of a detection, (key, payload)
    of the garbage."""
    out: list[tuple[str, int | bytes]] = []
    for key, payload in seen:
        if payload == b"forged":
            out.append((key, payload))
        elif "/det/" in key and (seq := msgpack.unpackb(payload)["k"]) >= FORGED_SEQ:
            out.append((key, seq))
    return out


def forge(cluster: Cluster, certs, seen: list) -> None:
    """As sensor 0 (its certificate): future detections on sensor 1's key, garbage on tracker 1's, then the
    same detections on its own key; ``seen`` gets what the recorder's session receives on those keys."""
    keys, s = cluster.keys, cluster.setup.scenario
    got: queue.Queue = queue.Queue()
    subs = [cluster.session.declare_subscriber(k, lambda m: got.put((str(m.key_expr), m.payload.to_bytes())))
            for k in (keys.det(0), keys.det(1), keys.prior(1))]

    def future(sensor: int, n: int) -> bytes:
        return Detection(FORGED_SEQ + n, time.time() + 1000.0, sensor, np.array([[0.1, 0.05]]),
                         np.asarray(s.sensors[sensor], float), np.asarray(s.noise_cov[sensor], float),
                         time.time()).encode()

    conf = build_config("client", connect=[cluster.endpoint], secure=Identity(certs, "sensor-0"))
    try:
        with zenoh.open(conf) as insider:
            for n in range(FORGED):
                insider.put(keys.det(1), future(1, n))
                insider.put(keys.prior(1), b"forged")
            for n in range(FORGED):  # after the forgeries: had they passed, they had reached the recorder first
                insider.put(keys.det(0), future(0, n))
                time.sleep(0.05)  # (within the intake's burst of sensor 0's rate)
            end = time.time() + 10.0
            while sum(1 for key, _ in forged(seen) if key == keys.det(0)) < FORGED and time.time() < end:
                try:
                    seen.append(got.get(timeout=0.1))
                except queue.Empty:
                    pass
    finally:
        for sub in subs:
            sub.undeclare()


def run(out, s: RunSetup, certs=None) -> tuple[dict, dict[int, dict], list]:
    """One run to its end (attacked by :func:`forge` in secure mode): the summary, each tracker's final report,
    and the forger's messages the recorder saw."""
    seen: list = []
    with Cluster(s, out, secure=None if certs is None else str(certs)) as cluster:
        cluster.start()
        if certs is not None:
            assert wait_until(60.0, lambda: cluster.pump(0.1) or cluster.recorder.steps_reached() >= 30), (
                "no step 30 within 60 s; sensor-0's log ends: " + (out / "logs" / "sensor-0.log").read_text()[-600:])
            forge(cluster, certs, seen)
        assert cluster.wait(timeout=STEPS * 0.1 * 3 + 60) == 0, "the truth failed"
        sensors = [p for name, p in cluster.procs.items() if name.startswith("sensor-")]
        assert wait_until(15.0, lambda: all(p.poll() is not None for p in sensors))  # each leaves at ctl/stop
        reports = cluster.node_reports()
        cluster.stop()
        summary = cluster.write_results()
    return summary, reports, forged(seen)


def published(out, sensor: int) -> int:
    """How many detections sensor ``sensor`` published (its log's last line)."""
    counts = re.findall(r"done, (\d+) detection\(s\) published", (out / "logs" / f"sensor-{sensor}.log").read_text())
    assert len(counts) == 1, f"sensor {sensor} did not finish its run"
    return int(counts[0])


def test_sensors_of_their_own_run_in_secure_mode_as_well_as_without_it_and_only_on_their_own_keys(tmp_path):
    certs = tmp_path / "certs"
    make_certificates(certs, NODES, sensors=NODES)
    s = setup()
    plain, plain_reports, _ = run(tmp_path / "plain", s)
    summary, reports, seen = run(tmp_path / "secure", s, certs)
    assert run_failures(summary, 0.1) == [] and run_failures(plain, 0.1) == [], (run_failures(summary, 0.1),
                                                                                  run_failures(plain, 0.1))
    assert "mutual TLS as sensor-0" in (tmp_path / "secure" / "logs" / "sensor-0.log").read_text()
    lines = []
    for i in range(NODES):
        det, ref = reports[i]["detections"], plain_reports[i]["detections"]
        rmse, rmse_plain = float(summary["nodes"][i]["rmse_p"]), float(plain["nodes"][i]["rmse_p"])
        rate = s.sensor_streams()[i].rate_hz
        sent = published(tmp_path / "secure", i)
        lines.append(f"node {i}: {rate:g} Hz, RMSE secure {rmse:.2f} / plain {rmse_plain:.2f} = "
                     f"{rmse / rmse_plain:.2f}; sensor {i} published {sent}, det_rx {det['det_rx']} (plain "
                     f"{ref['det_rx']}), too_old {det['too_old']} (plain {ref['too_old']}), refused "
                     f"{reports[i]['rejected']}")
        assert reports[i]["meas_rx"] == 0, lines[-1]  # its sensor's detections only
        # tracker i takes sensor i: what reached it, kept or older than the lag (a reordered 1 Hz scan, by design)
        assert sent >= 0.8 * STEPS * 0.1 * rate and det["det_rx"] + det["too_old"] >= RECEIVED * sent, lines[-1]
        assert det["det_rx"] >= KEPT * sent, lines[-1]
        assert rmse <= RMSE_RATIO * rmse_plain, lines[-1]
    print("\n".join(lines))
    assert [n["detections"] for n in summary["nodes"]] == [reports[i]["detections"] for i in range(NODES)]
    # the insider: only what it put on its own key reached anyone, each refused by tracker 0 as from the future
    assert sorted((key.rsplit("/", 2)[1:], seq) for key, seq in seen) == [
        (["det", "0"], FORGED_SEQ + n) for n in range(FORGED)], seen
    # (a loaded host also has a tracker refuse a prior as stale now and then: only these reasons are the forger's)
    refused = [{r: reports[i]["rejected"].get(r, 0) for r in ("future", "undecodable")} for i in range(NODES)]
    assert refused == [{"future": FORGED, "undecodable": 0}] + [{"future": 0, "undecodable": 0}] * (NODES - 1), refused
