"""Zenoh's receive runtime gets enough threads that links closing on a dead path cannot stall it
(zentrack/transport/zruntime.py; the partition it fixes is measured in tests/test_partition.py)."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from zentrack.transport import zruntime


def test_the_default_is_set_when_the_user_set_none(monkeypatch):
    monkeypatch.delenv("ZENOH_RUNTIME", raising=False)
    assert zruntime.ensure_runtime_threads() == f"(rx: (worker_threads: {zruntime.RX_WORKER_THREADS}))"
    assert os.environ["ZENOH_RUNTIME"] == zruntime.runtime_setting()


def test_a_setting_of_the_users_own_is_left_alone(monkeypatch):
    monkeypatch.setenv("ZENOH_RUNTIME", "(rx: (worker_threads: 3))")
    assert zruntime.ensure_runtime_threads() == "(rx: (worker_threads: 3))"
    assert os.environ["ZENOH_RUNTIME"] == "(rx: (worker_threads: 3))"


def test_fewer_than_one_thread_is_refused():
    with pytest.raises(ValueError, match="rx_workers must be at least 1"):
        zruntime.runtime_setting(0)


@pytest.mark.slow
def test_a_session_opened_by_zentrack_runs_that_many_receive_threads():
    """Two linked sessions in a fresh process: Zenoh's receive runtime (threads named rx-N) has at least
    RX_WORKER_THREADS threads, i.e. Zenoh read the setting (its default is 2)."""
    code = textwrap.dedent("""
        import socket, time
        from pathlib import Path
        from zentrack.transport.zsession import loopback_config, open_zenoh, open_retrying
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
        a = open_zenoh(loopback_config("peer", listen=[endpoint]), "a")
        b = open_retrying(loopback_config("peer", connect=[endpoint]), 10.0)
        end = time.time() + 10
        names = []
        while time.time() < end:
            names = [(t / "comm").read_text().strip() for t in Path("/proc/self/task").iterdir()]
            if sum(n.startswith("rx-") for n in names) >= WANT:
                break
            time.sleep(0.05)
        print(sum(n.startswith("rx-") for n in names))
        b.close(); a.close()
    """).replace("WANT", str(zruntime.RX_WORKER_THREADS))
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.split()[-1]) >= zruntime.RX_WORKER_THREADS, out.stdout
