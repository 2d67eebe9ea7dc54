"""deploy/cluster.sh on 4 trackers: status (from liveliness) follows up/kill/restart/freeze within 2 s, a
thawed node comes back, and down leaves no process behind."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from zentrack.zsession import processes_of_runs

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "deploy" / "cluster.sh"


def sh(tmp, *args, timeout=90):
    env = {**os.environ, "ZENTRACK": str(Path(sys.executable).with_name("zentrack"))}
    return subprocess.run(["bash", str(SCRIPT), "--dir", str(tmp), *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def live_nodes(tmp) -> list[int]:
    env = dict(line.split("=", 1) for line in (tmp / "cluster.env").read_text().split())
    out = subprocess.run([str(Path(sys.executable).with_name("zentrack")), "status", "--run", env["RUN"], "--connect",
                          f"tcp/127.0.0.1:{env['PORT']}", "--json", "--timeout", "2"],
                         capture_output=True, text=True, timeout=30)
    return json.loads(out.stdout)["nodes"]


def within(seconds, predicate) -> bool:
    end = time.time() + seconds
    while time.time() < end:
        if predicate():
            return True
        time.sleep(0.1)
    return predicate()


def test_cluster_sh_lifecycle(tmp_path):
    run = None
    try:
        up = sh(tmp_path, "up", "--nodes", "4", "--steps", "3000")
        assert up.returncode == 0, up.stderr + up.stdout
        run = dict(line.split("=", 1) for line in (tmp_path / "cluster.env").read_text().split())["RUN"]
        assert live_nodes(tmp_path) == [0, 1, 2, 3]
        status = sh(tmp_path, "status")
        assert "4 tracker(s) alive [0, 1, 2, 3]" in status.stdout and "truth" in status.stdout

        assert sh(tmp_path, "kill", "2").returncode == 0
        assert within(2.0, lambda: live_nodes(tmp_path) == [0, 1, 3]), "kill -9 not visible within 2 s"
        assert "dead" in sh(tmp_path, "status").stdout

        assert sh(tmp_path, "restart", "2").returncode == 0
        assert within(2.0, lambda: live_nodes(tmp_path) == [0, 1, 2, 3]), "restart not visible within 2 s"

        assert sh(tmp_path, "freeze", "1").returncode == 0
        assert within(2.0, lambda: live_nodes(tmp_path) == [0, 2, 3]), "freeze not visible within 2 s"
        assert "frozen" in sh(tmp_path, "status").stdout
        assert sh(tmp_path, "thaw", "1").returncode == 0
        # a thawed node must first re-open the links its peers closed when its lease ran out
        t_thaw = time.time()
        assert within(20.0, lambda: live_nodes(tmp_path) == [0, 1, 2, 3]), "thawed node did not come back"
        print(f"thawed node visible again after {time.time() - t_thaw:.1f} s")

        logs = sh(tmp_path, "logs", "0")
        assert logs.returncode == 0 and "node 0 up" in logs.stdout
        bad = sh(tmp_path, "kill", "9")
        assert bad.returncode == 2 and "tracker id from 0 to 3" in bad.stderr
        assert sh(tmp_path, "up").returncode == 2  # already up
    finally:
        down = sh(tmp_path, "down")
    assert down.returncode == 0, down.stderr
    time.sleep(0.3)
    assert run is not None and processes_of_runs([run]) == []


@pytest.mark.parametrize("args, message", [(["up", "--nodes", "x"], "positive whole number"),
                                           (["up", "--mode", "fast"], "realtime or lockstep"),
                                           (["status"], "no cluster")])
def test_cluster_sh_rejects_bad_input(tmp_path, args, message):
    out = sh(tmp_path, *args)
    assert out.returncode == 2 and message in out.stderr


def test_cluster_sh_help():
    out = subprocess.run(["bash", str(SCRIPT), "--help"], capture_output=True, text=True, timeout=10)
    for word in ("up", "down", "status", "logs", "kill", "restart", "freeze", "thaw"):
        assert f"\n  {word}" in out.stdout
