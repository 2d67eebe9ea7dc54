"""Deployment pieces: the compose file is the generator's output, status/health read liveliness tokens."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from zentrack.compose import render
from zentrack.orchestrator import free_port
from zentrack.zsession import loopback_config

ROOT = Path(__file__).resolve().parent.parent


def test_checked_in_compose_file_is_the_generator_output():
    assert (ROOT / "deploy" / "docker-compose.yml").read_text() == render(10)


def test_compose_wires_every_service_through_the_router():
    text = render(4)
    for name in ("router:", "truth:", "node-0:", "node-3:", "viewer:", "recordings:"):
        assert f"\n  {name}" in text or f"\n{name}" in text
    assert text.count('"--connect", "tcp/router:7447"') == 6  # truth, 4 nodes, viewer
    assert text.count('"--nodes", "4"') == 6
    assert "node-4:" not in text


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "zentrack", *args], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **(env or {})})


def test_status_and_health_follow_liveliness_tokens():
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with zenoh.open(loopback_config("peer", listen=[endpoint])) as session:
        token = session.liveliness().declare_token("zentrack/deploytest/alive/3")
        truth = session.liveliness().declare_token("zentrack/deploytest/alive/truth")
        try:
            out = run_cli("status", "--run", "deploytest", "--connect", endpoint, "--json")
            assert out.returncode == 0, out.stderr
            assert json.loads(out.stdout) == {"run": "deploytest", "nodes": [3], "processes": ["truth"]}
            ok = run_cli("health", env={"ZENTRACK_RUN": "deploytest", "ZENTRACK_NAME": "3", "ZENTRACK_CONNECT": endpoint})
            assert ok.returncode == 0, ok.stderr
            token.undeclare()
            time.sleep(0.3)
            gone = run_cli("health", "--name", "3", "--run", "deploytest", "--connect", endpoint)
            assert gone.returncode == 1 and "no liveliness token" in gone.stderr
        finally:
            truth.undeclare()


def test_health_needs_a_name():
    out = run_cli("health", env={"ZENTRACK_NAME": ""})
    assert out.returncode == 2 and "--name" in out.stderr


@pytest.mark.parametrize("path", ["Dockerfile"])
def test_dockerfile_runs_as_non_root_with_a_healthcheck(path):
    text = (ROOT / path).read_text()
    assert "USER zentrack" in text and 'HEALTHCHECK' in text and '"zentrack", "health"' in text
    assert text.startswith("# zentrack image") and "FROM python:3.11-slim" in text
