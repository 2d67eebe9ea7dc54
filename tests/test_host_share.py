"""The suite's own sharing of the host between xdist workers (tests/host_share.py): the critical path's reserved
slot is never taken by another slow test while that path runs, and an exclusive holder runs alone."""
from __future__ import annotations

import fcntl
import json
import os
import threading
import time
import uuid
from pathlib import Path

import host_share
import pytest


@pytest.fixture(autouse=True)
def own_lock_folder(monkeypatch):
    monkeypatch.setenv("ZENTRACK_TEST_RUN", f"host-share-test-{uuid.uuid4().hex}")
    yield
    host_share.remove()


def _enter_in_thread(make) -> tuple[threading.Event, threading.Event, threading.Thread]:
    entered, leave = threading.Event(), threading.Event()

    def hold():
        with make():
            entered.set()
            leave.wait(10)

    thread = threading.Thread(target=hold, daemon=True)
    thread.start()
    return entered, leave, thread


def _until_held(name: str, timeout: float = 5.0) -> None:
    end = time.monotonic() + timeout
    while True:
        fd = os.open(host_share._folder() / name, os.O_CREAT | os.O_RDWR, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return
        finally:
            os.close(fd)
        assert time.monotonic() < end, f"nobody took {name} within {timeout} s"
        time.sleep(0.01)


def test_the_reserved_slot_is_kept_for_the_critical_path_until_it_has_ended():
    path_done = threading.Event()
    holders = [_enter_in_thread(lambda: host_share.shared(reserved_free=path_done.is_set)) for _ in range(2)]
    assert all(entered.wait(5) for entered, _, _ in holders)
    waiting = _enter_in_thread(lambda: host_share.shared(reserved_free=path_done.is_set))
    assert not waiting[0].wait(0.5), "a third test took a slot while two ran and the critical path had not ended"
    critical = _enter_in_thread(lambda: host_share.shared(reserved=True))
    assert critical[0].wait(5), "the critical path's test queued behind the other slow tests"
    critical[1].set()
    critical[2].join(5)
    assert not waiting[0].wait(0.5), "the reserved slot went to another test before the critical path ended"
    path_done.set()
    assert waiting[0].wait(5), "the reserved slot stayed empty after the critical path ended"
    for _, leave, thread in [*holders, waiting]:
        leave.set()
        thread.join(5)


def test_an_exclusive_holder_waits_for_the_shared_ones_and_runs_alone():
    shared = _enter_in_thread(lambda: host_share.shared(reserved=True))
    assert shared[0].wait(5)
    exclusive = _enter_in_thread(host_share.exclusive)
    assert not exclusive[0].wait(0.5), "the exclusive holder ran beside a shared one"
    _until_held("turnstile")  # (the exclusive holder takes it first, then waits for the slot)
    late = _enter_in_thread(lambda: host_share.shared(reserved_free=lambda: True))
    shared[1].set()
    assert exclusive[0].wait(5), "the exclusive holder did not start when the shared one ended"
    assert not late[0].wait(0.5), "a shared holder started beside the exclusive one"
    exclusive[1].set()
    assert late[0].wait(5)
    late[1].set()
    for _, _, thread in (shared, exclusive, late):
        thread.join(5)


def test_a_shared_holder_waits_until_the_host_loading_tests_have_ended():
    loading_done = threading.Event()
    waiting = _enter_in_thread(lambda: host_share.shared(reserved=True, after=loading_done.is_set))
    assert not waiting[0].wait(0.5), "a shared holder started before the host-loading tests had ended"
    loading_done.set()
    assert waiting[0].wait(5), "the shared holder did not start once the host-loading tests had ended"
    waiting[1].set()
    waiting[2].join(5)


def test_the_host_loading_tests_are_one_group_collected_first_and_a_stray_one_is_refused():
    import subprocess
    import sys
    from types import SimpleNamespace

    import conftest

    modules = ["tests/test_multihost.py", "tests/test_soak_loaded.py", "tests/test_host_share.py"]
    listed = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *modules],
                            capture_output=True, text=True, cwd=Path(conftest.__file__).parents[1], timeout=120)
    ids = [line for line in listed.stdout.splitlines() if "::" in line]
    groups = [conftest.group_of(nodeid) for nodeid in ids]
    first = groups.count(conftest.LOADS_HOST_GROUP)
    assert first and groups[:first] == [conftest.LOADS_HOST_GROUP] * first, groups
    assert groups[first] == conftest.NETNS_GROUP, "the namespace group comes right after the host-loading one"

    def item(nodeid, marked):
        return SimpleNamespace(nodeid=nodeid, get_closest_marker=lambda name: object() if marked and name == "loads_host" else None)
    assert conftest.loads_host_strays([item("tests/test_attacks.py::test_a", True), item("tests/test_x.py::test_b", False),
                                       item("tests/test_x.py::test_c", True)]) == ["tests/test_x.py::test_c"]


def test_the_timeline_tool_reports_each_groups_span_run_and_wait(tmp_path, capsys):
    import timeline

    rows = [{"test": "tests/test_a.py::t1", "group": "netns", "asked": 100.0, "started": 100.0, "ended": 130.0, "worker": "gw0"},
            {"test": "tests/test_b.py::t2", "group": "test_b.py", "asked": 101.0, "started": 131.0, "ended": 141.0, "worker": "gw1"}]
    path = tmp_path / "timeline.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert timeline.main([str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "2 tests, 41 s from the first to the last"
    assert lines[2].split() == ["test_b.py", "1", "1", "41", "10", "30", "gw1"]  # the longest span first
    assert lines[3].split() == ["netns", "1", "0", "30", "30", "0", "gw0"]
    (tmp_path / "bad.jsonl").write_text("{not json\n")
    assert timeline.main([str(tmp_path / "bad.jsonl")]) == 2
    assert "timeline: cannot read" in capsys.readouterr().err



def test_a_unit_test_runs_in_the_background_and_its_worker_gets_its_priority_back():
    import subprocess
    import sys

    if os.geteuid() != 0:  # (only root can raise a priority back: background() leaves it alone then)
        before = os.getpriority(os.PRIO_PROCESS, 0)
        with host_share.background():
            assert os.getpriority(os.PRIO_PROCESS, 0) == before
        return
    own = os.getpriority(os.PRIO_PROCESS, 0)  # (this test itself runs in the background: nice 10)
    os.setpriority(os.PRIO_PROCESS, 0, 0)
    try:
        with host_share.background():
            assert os.getpriority(os.PRIO_PROCESS, 0) == host_share.BACKGROUND_NICE
            child = subprocess.run([sys.executable, "-c", "import os; print(os.getpriority(os.PRIO_PROCESS, 0))"],
                                   capture_output=True, text=True, timeout=30)
            assert int(child.stdout) == host_share.BACKGROUND_NICE, "what a unit test starts runs in the background too"
        assert os.getpriority(os.PRIO_PROCESS, 0) == 0, "the worker's priority is back after the test"
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, own)
