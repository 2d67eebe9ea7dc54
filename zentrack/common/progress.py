"""Feedback on long work, one implementation for every command (runs, soaks, benches): a progress line that
updates in place on a terminal, and a closing line that says where the outputs are.

``Progress`` is a ``tqdm`` bar with zentrack's line, ``<label> [#####     ] 120/300 steps  12 s``, on its
stream (stderr by default) when that stream is a terminal, at most every ``min_interval`` seconds, and
nothing at all otherwise (a log file or a pipe gets no carriage returns); ``close()`` ends the line.
``write_above(text)`` prints a message line above the bar (``tqdm.write``: the bar is redrawn below it); while
a bar is drawn, the log records of the root logger's handlers that write to the same stream go above it too.
``outputs_line`` formats the closing line, printed whether or not a terminal is attached::

    with Progress(300, "steps", label="run") as bar:
        for k in range(300):
            ...
            bar.update(k + 1)
    print(outputs_line("run OK", report=out / "report.json", plot=[out / "error.png", out / "error.svg"]))

Deep inside long work, ``note(msg, done=1)`` reports a finished unit without a handle on the bar: it advances
the innermost bar that is open and writes ``msg`` above it (a plain stderr line when no bar is open).

The stream and the clock are injected (the clock as tqdm's own), so the bar is tested without a terminal or a
real clock.
"""
from __future__ import annotations

import logging
import math
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import TextIO

from tqdm import tqdm

#: characters of the bar between the brackets
BAR_WIDTH = 20
#: the bars open now, innermost last (what ``note`` reports to)
_OPEN: list[Progress] = []


def is_terminal(stream: TextIO) -> bool:
    """True when ``stream`` is an interactive terminal (a closed or fake stream counts as not one)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class Progress:
    """A progress line for ``total`` units of work (``None``: an unknown total, the count and the time only).

    ``enabled``: ``None`` (default) draws only when ``stream`` is a terminal. ``update(done)`` sets the count,
    ``advance(n)`` adds to it; both redraw when ``min_interval`` seconds passed since the last drawing (the
    first and the final count are always drawn). ``close()`` ends the line (idempotent); a context manager
    closes on exit."""

    def __init__(self, total: int | None, unit: str = "steps", *, label: str = "", stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic, enabled: bool | None = None,
                 min_interval: float = 0.2, width: int = BAR_WIDTH) -> None:
        self.total = total if total is None or total > 0 else None
        self.unit, self.label = unit, label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = is_terminal(self.stream) if enabled is None else enabled
        self.note = ""
        self._closed = False
        self._rerouted: list[logging.StreamHandler] = []
        head = "{desc} " if label else ""
        size = shutil.get_terminal_size(fallback=(120, 24))
        counts = "{n}/{total} " if self.total is not None else "{n} "
        self.bar = tqdm(total=self.total, desc=label, unit=unit, file=self.stream, disable=not self.enabled,
                        mininterval=min_interval, miniters=1, ascii=" #", leave=True,
                        # the terminal's size: one that reports none (a fresh pty: 0 x 0) has tqdm draw nothing at
                        # all (no row for the bar), so it falls back to 120 x 24
                        ncols=size.columns or 120, nrows=size.lines or 24,
                        delay=math.inf,  # (nothing is drawn before the clock is ours, below)
                        bar_format=head + (f"[{{bar:{width}}}] " if self.total is not None else "") + counts + unit
                        + "  {elapsed}{postfix}")
        self.bar._time = clock  # tqdm's clock (its attribute; its own tests set it so), then started on it
        self.bar.delay = 0
        _OPEN.append(self)
        if self.enabled:
            self.bar.reset(self.total)
            above = _Above(self)
            for handler in logging.getLogger().handlers:
                if isinstance(handler, logging.StreamHandler) and handler.stream is self.stream:
                    handler.setStream(above)
                    self._rerouted.append(handler)

    @property
    def done(self) -> int:
        return int(self.bar.n)

    def update(self, done: int, note: str = "") -> None:
        """Set the count of units done (and an optional short note shown after the time)."""
        if note != self.note:
            self.note = note
            self.bar.postfix = note  # (tqdm shows it after the time, ", note")
        self.bar.update(done - self.bar.n)

    def advance(self, n: int = 1, note: str = "") -> None:
        self.update(self.done + n, note)

    def write_above(self, text: str) -> None:
        """Write ``text`` as its own line(s): above the bar on a terminal (the bar is redrawn under it), plainly
        otherwise."""
        text = text[:-1] if text.endswith("\n") else text
        if not self.enabled or self._closed:
            self.stream.write(text + "\n")
            self.stream.flush()
            return
        tqdm.write(text, file=self.stream)

    def close(self) -> None:
        """Draw the last count and end the line (nothing when not drawing); log records go to the stream again."""
        if self._closed:
            return
        self.bar.close()
        for handler in self._rerouted:
            handler.setStream(self.stream)
        self._closed = True
        if self in _OPEN:
            _OPEN.remove(self)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def note(msg: str, done: int = 0) -> None:
    """A line of news from long work: advances the innermost open bar by ``done`` units and writes ``msg`` above
    it; with no bar open, ``msg`` goes to stderr as a plain line."""
    if _OPEN:
        bar = _OPEN[-1]
        if done:
            bar.advance(done, bar.note)
        bar.write_above(msg)
    else:
        print(msg, file=sys.stderr, flush=True)


class _Above:
    """A stream that writes above a progress bar (what a log handler writes to while the bar is drawn)."""

    def __init__(self, bar: Progress) -> None:
        self.bar = bar

    def write(self, text: str) -> int:
        self.bar.write_above(text)
        return len(text)

    def flush(self) -> None:
        self.bar.stream.flush()


def _show(path: str | os.PathLike) -> str:
    return os.fspath(path)


def outputs_line(verdict: str, **outputs: str | os.PathLike | Sequence[str | os.PathLike] | None) -> str:
    """The closing line of a command: ``<verdict>: <name> <path>, <name> <path> <path>`` (a name with a list
    of paths, e.g. a figure's PNG and SVG, gets them all; ``None`` values are left out; an underscore in a
    name reads as a space)."""
    parts = []
    for name, value in outputs.items():
        if value is None:
            continue
        paths = [value] if isinstance(value, (str, os.PathLike)) else list(value)
        if paths:
            parts.append(f"{name.replace('_', ' ')} {' '.join(_show(p) for p in paths)}")
    return f"{verdict}: {', '.join(parts)}" if parts else verdict

