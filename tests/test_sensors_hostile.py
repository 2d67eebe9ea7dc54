"""Hostile time, live (issue 52 item 6): beside genuine sensor 0 of an ``exp2-async`` run, ``tests/hostile_sensor.py``
puts on ``det/0`` a detection from the future, with a NaN, a negative and a zero time, one far in the past, one with
a forged sensor id, an exact copy, 2 s of a clock 10 s back and 2 s at 1000 Hz. Tracker 0 must refuse or
rate-limit each and count it under its reason, keep serving (estimates after the attack, a track as good as its
neighbours'), and the run's summary must say what it refused."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from zentrack.cli import build_parser
from zentrack.cluster.run.cluster import Cluster
from zentrack.common.run_summary import run_failures
from zentrack.config.run_setup import resolve_setup

#: the 1000 Hz flood loads the host: beside it, another live test's tracker missed messages (run 39 of
#: docs/testing.md: node 3 of test_runtime.py's hostile-input test counted 2,779 of 5,000)
pytestmark = [pytest.mark.slow, pytest.mark.loads_host]

HOSTILE = Path(__file__).resolve().parent / "hostile_sensor.py"
STEPS = 220
#: tracker 0's RMSE against the median of the run's other trackers: the flood's rate limit costs it about 2 s of
#: its own sensor's detections (the bucket is the sensor's), which its neighbours' estimates bridge, and the forged
#: detections the rate limit lets through (3 times the sensor's rate) are held off by the validation gate (without
#: it, measured: 388 m against 7.2 m)
RMSE_RATIO = 1.5


def test_a_tracker_refuses_hostile_time_counts_it_and_keeps_tracking(tmp_path) -> None:
    argv = ["run", "--scenario", "exp2-async", "--steps", str(STEPS), "--out", "unused"]
    setup = resolve_setup(build_parser(argv).parse_args(argv))
    report_path = tmp_path / "hostile.json"
    with Cluster(setup, tmp_path / "run") as cluster:
        cluster.start()
        hostile = subprocess.Popen([sys.executable, str(HOSTILE), cluster.endpoint, cluster.run_name, "0", "0",
                                    str(report_path)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            end = time.time() + 90
            while hostile.poll() is None and time.time() < end:  # the attack, paced by the tracker's estimates
                cluster.pump(0.1)
            assert hostile.poll() == 0, hostile.stderr.read() if hostile.poll() is not None else "still attacking"
            code = cluster.wait(timeout=STEPS * 0.1 * 3 + 60)
            assert code == 0, f"the truth exited {code}"
            reports = cluster.node_reports()
            cluster.stop()
            summary = cluster.write_results()
        finally:
            if hostile.poll() is None:
                hostile.kill()
                hostile.wait()
    attack = json.loads(report_path.read_text())
    assert attack["served_after"], "tracker 0 published no estimates after the attack"
    rejected, dropped = reports[0]["rejected"], reports[0].get("dropped", {})
    rmse = [float(n["rmse_p"]) for n in summary["nodes"]]
    print(f"hostile time: sent {attack['sent']}, tracker 0 refused {rejected}, dropped {dropped}, "
          f"detections {reports[0]['detections']}, RMSE {rmse[0]:.2f} m (others' median {np.median(rmse[1:]):.2f} m)")
    expected = {"future": 1, "nonfinite": 1, "range": 2, "sender_mismatch": 1, "duplicate": 1,
                "stale": 1 + attack["sent"]["clock_back_10s"]}
    for reason, least in expected.items():
        assert rejected.get(reason, 0) >= least, (reason, rejected)
    flood = attack["sent"]["flood_1000hz"]
    limited = rejected.get("rate", 0) + sum(v for k, v in dropped.items() if k.startswith("det/"))
    assert limited >= 0.8 * flood, (limited, flood, rejected, dropped)  # at most 3x 10 Hz and a burst get through
    for i, other in reports.items():  # nothing of it reached another tracker
        assert i == 0 or not other["rejected"], (i, other["rejected"])
    assert not run_failures(summary, 0.05), run_failures(summary, 0.05)
    entry = summary["nodes"][0]
    assert sum(entry["messages"]["rejected"].values()) >= sum(expected.values()), entry["messages"]
    assert reports[0]["detections"]["gated"] >= 0.5 * (flood - limited), reports[0]["detections"]  # forged values
    assert rmse[0] <= RMSE_RATIO * float(np.median(rmse[1:])), rmse
