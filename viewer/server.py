"""The Rerun web server of ``zentrack viewer --serve``: the real ``rerun`` binary as a child in its own process
group, so stopping it (or this process dying) leaves nothing serving on its ports."""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from zentrack.common.procs import StopFlag, die_with_parent


def rerun_binary() -> str:
    """The real ``rerun`` executable shipped by rerun-sdk (``rerun_cli/rerun``), not the ``rerun`` console
    script, which is a Python wrapper that runs the binary as a child: stopping the wrapper would leave the
    server running and holding its ports."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).with_name("rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    return shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))


def start_web_server(args: argparse.Namespace, recordings: tuple[str, ...] = ()) -> subprocess.Popen:
    """A ``rerun --serve-web`` child: gRPC server + web viewer bound to ``--bind`` (with ``recordings``, saved
    ``.rrd`` files, loaded), in its own process group (:func:`stop_web_server` stops the whole group) and sent
    SIGTERM by the kernel if this process dies."""
    return subprocess.Popen([rerun_binary(), "--serve-web", "--bind", args.bind, "--port", str(args.grpc_port),
                             "--web-viewer-port", str(args.web_port), "--server-memory-limit", "512MiB",
                             *recordings],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, preexec_fn=die_with_parent)


def wait_listening(server: subprocess.Popen, host: str, ports: list[int], timeout: float = 15.0,
                   stop: StopFlag | None = None) -> None:
    """Poll until the server accepts connections on every port (or ``stop`` is set); ValueError if it exits or
    takes too long."""
    host = "127.0.0.1" if host in ("0.0.0.0", "") else ("::1" if host == "::" else host)
    end = time.monotonic() + timeout
    pending = list(ports)
    while pending and not stop:
        if server.poll() is not None:
            raise ValueError(f"the Rerun web server (rerun --serve-web) exited with status {server.returncode} "
                             f"before listening on {host}:{pending[0]}")
        try:
            with socket.create_connection((host, pending[0]), timeout=0.5):
                pending.pop(0)
            continue
        except OSError:
            pass
        if time.monotonic() > end:
            raise ValueError(f"the Rerun web server is not listening on {host}:{pending[0]} after {timeout:.0f} s")
        time.sleep(0.05)


def stop_web_server(server: subprocess.Popen, grace: float = 5.0) -> None:
    """SIGTERM the server's whole process group, SIGKILL it after ``grace`` seconds, and reap the server."""
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(server.pid, sig)
        except ProcessLookupError:
            pass
        try:
            server.wait(timeout=wait)
            break
        except subprocess.TimeoutExpired:
            continue
    try:  # anything else the server started in its group
        os.killpg(server.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
