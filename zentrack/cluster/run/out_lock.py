"""One live run per output folder: ``<out>/.lock``, held with ``fcntl.flock`` for the life of the run.

Two runs into the same ``--out`` would mix their logs and lose one summary. The first run takes an exclusive
lock on ``<out>/.lock`` and writes its pid and run name there; a second one finds the lock taken and is refused
with one line naming the first (:class:`OutInUse`, a ``ValueError``: ``zentrack`` prints it and exits 2)
before it writes anything. The kernel drops the lock when the holder exits, however it exits (SIGKILL too),
so a dead run's lock file never blocks the next run.
"""
from __future__ import annotations

import fcntl
import os
from pathlib import Path

LOCK_NAME = ".lock"


class OutInUse(ValueError):
    """Another live run holds the output folder's lock."""


def holder(path: Path) -> str:
    """Who holds the lock at ``path``, as its holder wrote it (``pid 1234, run r1234x5``), or "another run"."""
    try:
        words = path.read_text().split()
    except OSError:
        return "another run"
    if len(words) >= 2 and words[0].isdigit():
        return f"pid {words[0]}, run {words[1]}"
    return "another run"


def claim_out(out: Path, run_name: str) -> int:
    """Take ``<out>/.lock`` for this process (creating ``out``); returns the descriptor to keep open for the
    run's life (:func:`release_out`). :class:`OutInUse` when another live run holds it: nothing else in
    ``out`` is touched."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)  # no O_TRUNC: the holder's line stays
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise OutInUse(f"--out {out} is in use by another live run ({holder(path)}); wait for it to finish, "
                       "stop it, or choose another --out") from None
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()} {run_name}\n".encode())
    return fd


def release_out(fd: int) -> None:
    """Let go of a lock taken by :func:`claim_out` (the file stays; an unlocked file blocks no one)."""
    try:
        fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
