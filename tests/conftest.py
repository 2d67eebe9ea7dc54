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

import collections
import contextlib
import json
import os
import signal
import time
from pathlib import Path

import host_share
import leftovers
import numpy as np
import pytest

from zentrack.config.scenario_config import builtin_spec
from zentrack.truth.simulation.simulate import simulate

#: modules whose every test starts a cluster or runs for minutes
SLOW_MODULES = {"test_runtime.py"}
#: an unmarked test slower than this is reported at the end of the run
FAST_TEST_BUDGET_S = 5.0


#: Side by side (.ci/run: ``pytest -n 4 --dist loadgroup``): every test belongs to a group, and a group's tests
#: run one after another on one worker (the scheduler below). A module is its own group (its module-scoped
#: fixtures are made once), except the modules (or single tests, ``module::test``) listed here, which share a group:
GROUPS = {
    # network namespaces: the harness's subnet and bridges, namespace names (``zt<tag>-...``)
    **dict.fromkeys(["test_netns.py", "test_netns_guard.py", "test_netns_impair.py", "test_partition.py",
                     "test_multihost.py", "test_capacity.py", "test_soak.py"], "netns"),
    "test_soak.py::test_short_secure_soak": "secure-soak",  # (on loopback: apart from the other soak's namespaces)
    # the Docker engine, the swarm and its namespace workers (``ztsw...``); the companions are quick and keep
    # xdist from queueing a second group behind the long Docker test on its worker (a worker is handed more
    # work when it has at most two tests left)
    **dict.fromkeys(["test_docker.py", "test_stack.py", "test_swarm_drain.py"], "docker"),
    # the viewer's default web and gRPC ports (9090, 9876)
    "test_viewer_hygiene.py": "viewer-ports",
    "test_docs_examples.py::test_a_docs_page_serving_the_viewer_runs_as_written": "viewer-ports",
    # a restarted sensor's first detections, counted to the last: beside the sensor soak (two clusters of six
    # trackers and six sensors) its node refused 21 as too old (run 58 of docs/testing.md, the one run of six in
    # which they overlapped); one after the other on one worker
    "test_sensors_live.py::test_a_sensor_restarted_mid_run_resumes_at_the_current_time": "test_soak_sensors.py",
}
NETNS_GROUP = "netns"
#: the longest chain of tests that must run one after another (the Docker test waits for the namespace group,
#: tests/test_docker.py): its tests hold the host's reserved slot (tests/host_share.py), so that they never queue
#: behind other slow tests and the suite's wall time is not that chain's length plus its waits
CRITICAL_PATH = (NETNS_GROUP, "docker")

#: seconds each long group took run alone, one test after another (2 cores): groups start longest first, so that
#: no long group starts last (only the order matters; a group not listed is short and starts after these)
GROUP_SECONDS = {"docker": 560, "netns": 448, "test_attacks.py": 190, "test_stalls.py": 152, "secure-soak": 130,
                 "test_soak_loaded.py": 92, "test_bench_scale.py": 74, "test_multitarget_live.py": 65,
                 "test_runtime.py": 61, "test_clock_skew.py": 56, "test_sensors_live.py": 49, "test_layers.py": 46,
                 "test_contracts.py": 44,
                 "test_viewer.py": 40, "test_soak_sensors.py": 164, "test_sensors_hostile.py": 33,
                 "test_third_party_sensor.py": 25, "test_viewer_detections.py": 15, "test_secure_sensors_live.py": 35,
                 "test_multitarget_async_live.py": 55, "test_sensor_faults.py": 80, "test_tracker_clocks.py": 45,
                 "test_docs_examples.py": 285, "test_router_restart.py": 29}


def group_of(nodeid: str) -> str:
    """The group of the test ``nodeid`` (``tests/test_x.py::test_y[param]``; a parameter may hold a slash)."""
    path, _, rest = nodeid.partition("::")
    module = path.rsplit("/", 1)[-1]
    return GROUPS.get(f"{module}::{rest.split('[', 1)[0]}", GROUPS.get(module, module))


def pytest_xdist_make_scheduler(config, log):
    """xdist's scope scheduling with this suite's groups as the scopes (its own ``loadgroup`` reads groups from
    the test ids, which pytest 9.2 no longer lets a plugin change)."""
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return group_of(nodeid)

    return GroupScheduling(config, log)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
    first: dict[str, int] = {}
    slow_groups = set()
    for n, item in enumerate(items):
        first.setdefault(group_of(item.nodeid), n)
        if item.get_closest_marker("slow") is not None and item.get_closest_marker("cpu_only") is None:
            slow_groups.add(group_of(item.nodeid))  # (a group of cpu_only tests starts with the unit tests)

    def order(item) -> tuple:
        """The namespace group first and the Docker group next (the longest two; the Docker test waits for the
        namespace tests to end, tests/test_docker.py), then the groups of fast unit tests (they need no slot),
        then the other slow groups by measured length; a group's tests keep their order. Every worker collects
        the same order, and the scheduler hands out the groups in it."""
        group = group_of(item.nodeid)
        rank = {NETNS_GROUP: 0, "docker": 1}.get(group, 3 if group in slow_groups else 2)
        return rank, -GROUP_SECONDS.get(group, 0.0), first[group]

    items.sort(key=order)


