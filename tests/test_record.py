"""``zentrack record``: a recorder process joins a run it did not start, writes its summary when truth says
stop, and exits 1 when the run did not do its job (a silent tracker, no stop)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest
import zenoh

from zentrack.common.ports import free_port
from zentrack.config.scenario_config import builtin_spec
from zentrack.config.scenario_file import save_scenario
from zentrack.transport import wire
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Stop
from zentrack.transport.zsession import loopback_config
from zentrack.truth.simulation.simulate import simulate

pytestmark = pytest.mark.slow
STEPS, NODES = 30, 3


def wait_for(predicate, timeout: float, what: str) -> None:
    end = time.time() + timeout
    while not predicate():
        if time.time() > end:
            raise AssertionError(f"{what}: not within {timeout:.0f} s")
        time.sleep(0.05)


def record_a_run(tmp_path, silent_node: int | None = None, stop_sender: str = "truth", timeout: float = 60.0):
    """Start ``zentrack record``, publish every node's estimates (the truth plus a little noise) and a stop;
    return the process's exit code, its output and the summary it wrote."""
    scn = simulate(builtin_spec("exp2", nodes=NODES, steps=STEPS), runs=1, seed=3)
    scenario = save_scenario(tmp_path / "scenario.npz", scn)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys("recordtest")
    out = tmp_path / "out"
    with zenoh.open(loopback_config("peer", listen=[endpoint])) as session:
        proc = subprocess.Popen([sys.executable, "-m", "zentrack", "record", "--scenario-file", str(scenario),
                                 "--run", keys.run, "--connect", endpoint, "--out", str(out), "--timeout", str(timeout)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            def recorder_alive() -> bool:
                return any(r.ok is not None for r in session.liveliness().get(keys.alive("recorder"), timeout=1.0))

            wait_for(recorder_alive, 30.0, "the recorder's liveliness token")
            rng = np.random.default_rng(0)
            for k in range(STEPS):
                for i in range(NODES):
                    if i == silent_node:
                        continue
                    x = scn.truth[0, k] + rng.normal(0.0, 1.0, 6)
                    session.put(keys.est(i), EstimateMessage(k, k * scn.ts, i, x, np.eye(6), time.time(),
                                                             counters={"steps": k + 1, "misses": 0}).encode())
            # nothing to wait for before the stop: this session's puts reach each observer in the order sent (the
            # observers declared their subscribers before the tokens waited for above), and an observer records
            # for a grace second after ctl/stop
            stop = Stop(STEPS).encode() if stop_sender == "truth" else wire.encode("stop", STEPS, 0.0, stop_sender)
            session.put(keys.stop, stop)
            stdout, stderr = proc.communicate(timeout=timeout + 30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else None
    return proc.returncode, stdout + stderr, summary


def test_record_writes_the_summary_of_a_run_it_did_not_start(tmp_path):
    code, text, summary = record_a_run(tmp_path)
    assert code == 0, text
    assert "run OK" in text
    assert [n["steps_estimated"] for n in summary["nodes"]] == [STEPS] * NODES
    assert all(0.5 < n["rmse_p"] < 3.0 for n in summary["nodes"])  # the published noise is 1 m per component
    assert summary["run"]["recorded_by"] == "zentrack record"
    assert np.load(tmp_path / "out" / "estimates.npz")["mean"].shape == (STEPS, NODES, 6)


def test_record_fails_a_run_with_a_silent_tracker(tmp_path):
    code, text, summary = record_a_run(tmp_path, silent_node=2)
    assert code == 1, text
    assert "FAILED: node 2 published no estimate" in text and "run OK" not in text
    assert summary["nodes"][2]["steps_estimated"] == 0 and summary["nodes"][0]["steps_estimated"] == STEPS


def test_record_ignores_a_forged_stop_and_fails_when_none_comes(tmp_path):
    code, text, summary = record_a_run(tmp_path, stop_sender="mallory", timeout=4.0)
    assert code == 1, text
    assert "ignored a message on ctl/stop" in text and "did not say stop" in text
    assert summary is not None  # what was recorded is written all the same
