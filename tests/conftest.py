"""Shared fixtures (small scenarios that keep the suite fast) and the fast/slow split.

The split: ``pytest -m "not slow"`` runs the fast unit tests (pure maths, codecs, parsers, in-process CLI;
under a minute on two cores); plain ``pytest`` (what .ci/run does) runs everything. A test is ``slow`` when it
starts processes (clusters, the orchestrator, zentrack subprocesses that open Zenoh sessions), Chromium or
network namespaces, or runs a long simulation. Mark such tests with ``@pytest.mark.slow`` where they are
written, or a whole module with ``pytestmark = pytest.mark.slow``. The runtime module, which only holds
such tests, is also listed in ``SLOW_MODULES`` below, so none of its tests can slip into the fast suite
unmarked. At the end of a run, every unmarked test that took longer than ``FAST_TEST_BUDGET_S`` is
listed, as a hint that it belongs in the slow set.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time

import numpy as np
import pytest

from zentrack.common.procs import process_running
from zentrack.config.scenario_config import builtin_spec
from zentrack.truth.simulation.simulate import simulate

#: modules whose every test starts a cluster or runs for minutes
SLOW_MODULES = {"test_runtime.py"}
#: an unmarked test slower than this is reported at the end of the run
FAST_TEST_BUDGET_S = 5.0


#: modules that run last: building a container image writes and evicts gigabytes, which stalls the page cache
#: and the disk of a small machine for minutes, and realtime tests after it would measure that, not zentrack
LAST_MODULES = {"test_docker.py"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
    items.sort(key=lambda item: item.path.name in LAST_MODULES)  # stable: the rest keep their order


_slow_unmarked: list[tuple[str, float]] = []


def pytest_runtest_logreport(report):
    if report.when == "call" and report.duration > FAST_TEST_BUDGET_S and "slow" not in report.keywords:
        _slow_unmarked.append((report.nodeid, report.duration))


def pytest_terminal_summary(terminalreporter):
    if _slow_unmarked:
        terminalreporter.section("unmarked tests slower than the fast-suite budget")
        for nodeid, seconds in sorted(_slow_unmarked, key=lambda t: -t[1]):
            terminalreporter.write_line(f"{seconds:6.1f} s  {nodeid}  (mark it @pytest.mark.slow?)")


#: every process this test session starts inherits this variable, so leftovers are told from processes of
#: other sessions or of a cluster the developer runs meanwhile (they are never flagged, never killed)
SESSION_MARK = f"ZENTRACK_TEST_SESSION={os.getpid()}"
os.environ["ZENTRACK_TEST_SESSION"] = str(os.getpid())


def _our_processes() -> dict[int, str]:
    """pid -> command line of every zentrack, Rerun or Chromium process that this test session started (it
    carries :data:`SESSION_MARK` in its environment, or descends from this process)."""
    found = {}
    me = os.getpid()
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == me:
            continue
        try:
            cmd = open(f"/proc/{pid}/cmdline", "rb").read().replace(b"\0", b" ").decode(errors="replace")
            stat = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if stat[0] == "Z" and not process_running(int(pid)) or not ("zentrack" in cmd or "rerun" in cmd or "chromium" in cmd):
            continue
        if _marked(pid) or _descends_from(int(pid), me):
            found[int(pid)] = cmd[:160]
    return found


def _marked(pid: str) -> bool:
    try:
        return SESSION_MARK.encode() in open(f"/proc/{pid}/environ", "rb").read().split(b"\0")
    except OSError:
        return False


def _descends_from(pid: int, ancestor: int) -> bool:
    for _ in range(64):
        try:
            pid = int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            return False
        if pid == ancestor:
            return True
        if pid <= 1:
            return False
    return False


def _our_namespaces_and_bridges() -> set[str]:
    names = set()
    for argv in (["ip", "netns", "list"], ["ip", "-o", "link"]):
        try:
            out = subprocess.run(argv, capture_output=True, text=True, timeout=10).stdout
        except (OSError, subprocess.TimeoutExpired):
            continue
        names |= set(re.findall(r"\bzt[a-z0-9]*(?:br|-[a-z0-9-]+)\b", out))
    return names


@pytest.fixture(autouse=True)
def nothing_left_behind(request):
    """After every slow test: no process, namespace or bridge it started is left (waits up to 15 s for them to
    go; what remains is killed so that later tests start clean, and the test fails naming it)."""
    if request.node.get_closest_marker("slow") is None:
        yield
        return
    before, nets_before = set(_our_processes()), _our_namespaces_and_bridges()
    yield
    end = time.time() + 15
    while True:
        left = {pid: cmd for pid, cmd in _our_processes().items() if pid not in before}
        nets = _our_namespaces_and_bridges() - nets_before
        if not left and not nets or time.time() > end:
            break
        time.sleep(0.1)
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    assert not left, f"processes left running after the test: {sorted(left.values())}"
    assert not nets, f"namespaces or bridges left after the test: {sorted(nets)}"


@pytest.fixture(scope="session")
def exp2_small():
    """Experiment 2 (bearing), 6 nodes, 120 steps, 3 runs."""
    return simulate(builtin_spec("exp2", nodes=6, steps=120), runs=3, seed=11)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