def host_share_of(item):
    """How a test holds the host's CPU (tests/host_share.py): exclusive when it loads the host on purpose or by
    its nature (``loads_host``), shared when it is slow, nothing when it is a fast unit test or a slow one that
    starts no real-time process (``cpu_only``: its work, like a unit test's, runs in the workers' autogroup). The
    Docker test takes it itself (tests/test_docker.py: exclusive once the namespace tests have ended). A test
    marked ``alone`` (a fault judged to the step at one moment) takes it exclusive in its group's turn, without
    waiting for the namespace group: it may be one of them."""
    if item.get_closest_marker("loads_host") is not None:
        return exclusive_after_the_namespace_tests(item.session)
    if item.get_closest_marker("alone") is not None:
        return host_share.exclusive()
    if (item.get_closest_marker("slow") is not None and item.get_closest_marker("cpu_only") is None
            and group_of(item.nodeid) != "docker"):
        return host_share.shared(reserved=group_of(item.nodeid) in CRITICAL_PATH,
                                 reserved_free=lambda: critical_path_done(item.session))
    return host_share.nothing()


@contextlib.contextmanager
def exclusive_after_the_namespace_tests(session):
    """The host exclusive, asked once the namespace group of this session has ended (up to 1800 s), as the
    Docker test asks it: the host-loading tests and the Docker test then run one after another, the host emptied
    of shared holders once (tests/host_share.py), and the namespace group, the start of the suite's critical
    path, never waits for them. Spread over the suite, each emptied the host on its own: the namespace group
    waited 186 s of its 641 for them in run 20 of docs/testing.md."""
    namespace_tests_ended(session, 1800.0)  # (past the limit it asks anyway: the exclusive hold still protects)
    with host_share.exclusive():
        yield


def namespace_tests_ended(session, timeout: float) -> bool:
    """Wait (polling, up to ``timeout`` s) until every test of the namespace group in ``session`` has finished on
    whichever worker; whether they did."""
    netns_tests = sum(group_of(item.nodeid) == NETNS_GROUP for item in session.items)
    end = time.monotonic() + timeout
    while host_share.done(NETNS_GROUP) < netns_tests:
        if time.monotonic() > end:
            return False
        time.sleep(1.0)
    return True


def critical_path_done(session) -> bool:
    """Whether every test of the critical path's groups in this session has finished (on whichever worker)."""
    if not _critical_sizes:
        sizes = collections.Counter(group_of(item.nodeid) for item in session.items)
        _critical_sizes.update({group: sizes[group] for group in CRITICAL_PATH})
    return all(host_share.done(group) >= n for group, n in _critical_sizes.items())


_critical_sizes: dict[str, int] = {}


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    """The host held around the whole test: set-up (a module's reference cluster included), call and teardown.
    Outermost, so the per-test time limit counts the test, not its wait for the host (each holder has a limit)."""
    asked = time.time()
    with host_share_of(item):
        started = time.time()
        yield
    host_share.note_done(group_of(item.nodeid))
    if os.environ.get("ZENTRACK_TEST_TIMELINE"):  # where each test ran and waited: a JSON line per test
        with open(os.environ["ZENTRACK_TEST_TIMELINE"], "a") as f:
            f.write(json.dumps({"test": item.nodeid, "group": group_of(item.nodeid), "asked": asked,
                                "started": started, "ended": time.time(),
                                "worker": os.environ.get("PYTEST_XDIST_WORKER", "-")}) + "\n")


_slow_unmarked: list[tuple[str, float]] = []


def pytest_runtest_logreport(report):
    if report.when == "call" and report.duration > FAST_TEST_BUDGET_S and "slow" not in report.keywords:
        _slow_unmarked.append((report.nodeid, report.duration))


def pytest_terminal_summary(terminalreporter):
    if _slow_unmarked:
        terminalreporter.section("unmarked tests slower than the fast-suite budget")
        for nodeid, seconds in sorted(_slow_unmarked, key=lambda t: -t[1]):
            terminalreporter.write_line(f"{seconds:6.1f} s  {nodeid}  (mark it @pytest.mark.slow?)")


#: A suite started in the background by a non-interactive shell (``bash .ci/run &``, a CI job's step) inherits
#: SIGINT and SIGQUIT ignored (POSIX: an asynchronous command without job control), and every process a test
#: starts would inherit that too: a ``zentrack run`` that a test sends Ctrl-C ignores it, as it should under
#: ``nohup``. The tests start their processes as a terminal's foreground job has them: default dispositions.
#: (Before, whether the Ctrl-C tests passed hung on whether their worker had run an in-process test that set
#: a SIGINT handler first.)
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
if signal.getsignal(signal.SIGQUIT) == signal.SIG_IGN:
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)

