"""``zentrack run`` as a newcomer meets it (issue 31, item 6): a Ctrl-C'd run reports only the steps it ran,
a second run into a live run's ``--out`` is refused, ``--nodes 1`` warns that nothing is fused, a progress line
on a terminal (none in a pipe), the summary's columns explained with ANEES beside its band, and the closing
line naming the outputs."""
from __future__ import annotations

import json
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from zentrack.cli import main
from zentrack.common.run_summary import LEGEND, anees_cell, interrupted_line, ok_line

RUN = [sys.executable, "-m", "zentrack", "run", "--scenario", "exp2"]


def stop(proc: subprocess.Popen) -> None:
    """Kill what a test started (its whole session), if still running."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)


@pytest.mark.slow
def test_a_ctrl_c_run_on_a_terminal_shows_progress_and_reports_only_the_steps_run(tmp_path):
    """Before: the summary counted the 550 steps never reached as missed ("deadline misses" per node) and the
    progress of the run's wait was silence."""
    out = tmp_path / "run"
    master, slave = pty.openpty()
    proc = subprocess.Popen([*RUN, "--nodes", "2", "--steps", "600", "--timing", "realtime", "--out", str(out)],
                            stdin=subprocess.DEVNULL, stdout=slave, stderr=slave, start_new_session=True)
    os.close(slave)
    text = b""

    def read(seconds: float) -> None:
        nonlocal text
        end = time.time() + seconds
        while time.time() < end:
            if select.select([master], [], [], 0.1)[0]:
                try:
                    text += os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    return

    try:
        end = time.time() + 90
        while not re.search(rb"\] ([2-9]\d|\d{3})/600 steps", text):  # 20 or more steps drawn on the terminal
            assert time.time() < end and proc.poll() is None, text.decode(errors="replace")
            read(0.2)
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
        end = time.time() + 60
        while proc.poll() is None and time.time() < end:
            read(0.2)
        read(0.5)
    finally:
        stop(proc)
        os.close(master)
    output = text.decode(errors="replace")
    assert proc.returncode == 130, output
    assert "run OK" not in output
    summary = json.loads((out / "summary.json").read_text())
    k = summary["network"]["steps"]
    assert 20 <= k < 600 and summary["network"]["steps_planned"] == 600
    assert summary["run"]["interrupted_at_step"] == k
    assert f"run interrupted at step {k} of 600" in output, output
    for n in summary["nodes"]:
        assert n["steps_estimated"] + n["steps_without_estimate"] == k
        assert n["deadline_misses"] < 600 - k, n  # the steps never reached are not misses
    assert summary["network"]["anees_band_per_node"][0] > 0


@pytest.mark.slow
def test_a_run_into_the_out_of_a_live_run_is_refused_in_one_line(tmp_path):
    """Before: both runs said "run OK" into one folder (mixed logs, one summary lost)."""
    out = tmp_path / "shared"
    first = subprocess.Popen([*RUN, "--nodes", "2", "--steps", "400", "--timing", "realtime", "--out", str(out)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        end = time.time() + 60
        while not (out / "logs" / "node-1.log").exists() or not (out / ".lock").read_text().strip():
            assert time.time() < end and first.poll() is None, "the first run did not start"
            time.sleep(0.1)
        before = {p.relative_to(out): p.stat().st_mtime_ns for p in out.rglob("*") if p.suffix != ".log"}
        second = subprocess.run([*RUN, "--nodes", "2", "--steps", "20", "--timing", "lockstep", "--out", str(out)],
                                capture_output=True, text=True, timeout=60)
        after = {p.relative_to(out): p.stat().st_mtime_ns for p in out.rglob("*") if p.suffix != ".log"}
        assert first.poll() is None, "the first run must be untouched"
    finally:
        stop(first)
    assert second.returncode == 2, second.stdout + second.stderr
    assert second.stderr.splitlines() == [
        f"zentrack run: error: --out {out} is in use by another live run (pid {first.pid}, run "
        f"{(out / '.lock').read_text().split()[1]}); wait for it to finish, stop it, or choose another --out"]
    assert second.stdout == "" and before == after


@pytest.mark.slow
def test_a_held_out_lock_refuses_the_run_before_anything_is_written(tmp_path):
    """The same refusal without a cluster: another process holds ``<out>/.lock``."""
    out = tmp_path / "busy"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from pathlib import Path; "
                               "from zentrack.cluster.run.out_lock import claim_out; claim_out(Path(sys.argv[1]), 'r42'); "
                               "print('held', flush=True); time.sleep(60)", str(out)],
                              stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        proc = subprocess.run([*RUN, "--nodes", "2", "--steps", "5", "--out", str(out)], capture_output=True,
                              text=True, timeout=60)
    finally:
        stop(holder)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"zentrack run: error: --out {out} is in use by another live run (pid "
                                   f"{holder.pid}, run r42); wait for it to finish, stop it, or choose another --out")
    assert sorted(p.name for p in out.iterdir()) == [".lock"]  # no scenario, logs or config written


