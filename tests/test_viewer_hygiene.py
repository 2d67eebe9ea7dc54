"""The viewer's web server: refused when its ports are taken, and nothing of it outlives the viewer.

``zentrack viewer --serve`` runs the real ``rerun`` binary in its own process group and stops the whole group
on exit (ctl/stop, SIGTERM); a stale server would otherwise keep the ports and silently take the next run.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from zentrack.common.ports import free_port
from zentrack.common.procs import process_running
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Stop
from zentrack.transport.zsession import loopback_config
from zentrack.viewer.ports import check_ports_free, port_in_use

pytestmark = pytest.mark.slow  # starts zentrack viewer processes that open Zenoh sessions and a Rerun server

VIEWER = [sys.executable, "-m", "zentrack", "viewer", "--scenario", "exp2", "--nodes", "2", "--steps", "20",
          "--nice", "0"]


def listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def poll(predicate, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"{what}: not within {timeout:.0f} s")
        time.sleep(0.05)


def descendants(pid: int) -> set[int]:
    """Every live process whose parent chain leads to ``pid``, and members of ``pid``'s children's groups."""
    parents: dict[int, int] = {}
    groups: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            parents[int(entry)], groups[int(entry)] = int(fields[1]), int(fields[2])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier} - found
        found |= frontier
    return found | {p for p, g in groups.items() if g in found}


def test_taken_port_is_refused_with_one_line(tmp_path):
    web, grpc = free_port(), free_port()
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", web))
        squatter.listen()
        with pytest.raises(ValueError, match=f"port {web} \\(--web-port\\)"):
            check_ports_free({web: "--web-port"})
        proc = subprocess.run([*VIEWER, "--serve", "--web-port", str(web), "--grpc-port", str(grpc), "--run", "vhport"],
                              capture_output=True, text=True, timeout=60, cwd=tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and f"port {web} (--web-port)" in lines[0] and "already in use" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
    check_ports_free([grpc])  # the refused viewer started nothing


@pytest.mark.parametrize("ending", ["sigterm", "ctl-stop", "sigkill"])
def test_nothing_of_a_served_viewer_outlives_it(tmp_path, ending):
    web, grpc, zport = free_port(), free_port(), free_port()
    run = f"vh{ending[:4]}"
    proc = subprocess.Popen([*VIEWER, "--serve", "--web-port", str(web), "--grpc-port", str(grpc), "--run", run,
                             "--listen", f"tcp/127.0.0.1:{zport}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            start_new_session=True)
    children: set[int] = set()
    try:
        poll(lambda: proc.poll() is not None or (listening(web) and listening(grpc)), 60, "the web server listening")
        assert proc.poll() is None, proc.stderr.read()
        children = descendants(proc.pid)
        assert children, "the viewer runs its Rerun server as a child"
        if ending in ("sigterm", "sigkill"):  # SIGKILL: no finally runs; the kernel's parent-death signal must do
            proc.send_signal(signal.SIGTERM if ending == "sigterm" else signal.SIGKILL)
        else:
            conf = loopback_config("peer", listen=["tcp/127.0.0.1:0"], connect=[f"tcp/127.0.0.1:{zport}"])
            with zenoh.open(conf) as session:
                keys = Keys(run)
                end = time.monotonic() + 30
                while proc.poll() is None and time.monotonic() < end:  # repeat until the viewer has it
                    session.put(keys.stop, Stop(20).encode())  # the truth's message: raw bytes are ignored
                    try:
                        proc.wait(timeout=0.5)
                    except subprocess.TimeoutExpired:
                        pass
        assert proc.wait(timeout=30) == (-signal.SIGKILL if ending == "sigkill" else 0), proc.stderr.read()
        poll(lambda: not any(process_running(p) for p in children), 10, f"the viewer's children {sorted(children)} gone")
        assert not port_in_use(web) and not port_in_use(grpc)
        check_ports_free([web, grpc])
        for port in (web, grpc):  # and they can really be bound and listened on again
            with socket.socket() as s:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind(("127.0.0.1", port))
                s.listen()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        for pid in children | descendants(proc.pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.stderr.close()


def test_run_with_viewer_serve_refuses_a_taken_web_port_before_starting_anything(tmp_path):
    """`zentrack run --viewer-serve` checks the viewer's default ports first: one line, exit 2, no cluster."""
    squatter = socket.socket()
    try:
        squatter.bind(("127.0.0.1", 9090))
        squatter.listen()
    except OSError:
        pass  # something else holds 9090 already: the run must refuse all the same
    try:
        out = tmp_path / "run"
        proc = subprocess.run([sys.executable, "-m", "zentrack", "run", "--viewer-serve", "--nodes", "2", "--steps",
                               "20", "--out", str(out)], capture_output=True, text=True, timeout=60)
    finally:
        squatter.close()
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "port 9090 on 127.0.0.1 is already in use" in lines[0], lines
    assert "--web-port" not in lines[0], lines  # zentrack run has no port flag to suggest
    assert not (out / "logs").exists(), "nothing was started"


def test_a_run_with_viewer_serve_prints_the_recording_and_the_address_and_leaves_no_server(tmp_path):
    """`zentrack run --viewer-serve`: stdout names the recording, how to open it and the live address (before
    the run ends, not only in logs/viewer.log), and once the run has stopped nothing listens on the ports."""
    from zentrack.viewer.hints import rerun_command, web_url
    from zentrack.viewer.ports import GRPC_PORT, WEB_PORT

    check_ports_free()  # the test needs the default ports: one line naming the one held, if any
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "run", "--viewer-serve", "--nodes", "2", "--steps", "20",
                           "--timing", "lockstep", "--out", str(out)], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rrd = out / "recording.rrd"
    url = web_url("127.0.0.1", WEB_PORT, GRPC_PORT)
    assert rrd.is_file() and f"`{rerun_command()} {rrd}`" in proc.stdout, proc.stdout
    assert url in proc.stdout and proc.stdout.index(url) < proc.stdout.index("run OK"), proc.stdout
    poll(lambda: not port_in_use(WEB_PORT) and not port_in_use(GRPC_PORT), 15, "the viewer's ports free after the run")
