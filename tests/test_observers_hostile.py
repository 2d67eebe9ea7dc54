"""A live recorder (``zentrack record``) and viewer (``zentrack viewer --save``) sent well-formed but wrong
estimates among a run's good ones: each counts what it refused and keeps going, to the run's end.

The wrong estimates are valid msgpack maps of kind ``est`` on a node's key, each with one field of the wrong
type or out of its range (``fused`` a string, counters a list, neighbours holding a float, ...). Before the
typed messages the recorder decoded an estimate into its map and ``int(e.get("fused") or 0)`` raised outside
its error handler, which ended the recorder.
"""
from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest
import zenoh
from test_viewer import column, read_rrd

from zentrack.common.ports import free_port
from zentrack.config.scenario_config import builtin_spec
from zentrack.config.scenario_file import save_scenario
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Stop, Truth
from zentrack.transport.zsession import loopback_config
from zentrack.truth.simulation.simulate import simulate

pytestmark = pytest.mark.slow
STEPS, NODES = 20, 3
#: (field, value): node 0's estimate with that field, sent before its good estimate of the step (the recorded
#: run is the good one)
WRONG = [
    ("fused", "3"), ("fused", 2.5), ("counters", [1, 2]), ("counters", {"steps": "3"}), ("counters", {"rejected": 3}),
    ("neighbours", [1, 2.0]), ("neighbours", "1,2"), ("update_us", "fast"), ("t_meas_pub", float("nan")),
    ("coasted", 1), ("warm", "no"), ("round_ms", [1.0, 2.0]), ("samples", {"shape": [2, 6], "data": b"\x00" * 8}),
    ("beta", {"shape": [2], "data": np.array([0.5, 7.0]).tobytes()}), ("k", 2**64 - 1),
    ("x", {"shape": [5], "data": b"\x00" * 40}),  # not the scenario's dimension (P left 6 x 6: shape)
    ("k", 2**62),  # a step far beyond the run (the viewer drew it once, and lost node 0's earlier rows)
]


def wait_for(predicate, timeout: float, what: str) -> None:
    end = time.time() + timeout
    while not predicate():
        if time.time() > end:
            raise AssertionError(f"{what}: not within {timeout:.0f} s")
        time.sleep(0.05)


def wrong_estimate(k: int, x: np.ndarray, field: str, value) -> bytes:
    msg = msgpack.unpackb(EstimateMessage(k, k * 0.1, 0, x, np.eye(6), time.time(), fused=2, neighbours=(1, 2),
                                          counters={"steps": k + 1}).encode())
    msg[field] = value
    return msgpack.packb(msg, use_bin_type=True)


def test_a_live_recorder_and_viewer_count_wrong_estimates_and_keep_recording(tmp_path):
    scn = simulate(builtin_spec("exp2", nodes=NODES, steps=STEPS), runs=1, seed=3)
    scenario = save_scenario(tmp_path / "scenario.npz", scn)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys("hostileobs")
    common = ["--scenario-file", str(scenario), "--run", keys.run, "--connect", endpoint]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    rrd = tmp_path / "recording.rrd"
    with zenoh.open(loopback_config("peer", listen=[endpoint])) as session:
        procs = {
            "recorder": subprocess.Popen([sys.executable, "-m", "zentrack", "record", *common, "--out", str(tmp_path / "out"),
                                          "--timeout", "120"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env),
            "viewer": subprocess.Popen([sys.executable, "-m", "zentrack", "viewer", *common, "--save", str(rrd),
                                        "--flush-s", "0.2", "--nice", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                       text=True, env=env),
        }
        try:
            for name in procs:
                def alive(name=name) -> bool:
                    return any(r.ok is not None for r in session.liveliness().get(keys.alive(name), timeout=1.0))

                wait_for(alive, 60.0, f"the {name}'s liveliness token")
            rng = np.random.default_rng(0)
            plan: dict[int, list] = {}  # two wrong estimates before the good one of steps 1, 2, ...
            for j, (field, value) in enumerate(WRONG):
                plan.setdefault(1 + j // 2, []).append((field, value))
            for k in range(STEPS):
                session.put(keys.truth, Truth(k, k * scn.ts, scn.truth[0, k], time.time()).encode())
                for i in range(NODES):
                    x = scn.truth[0, k] + rng.normal(0.0, 1.0, 6)
                    for field, value in plan.get(k, []) if i == 0 else []:
                        session.put(keys.est(0), wrong_estimate(k, x, field, value))
                    session.put(keys.est(i), EstimateMessage(k, k * scn.ts, i, x, np.eye(6), time.time(), fused=2,
                                                             counters={"steps": k + 1, "misses": 0}).encode())
                time.sleep(0.02)
            # nothing to wait for before the stop: this session's puts reach each observer in the order sent (the
            # observers declared their subscribers before the tokens waited for above), and an observer records
            # for a grace second after ctl/stop
            session.put(keys.stop, Stop(STEPS).encode())
            out = {name: proc.communicate(timeout=90) for name, proc in procs.items()}
        finally:
            for proc in procs.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(timeout=10)
    text = {name: stdout + stderr for name, (stdout, stderr) in out.items()}
    assert procs["recorder"].returncode == 0, text["recorder"]
    assert procs["viewer"].returncode == 0, text["viewer"]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["network"]["dropped_estimate_messages"] == len(WRONG)
    assert [n["steps_estimated"] for n in summary["nodes"]] == [STEPS] * NODES
    assert all(0.5 < n["rmse_p"] < 3.0 for n in summary["nodes"])  # the good estimates, not the wrong ones
    logged = ast.literal_eval(re.search(r"viewer: logged (\{.*\})", text["viewer"]).group(1))
    assert logged["bad"] == len(WRONG) and logged["est"] == STEPS * NODES
    rec = read_rrd(rrd)
    for i in range(NODES):  # drawn to the run's end, after every wrong estimate
        steps = column(rec[f"/world/nodes/{i}/estimate"], "step")
        assert set(range(STEPS)) <= set(steps), (i, sorted(steps))
