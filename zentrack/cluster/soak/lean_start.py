"""What the processes a soak starts need less of to start: a restarted tracker on a loaded host.

A restarted tracker is CPU-bound until it is ready (about 0.3 s of CPU on the 2-core machine, almost all of
it imports), and on a host whose cores are busy it gets only its share of them: its start, not its schedule,
is what a restart costs there (docs/networks.md, "Loaded hosts"). Two parts of that CPU are waste:

- **OpenBLAS's thread pool.** NumPy's OpenBLAS starts a thread per core when it loads (about 0.09 s of CPU
  per process here) for matrix products far larger than a tracker's; ``OPENBLAS_NUM_THREADS=1`` (unless the
  user set it) starts none.
- **Compiling the sources at every start.** With ``PYTHONDONTWRITEBYTECODE`` set (this machine's environment
  and the image's) and an editable install, no ``__pycache__`` is ever written beside zentrack's sources, so
  every process compiles the ~55 modules a tracker imports (about 0.08 s of CPU). They are compiled once here
  (``compileall``: up-to-date files are skipped; a source edited later is compiled again in memory, as before).

:func:`prepare` sets the first in ``os.environ`` (inherited by every process the soak's engines start) and
does the second; it returns what it did, for the report.
"""
from __future__ import annotations

import compileall
import importlib.util
import os
import sys
from pathlib import Path

#: the packages whose modules a tracker and the truth import (their folders, wherever the install put them)
PACKAGES = ("zentrack", "zentrack.node", "zentrack.fusion", "zentrack.truth")

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS",)


def package_folders() -> list[Path]:
    folders = []
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            folders += [Path(p) for p in spec.submodule_search_locations]
    return folders


def bytecode_is_written() -> bool:
    return not (sys.flags.dont_write_bytecode or os.environ.get("PYTHONDONTWRITEBYTECODE"))


def compile_sources() -> int:
    """Compile zentrack's packages' sources to ``__pycache__`` (quietly, skipping up-to-date files); the number
    of folders that compiled cleanly."""
    ok = 0
    for folder in package_folders():
        if os.access(folder, os.W_OK):
            ok += bool(compileall.compile_dir(str(folder), quiet=2, workers=1))
    return ok


def prepare() -> dict:
    """The lean start for every process started after this call (module docstring); what was done."""
    threads = {}
    for var in THREAD_VARIABLES:
        threads[var] = os.environ.setdefault(var, "1")
    compiled = 0 if bytecode_is_written() else compile_sources()
    return {"thread_variables": threads, "bytecode_written_by_processes": bytecode_is_written(),
            "package_folders_compiled": compiled}
