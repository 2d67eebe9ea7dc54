"""The host's CPU shared between xdist workers: timing-sensitive tests side by side, host-loading tests alone.

Most slow tests run real-time clusters that need little CPU and run side by side. A few load the host on
purpose or by their nature (CPU hogs, message floods, an image build); next to them the real-time tests would
measure the load, not zentrack. So every slow test takes the host **shared**, at most ``SLOTS`` at once, and a
host-loading one takes it **exclusive** (``flock`` on files every worker of the suite opens: a slot each, and a
turnstile): an exclusive holder waits for the shared holders running to finish and runs alone among them, and
while it waits no new shared holder starts (the turnstile), so it is not starved. Fast unit tests take nothing: they are not timing
sensitive, and xdist's workers share one scheduler autogroup, while every cluster process has one of its own.
"""
from __future__ import annotations

import fcntl
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path


def _folder() -> Path:
    folder = Path(tempfile.gettempdir()) / f"zentrack-tests-{os.environ.get('ZENTRACK_TEST_RUN', os.getpid())}"
    folder.mkdir(exist_ok=True)
    return folder


def _take(name: str, how: int) -> int:
    fd = os.open(_folder() / name, os.O_CREAT | os.O_RDWR, 0o600)
    fcntl.flock(fd, how)
    return fd


#: how many shared holders run at once. A real-time test's cluster averages 0.4-0.7 of a core alone (the partition,
#: secure-sensor and soak tests, measured), but its start-up and restarts are bursts of many interpreters importing
#: at once: three side by side failed one to three real-time judgements in most suites (runs 42-48 and two CI runs
#: of docs/testing.md: three whole passes of nine), nearly always a burst of one (a soak's restarts, a docs page's
#: 20 processes) landing on another's fault window; four saturated two cores outright
SLOTS = 2
#: the slot kept for the tests on the suite's critical path (the namespace group, then the Docker test: the
#: longest chain of tests that must run one after another; conftest.CRITICAL_PATH): they never queue behind
#: other slow tests, only behind an exclusive holder. The others take the remaining slots, and this one too once
#: the critical path has ended
RESERVED = 0


@contextmanager
def shared(reserved: bool = False, reserved_free: Callable[[], bool] = lambda: False) -> Iterator[None]:
    """Run beside at most ``SLOTS - 1`` other shared holders, never beside an exclusive one: in the reserved slot
    when ``reserved``, otherwise in another (or the reserved one once ``reserved_free()`` says it is)."""
    others = [n for n in range(SLOTS) if n != RESERVED]
    while True:
        if _exclusive_asked():  # one waits or runs: it goes first, and those waiting behind it too
            time.sleep(0.1)
            continue
        # the turnstile is held by an exclusive holder waiting or running, and by a shared one only while it
        # tries the slots once (a holder waiting for another slot does not block the reserved one)
        turnstile = _take("turnstile", fcntl.LOCK_EX)
        try:
            slot = _try_slots([RESERVED] if reserved else others + [RESERVED] if reserved_free() else others)
        finally:
            os.close(turnstile)
        if slot is not None:
            break
        time.sleep(0.1)
    try:
        yield
    finally:
        os.close(slot)


def _try_slots(slots: list[int]) -> int | None:
    for n in slots:
        fd = os.open(_folder() / f"slot-{n}", os.O_CREAT | os.O_RDWR, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            os.close(fd)
    return None


def _exclusive_asked() -> bool:
    """Whether an exclusive holder waits or runs (each holds the ``asked`` file shared from its ask to its end)."""
    fd = os.open(_folder() / "asked", os.O_CREAT | os.O_RDWR, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


@contextmanager
def exclusive() -> Iterator[None]:
    """Run alone among the holders of the host (fast unit tests may still run on other workers). From its ask to
    its end no new shared holder starts, so exclusive holders asking one after another run one after another,
    the host emptied of shared holders once: at the hand-over from one to the next, a shared holder polling
    for a slot would otherwise win the turnstile, and the next would wait for that test to end."""
    asked = _take("asked", fcntl.LOCK_SH)
    try:
        turnstile = _take("turnstile", fcntl.LOCK_EX)
        try:
            slots = [_take(f"slot-{n}", fcntl.LOCK_EX) for n in range(SLOTS)]
            try:
                yield
            finally:
                for fd in slots:
                    os.close(fd)
        finally:
            os.close(turnstile)
    finally:
        os.close(asked)


@contextmanager
def nothing() -> Iterator[None]:
    yield


def note_done(group: str) -> None:
    """Count one finished test of ``group`` (every worker appends to one file)."""
    with open(_folder() / f"done-{group}", "a") as f:
        f.write("1\n")


def done(group: str) -> int:
    """How many tests of ``group`` have finished."""
    try:
        return len((_folder() / f"done-{group}").read_text().splitlines())
    except OSError:
        return 0


def remove() -> None:
    """Remove the lock files (by the suite's own process, once every worker has ended)."""
    shutil.rmtree(_folder(), ignore_errors=True)