@pytest.mark.slow
def test_one_tracker_is_warned_that_nothing_is_fused_and_a_pipe_gets_no_progress_line(tmp_path):
    proc = subprocess.run([*RUN, "--nodes", "1", "--steps", "10", "--timing", "lockstep", "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert warnings == ["zentrack run: warning: --nodes 1: one tracker has no neighbours, so nothing is fused "
                        "(a network needs --nodes 2 or more)"]
    assert "\r" not in proc.stderr + proc.stdout  # quiet when not a terminal
    closing = proc.stdout.splitlines()[-1]
    o = tmp_path / "o"
    assert closing == (f"run OK: summary written to {o / 'summary.json'}, estimates {o / 'estimates.npz'}, "
                       f"logs {o / 'logs'}/")


def test_the_summary_explains_its_columns_and_puts_anees_beside_its_band():
    assert anees_cell({"anees": 3.104, "anees_band": [5.61, 6.4]}) == "3.10 [5.61, 6.40]"
    assert anees_cell({"anees": 3.104}) == "3.10"
    for column in ("RMSE", "ANEES [95% band]", "missed", "from neighbours", "late", "refused", "clock"):
        assert any(line.startswith(column) or f"; {column}:" in line for line in LEGEND), column
    assert all(len(line) <= 110 for line in LEGEND)


def test_the_closing_lines_name_where_the_outputs_are(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "estimates.npz").write_bytes(b"")
    (tmp_path / "recording.rrd").write_bytes(b"")
    where = (f"summary written to {tmp_path / 'summary.json'}, estimates {tmp_path / 'estimates.npz'}, "
             f"logs {tmp_path / 'logs'}/, recording {tmp_path / 'recording.rrd'}")
    assert ok_line({"network": {"refused": {}}}, tmp_path) == f"run OK: {where}"
    summary = {"network": {"steps": 57, "steps_planned": 300}}
    assert interrupted_line(summary, tmp_path) == (f"run interrupted at step 57 of 300 (the summary covers those 57 "
                                                   f"steps): {where}")


def test_closing_line_of_a_folder_without_outputs_still_names_the_summary():
    assert ok_line({"network": {"refused": {}}}, Path("o")) == "run OK: summary written to o/summary.json"


class _FakeSession:
    """Just enough of a Zenoh session for a Recorder that is fed by hand."""

    class _Handle:
        def undeclare(self) -> None:
            pass

    def declare_subscriber(self, key, callback):
        return self._Handle()

    def liveliness(self):
        return self

    def declare_token(self, key):
        return self._Handle()


@pytest.mark.parametrize("reached", [0, 1, 40])
def test_an_interrupted_summary_counts_only_the_steps_reached(exp2_small, reached):
    """The recorder's figures for a run stopped after ``reached`` of 120 steps: no step past it is a miss."""
    from zentrack.cluster.recording.core import Recorder
    from zentrack.cluster.recording.estimates import Estimates
    from zentrack.transport.keys import Keys

    scn = exp2_small
    recorder = Recorder(_FakeSession(), Keys("t"), Estimates(scn))  # type: ignore[arg-type]
    truth = scn.truth[0]
    recorder.part.mean[:reached] = truth[:reached, None, :] + 1.0
    recorder.part.cov[:reached] = np.eye(truth.shape[-1])
    recorder.update_us[:reached] = 50.0
    recorder.part.mean[reached // 2, 3] = np.nan  # one real miss, inside the steps run
    assert recorder.steps_reached() == reached
    summary = recorder.summary(steps_run=recorder.steps_reached())
    assert summary["network"]["steps"] == reached and summary["network"]["steps_planned"] == 120
    for n in summary["nodes"]:
        assert n["steps_estimated"] + n["steps_without_estimate"] == reached
    assert summary["nodes"][3]["deadline_misses"] == (1 if reached else 0)
    assert sum(n["deadline_misses"] for n in summary["nodes"]) == summary["network"]["deadline_misses"]
    if reached > 1:
        assert summary["nodes"][0]["anees"] == pytest.approx(truth.shape[-1])  # unit errors, unit covariance
        assert summary["nodes"][0]["anees_band"][0] < truth.shape[-1] < summary["nodes"][0]["anees_band"][1]
    full = recorder.summary()  # a run that ended: every step counts
    assert full["network"]["steps"] == 120 and full["nodes"][0]["steps_without_estimate"] == 120 - reached


def test_sim_with_one_node_warns_that_nothing_is_fused(capsys):
    assert main(["sim", "--scenario", "exp2", "--nodes", "1", "--steps", "5"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warnings == ["zentrack sim: warning: one node has no neighbours, so nothing is fused (a network needs "
                        "--nodes 2 or more)"]
