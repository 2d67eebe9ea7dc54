"""deploy/cluster.sh on 4 trackers: status (from liveliness) follows up/kill/restart/freeze within 2 s (plus the
cost of one status probe as margin), a thawed node comes back, and down leaves no process behind."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from zentrack.common.procs import processes_of_runs

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "deploy" / "cluster.sh"
ZENTRACK = str(Path(sys.executable).with_name("zentrack"))
#: how long a crash, restart or freeze may take to show in liveliness (the nodes' lease is 1 s)
LIVENESS_S = 2.0
#: `zentrack status --timeout`: how long one probe waits for the cluster's peers and replies
PROBE_TIMEOUT_S = 1.0


def sh(tmp, *args, timeout=90):
    env = {**os.environ, "ZENTRACK": ZENTRACK}
    return subprocess.run(["bash", str(SCRIPT), "--dir", str(tmp), *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


class Probe:
    """`zentrack status --json` against the cluster of ``tmp``, timing every call.

    A probe's answer reflects liveliness when it queries (a few hundred ms after it starts), but the process
    can take much longer to exit: closing a session while a peer is frozen blocks ~10 s in Zenoh. So
    :meth:`becomes` starts a new probe every ``PROBE_EVERY_S`` without waiting for the previous one to exit, and
    times the change by when the first probe that saw it *started*."""

    PROBE_EVERY_S = 0.5

    def __init__(self, tmp: Path) -> None:
        env = dict(line.split("=", 1) for line in (tmp / "cluster.env").read_text().split())
        self.cmd = [ZENTRACK, "status", "--run", env["RUN"], "--connect", f"tcp/127.0.0.1:{env['PORT']}", "--json",
                    "--timeout", str(PROBE_TIMEOUT_S)]
        self.costs: list[float] = []

    def nodes(self) -> list[int]:
        t0 = time.time()
        out = subprocess.run(self.cmd, capture_output=True, text=True, timeout=30)
        self.costs.append(time.time() - t0)
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout)["nodes"]

    def becomes(self, expected: list[int], what: str) -> None:
        """Some probe started within LIVENESS_S plus one probe's cost of now shows ``expected``."""
        budget = LIVENESS_S + max(self.costs)
        t0 = time.time()
        last_start, give_up = t0 + budget, t0 + budget + 30.0
        running: list[tuple[float, subprocess.Popen]] = []
        seen = []
        try:
            while time.time() < give_up:
                now = time.time()
                if now <= last_start and (not running or now - running[-1][0] >= self.PROBE_EVERY_S):
                    running.append((now, subprocess.Popen(self.cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                                          text=True)))
                for started, proc in [r for r in running if r[1].poll() is not None]:
                    running.remove((started, proc))
                    out, err = proc.communicate()
                    assert proc.returncode == 0, err
                    nodes = json.loads(out)["nodes"]
                    seen.append((round(started - t0, 2), nodes))
                    if nodes == expected:
                        print(f"{what}: visible to a probe started {started - t0:.2f} s after (budget {budget:.2f} s); "
                              f"that probe answered after {time.time() - started:.2f} s")
                        return
                if not running and now > last_start:
                    break
                time.sleep(0.05)
            raise AssertionError(f"{what}: no status probe started within {budget:.2f} s showed {expected}; "
                                 f"(start offset, nodes) seen: {seen}")
        finally:
            for _, proc in running:
                proc.kill()
                proc.wait(timeout=10)


def wait_until(timeout, predicate) -> bool:
    end = time.time() + timeout
    while time.time() < end:
        if predicate():
            return True
        time.sleep(0.1)
    return predicate()


