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

import numpy as np
import pytest

from zentrack.fusion.scenario import builtin_spec, simulate

#: modules whose every test starts a cluster or runs for minutes
SLOW_MODULES = {"test_runtime.py"}
#: an unmarked test slower than this is reported at the end of the run
FAST_TEST_BUDGET_S = 5.0


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)


_slow_unmarked: list[tuple[str, float]] = []


def pytest_runtest_logreport(report):
    if report.when == "call" and report.duration > FAST_TEST_BUDGET_S and "slow" not in report.keywords:
        _slow_unmarked.append((report.nodeid, report.duration))


def pytest_terminal_summary(terminalreporter):
    if _slow_unmarked:
        terminalreporter.section("unmarked tests slower than the fast-suite budget")
        for nodeid, seconds in sorted(_slow_unmarked, key=lambda t: -t[1]):
            terminalreporter.write_line(f"{seconds:6.1f} s  {nodeid}  (mark it @pytest.mark.slow?)")


@pytest.fixture(scope="session")
def exp2_small():
    """Experiment 2 (bearing), 6 nodes, 120 steps, 3 runs."""
    return simulate(builtin_spec("exp2", nodes=6, steps=120), runs=3, seed=11)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
