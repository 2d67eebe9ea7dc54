"""The suite's own sharing of the host between xdist workers (tests/host_share.py): the critical path's reserved
slot is never taken by another slow test while that path runs, and an exclusive holder runs alone."""
from __future__ import annotations

import fcntl
import json
import os
import threading
import time
import uuid

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
    holders = [_enter_in_thread(lambda: host_share.shared(reserved_free=path_done.is_set))
               for _ in range(host_share.SLOTS - 1)]
    assert all(entered.wait(5) for entered, _, _ in holders)
    waiting = _enter_in_thread(lambda: host_share.shared(reserved_free=path_done.is_set))
    assert not waiting[0].wait(0.5), "a test took the reserved slot while the others were held and the critical path ran"
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




def test_no_shared_holder_starts_while_an_exclusive_one_has_asked():
    """An exclusive holder that has asked and not yet taken the turnstile (between two exclusive holders, the
    next one) keeps new shared holders out even when every slot is free: those asking together run one after
    another, the host emptied of shared holders once (in run 20 of docs/testing.md two shared tests won the
    turnstile at such a hand-over, and the next exclusive test waited 156 s for one of them)."""
    asked = host_share._take("asked", fcntl.LOCK_SH)  # (what exclusive() holds from its ask)
    shared = _enter_in_thread(host_share.shared)
    try:
        assert not shared[0].wait(0.5), "a shared holder started while an exclusive one had asked"
    finally:
        os.close(asked)
    assert shared[0].wait(5), "the shared holder did not start once the exclusive one had ended"
    shared[1].set()
    shared[2].join(5)