@pytest.mark.slow
def test_cluster_sh_lifecycle(tmp_path):
    run = None
    try:
        up = sh(tmp_path, "up", "--nodes", "4", "--steps", "3000")
        assert up.returncode == 0, up.stderr + up.stdout
        run = dict(line.split("=", 1) for line in (tmp_path / "cluster.env").read_text().split())["RUN"]
        probe = Probe(tmp_path)
        assert probe.nodes() == [0, 1, 2, 3]
        assert probe.nodes() == [0, 1, 2, 3]  # two probes: their cost sets the budgets below
        print(f"status probe (--timeout {PROBE_TIMEOUT_S}) took {', '.join(f'{c:.2f}' for c in probe.costs)} s")
        status = sh(tmp_path, "status")
        assert "4 tracker(s) alive [0, 1, 2, 3]" in status.stdout and "truth" in status.stdout

        assert sh(tmp_path, "kill", "2").returncode == 0
        probe.becomes([0, 1, 3], "kill -9")
        assert "dead" in sh(tmp_path, "status").stdout

        assert sh(tmp_path, "restart", "2").returncode == 0
        probe.becomes([0, 1, 2, 3], "restart")

        running = sh(tmp_path, "thaw", "1")  # a running node: told apart from a frozen one, nothing sent
        assert running.returncode == 0 and running.stdout.strip() == "node-1 is running, not frozen: nothing to thaw"
        assert sh(tmp_path, "freeze", "1").returncode == 0
        probe.becomes([0, 2, 3], "freeze (1 s lease)")
        assert "frozen" in sh(tmp_path, "status").stdout
        assert "already frozen" in sh(tmp_path, "freeze", "1").stdout
        thaw = sh(tmp_path, "thaw", "1")
        assert thaw.returncode == 0 and thaw.stdout.strip() == "node-1 thawed", thaw.stdout
        # a thawed node must first re-open the links its peers closed when its lease ran out
        t_thaw = time.time()
        assert wait_until(20.0, lambda: probe.nodes() == [0, 1, 2, 3]), "thawed node did not come back"
        print(f"thawed node visible again after {time.time() - t_thaw:.1f} s")

        logs = sh(tmp_path, "logs", "0")
        assert logs.returncode == 0 and "node 0 up" in logs.stdout
        bad = sh(tmp_path, "kill", "9")
        assert bad.returncode == 2 and "tracker id from 0 to 3" in bad.stderr
        assert sh(tmp_path, "up").returncode == 2  # already up
    finally:
        down = sh(tmp_path, "down")
    assert down.returncode == 0, down.stderr
    assert run is not None
    assert wait_until(10.0, lambda: processes_of_runs([run]) == []), processes_of_runs([run])


@pytest.mark.parametrize("args, message", [(["up", "--nodes", "x"], "positive whole number"),
                                           (["up", "--timing", "fast"], "realtime or lockstep"),
                                           (["up", "--mode", "fast"], "deprecated and goes in the next release; "
                                                                      "use --timing fast"),
                                           (["up", "--zenoh-config", "/nonexistent.json5"], "no such file"),
                                           (["up", "--hosts", "0"], "--hosts must be"),
                                           (["up", "--nodes", "2", "--hosts", "2", "--secure", "."], "not supported"),
                                           (["kill-router", "0"], "no cluster"),
                                           (["status"], "no cluster")])
def test_cluster_sh_rejects_bad_input(tmp_path, args, message):
    out = sh(tmp_path, *args)
    assert out.returncode == 2 and message in out.stderr


def test_cluster_sh_secure_sensors_of_their_own_need_their_certificates(tmp_path):
    """exp2-async in secure mode: each sensor runs as sensor-<S>; a folder without their certificates is refused
    before anything starts, naming the command that makes them."""
    from zentrack.cluster.deployment.certs import make_certificates

    make_certificates(tmp_path / "certs", nodes=6)
    out = sh(tmp_path, "up", "--nodes", "6", "--scenario", "exp2-async", "--secure", str(tmp_path / "certs"))
    assert out.returncode == 2 and "no certificate for sensor-5" in out.stderr and "--nodes 6 --sensors 6" in out.stderr
    assert not (tmp_path / "cluster.env").exists()


@pytest.mark.parametrize("args, hint", [(["kil", "0"], "unknown command 'kil'; did you mean 'kill'?"),
                                        (["thwa", "0"], "unknown command 'thwa'; did you mean 'thaw'?"),
                                        (["up", "--nodse", "3"], "unknown option --nodse; did you mean '--nodes'?")])
def test_cluster_sh_suggests_the_command_or_option_meant(tmp_path, args, hint):
    out = sh(tmp_path, *args)
    assert out.returncode == 2 and hint in out.stderr.splitlines()[0], out.stderr


def test_cluster_sh_names_an_unknown_command_in_one_line(tmp_path):
    """Before: the whole 35-line usage, without the word at fault."""
    out = sh(tmp_path, "frobnicate", "0")
    lines = out.stderr.splitlines()
    assert out.returncode == 2 and len(lines) == 2, out.stderr
    assert lines[0] == "cluster.sh: unknown command 'frobnicate'" and "thaw" in lines[1] and "--help" in lines[1]


def test_cluster_sh_help():
    out = subprocess.run(["bash", str(SCRIPT), "--help"], capture_output=True, text=True, timeout=10)
    for word in ("up", "down", "status", "logs", "kill", "restart", "freeze", "thaw"):
        assert f"\n  {word}" in out.stdout


@pytest.mark.slow
def test_cluster_sh_hands_a_zenoh_file_to_every_process(tmp_path):
    conf = tmp_path / "zenoh.json5"
    conf.write_text("{}")
    run = None
    try:
        up = sh(tmp_path, "up", "--nodes", "2", "--steps", "3000", "--router", "--zenoh-config", str(conf))
        assert up.returncode == 0, up.stderr + up.stdout
        run = dict(line.split("=", 1) for line in (tmp_path / "cluster.env").read_text().split())["RUN"]
        assert wait_until(30.0, lambda: Probe(tmp_path).nodes() == [0, 1])
        for name in ("router", "truth", "node-0", "node-1"):
            text = (tmp_path / "logs" / f"{name}.log").read_text()
            lines = [line for line in text.splitlines() if "zenoh session" in line]
            assert lines and all("multicast scouting off" in line for line in lines), (name, text[-2000:])
            assert str(conf) in (tmp_path / "cmd" / name).read_text()
    finally:
        down = sh(tmp_path, "down")
    assert down.returncode == 0, down.stderr
    assert run is not None and wait_until(10.0, lambda: processes_of_runs([run]) == [])