#: every process this pytest process starts inherits ZENTRACK_TEST_SESSION (this worker's pid), and every process
#: of the suite ZENTRACK_TEST_RUN (the pid of the pytest the suite was started with): see tests/leftovers.py
SESSION_MARK = f"ZENTRACK_TEST_SESSION={os.getpid()}"
os.environ["ZENTRACK_TEST_SESSION"] = str(os.getpid())
os.environ.setdefault("ZENTRACK_TEST_RUN", str(os.getpid()))  # set by the first: xdist's workers inherit it
RUN_MARK = f"ZENTRACK_TEST_RUN={os.environ['ZENTRACK_TEST_RUN']}"
#: namespaces of the Docker test's swarm workers: the Docker group runs beside the namespace group and checks
#: its own (tests/test_docker.py), so the namespace tests' check leaves them out
SWARM_WORKER_PREFIX = "ztsw"


def _our_processes() -> dict[int, str]:
    return leftovers.marked_processes(SESSION_MARK, ancestor=os.getpid())


def _our_namespaces_and_bridges() -> set[str]:
    return {n for n in leftovers.namespaces_and_bridges() if not n.startswith(SWARM_WORKER_PREFIX)}


def _signal_mask_and_ignored() -> dict[str, str]:
    """This thread's blocked signals and this process's ignored ones (``/proc``): a child started from here
    inherits both across exec, so a SIGINT or SIGTERM left blocked or ignored makes its processes deaf to them."""
    status = Path("/proc/thread-self/status").read_text().splitlines()
    return {line.split(":")[0]: line.split(":")[1].strip() for line in status if line.startswith(("SigBlk", "SigIgn"))}


@pytest.fixture(autouse=True)
def signals_left_as_found():
    """Every test leaves the worker's blocked and ignored signals as it found them (the processes later tests
    start inherit them)."""
    before = _signal_mask_and_ignored()
    yield
    after = _signal_mask_and_ignored()
    assert after == before, f"the test changed the worker's blocked or ignored signals: {before} -> {after}"


@pytest.fixture(autouse=True)
def nothing_left_behind(request):
    """After every slow test: no process it started is left, and after a test of the namespace group no
    namespace or bridge (waits up to 15 s for them to go; what remains is killed so that later tests start clean,
    and the test fails naming it)."""
    if request.node.get_closest_marker("slow") is None:
        yield
        return
    uses_netns = group_of(request.node.nodeid) == NETNS_GROUP
    before = set(_our_processes())
    nets_before = _our_namespaces_and_bridges() if uses_netns else set()
    yield
    left = leftovers.wait_gone(lambda: {p: c for p, c in _our_processes().items() if p not in before}, 15.0)
    nets = leftovers.wait_gone(lambda: _our_namespaces_and_bridges() - nets_before, 15.0) if uses_netns else set()
    leftovers.kill(left)
    assert not left, f"processes left running after the test: {sorted(left.values())}"
    assert not nets, f"namespaces or bridges left after the test: {sorted(nets)}"


_at_start: dict[str, set] = {}


def pytest_sessionstart(session):
    if not hasattr(session.config, "workerinput"):  # the suite's own process (xdist's controller, or plain pytest)
        _at_start.update(nets=leftovers.namespaces_and_bridges(), ports=leftovers.listening_ports(),
                         dockerd=set(leftovers.marked_processes(None, watched=("dockerd",))))


def pytest_sessionfinish(session, exitstatus):
    """After the whole suite: nothing any test started on any worker is left (a process of the suite, dockerd
    included; a namespace or bridge; a listening port that was free at the start). What is found is named in
    one line each (processes are killed) and fails the run."""
    if hasattr(session.config, "workerinput") or not _at_start:
        return
    host_share.remove()
    procs = leftovers.wait_gone(lambda: leftovers.marked_processes(RUN_MARK, watched=None), 15.0)
    dockerd = set(leftovers.marked_processes(None, watched=("dockerd",))) - _at_start["dockerd"]
    nets = leftovers.wait_gone(lambda: leftovers.namespaces_and_bridges() - _at_start["nets"], 5.0)
    ports = leftovers.wait_gone(lambda: leftovers.listening_ports() - _at_start["ports"], 5.0)
    problems = [f"process left running after the suite: {cmd}" for cmd in sorted(procs.values())]
    problems += [f"dockerd started during the suite still runs (pid {pid})" for pid in sorted(dockerd - set(procs))]
    problems += [f"namespace or bridge left after the suite: {name}" for name in sorted(nets)]
    problems += [f"port {port} listened on after the suite (free at its start)" for port in sorted(ports)]
    leftovers.kill(procs)  # (namespaces and ports are only named: unlike processes, they carry no mark of this
    # suite, and another suite or harness on the host may own them)
    if problems:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter.section("left behind by the suite")
            for line in problems:
                reporter.write_line(line)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture(scope="session")
def exp2_small():
    """Experiment 2 (bearing), 6 nodes, 120 steps, 3 runs."""
    return simulate(builtin_spec("exp2", nodes=6, steps=120), runs=3, seed=11)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
