"""Atomic file writes, one implementation for every output (reports, summaries, estimates, scenario files, node
configs, certificates): the data goes to a temporary file beside the target (``<name>.tmp``, or a suffix the
writer needs, e.g. ``.tmp.npz`` for ``np.savez``), which is then renamed over the target. On any failure (a
full disk, a read-only folder) the temporary file is removed and the exception propagates: the target keeps
what it held before, and no ``*.tmp`` is left behind.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

#: exit status of a process that did its work but could not write its output (sysexits' EX_IOERR), so that
#: whoever started it can tell "could not write its report" from "failed"
EXIT_WRITE_FAILED = 74


def replace_atomically(path: str | os.PathLike, write: Callable[[Path], None], suffix: str = ".tmp") -> Path:
    """Call ``write(tmp)`` to fill a temporary file beside ``path`` (its name: ``path``'s + ``suffix``), then
    rename it over ``path``; the temporary file never outlives the call. The parent folder is made if needed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + suffix)
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_bytes_atomically(path: str | os.PathLike, data: bytes, mode: int = 0o644) -> Path:
    """Write ``data`` to ``path`` atomically; the file is created with permissions ``mode`` (0o600: private)."""

    def write(tmp: Path) -> None:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(data)

    return replace_atomically(path, write)


def write_text_atomically(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_bytes_atomically(path, text.encode())