@pytest.mark.slow
@pytest.mark.parametrize("given", [True, False], ids=["certs-given", "certs-made"])
def test_cluster_sh_secure_mode(tmp_path, given):
    """``up --secure DIR`` uses DIR's certificates; ``up --secure`` makes them in the cluster's folder."""
    from zentrack.cluster.deployment.certs import make_certificates

    certs = tmp_path / "certs"
    if given:
        make_certificates(certs, nodes=2)
        assert sh(tmp_path, "up", "--nodes", "3", "--secure", str(certs)).returncode == 2  # no node-2 certificate
    run = None
    try:
        up = sh(tmp_path, "up", "--nodes", "2", "--steps", "3000", "--secure", *([str(certs)] if given else []))
        assert up.returncode == 0, up.stderr + up.stdout
        env = dict(line.split("=", 1) for line in (tmp_path / "cluster.env").read_text().split())
        run = env["RUN"]
        assert env["SECURE"] == str(certs.resolve())
        # cluster.sh status asks over TLS with the monitor's certificate
        assert wait_until(30.0, lambda: "2 tracker(s) alive [0, 1]" in sh(tmp_path, "status").stdout)
        plain = subprocess.run([ZENTRACK, "status", "--run", run, "--connect", f"tcp/127.0.0.1:{env['PORT']}", "--json",
                                "--timeout", "2"], capture_output=True, text=True, timeout=60)
        assert plain.returncode != 0 or json.loads(plain.stdout)["nodes"] == [], plain.stdout  # nothing over plain TCP
        assert "access control on" in (tmp_path / "logs" / "router.log").read_text()
        for name in ("truth", "node-0", "node-1"):
            text = (tmp_path / "logs" / f"{name}.log").read_text()
            assert f"mutual TLS as {name}" in text and "mode client" in text, text[-1500:]
    finally:
        down = sh(tmp_path, "down")
    assert down.returncode == 0, down.stderr
    assert run is not None and wait_until(10.0, lambda: processes_of_runs([run]) == [])


@pytest.mark.slow
def test_cluster_sh_multi_host_topology_and_a_killed_router(tmp_path):
    """--hosts 3: one router per host linked to the routers before it, each tracker a client of its own host's
    router only; killing host 1's router takes exactly host 1's trackers out, restarting it brings them back."""
    assert sh(tmp_path, "up", "--nodes", "2", "--hosts", "3").returncode == 2  # more hosts than trackers
    run = None
    try:
        up = sh(tmp_path, "up", "--nodes", "6", "--hosts", "3", "--steps", "3000")
        assert up.returncode == 0, up.stderr + up.stdout
        env = dict(line.split("=", 1) for line in (tmp_path / "cluster.env").read_text().split())
        run, ports = env["RUN"], env["PORTS"].split(",")
        assert len(set(ports)) == 3 and env["PORT"] == ports[0]
        cmd = lambda name: (tmp_path / "cmd" / name).read_text().split()  # noqa: E731
        assert cmd("router-2")[cmd("router-2").index("--listen") + 1] == f"tcp/127.0.0.1:{ports[2]}"
        assert [a for i, a in enumerate(cmd("router-2")) if cmd("router-2")[i - 1] == "--connect"] == \
            [f"tcp/127.0.0.1:{ports[0]}", f"tcp/127.0.0.1:{ports[1]}"]
        for node in range(6):  # nodes 0-1 on host 0, 2-3 on host 1, 4-5 on host 2
            assert [a for i, a in enumerate(cmd(f"node-{node}")) if cmd(f"node-{node}")[i - 1] == "--connect"] == \
                [f"tcp/127.0.0.1:{ports[node // 2]}"]
        probe = Probe(tmp_path)
        assert wait_until(30.0, lambda: probe.nodes() == list(range(6)))
        killed = sh(tmp_path, "kill-router", "1")
        assert killed.returncode == 0, killed.stderr
        assert wait_until(15.0, lambda: probe.nodes() == [0, 1, 4, 5])
        restarted = sh(tmp_path, "restart-router", "1")
        assert restarted.returncode == 0, restarted.stderr
        assert wait_until(30.0, lambda: probe.nodes() == list(range(6)))
        assert sh(tmp_path, "kill-router", "3").returncode == 2
    finally:
        down = sh(tmp_path, "down")
    assert down.returncode == 0, down.stderr
    assert run is not None and wait_until(10.0, lambda: processes_of_runs([run]) == [])
