"""Markdown tables from benchmark JSON: the one helper every results renderer uses.

A table is a list of :class:`Column` (a header, the path of the value inside a row, a format) applied to a
list of rows taken from the JSON. A value that is missing raises :class:`ResultsError` naming the file, the
table, the row and the key, so a bench whose output changed shape breaks the docs build in one clear line
instead of leaving a stale or empty table.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Format = Callable[[Any], str]


class ResultsError(ValueError):
    """A results table could not be rendered from its JSON."""


def get(obj: Any, path: str, where: str) -> Any:
    """``obj[a][b]...`` for the dotted ``path`` ``"a.b"`` (integers index lists); ResultsError naming ``where``
    and the first missing part."""
    cur = obj
    for part in path.split("."):
        if isinstance(cur, dict) and part in cur:
            cur = cur[part]
        elif isinstance(cur, list) and part.lstrip("-").isdigit() and -len(cur) <= int(part) < len(cur):
            cur = cur[int(part)]
        else:
            raise ResultsError(f"{where}: no key {part!r} (looking up {path!r})")
    return cur


def num(digits: int = 2) -> Format:
    """A number with ``digits`` decimals; non-finite and None as written out."""
    def fmt(v: Any) -> str:
        if v is None:
            return "–"
        if isinstance(v, str) and v in ("inf", "Infinity"):
            return "diverged"
        if isinstance(v, str) and v.lower() == "nan" or isinstance(v, float) and math.isnan(v):
            return "–"
        if isinstance(v, bool) or not isinstance(v, int | float):
            return str(v)
        if isinstance(v, float) and not math.isfinite(v):
            return "diverged" if v > 0 else str(v)
        return f"{v:.{digits}f}"
    return fmt


def median_iqr(digits: int = 2) -> Format:
    """``{"median": m, "q25": a, "q75": b}`` (or a ``[m, a, b]`` list) as ``m [a, b]``."""
    one = num(digits)

    def fmt(v: Any) -> str:
        if isinstance(v, dict) and one(v["median"]) == "diverged":
            return "diverged"
        if isinstance(v, dict):
            return f"{one(v['median'])} [{one(v['q25'])}, {one(v['q75'])}]"
        if isinstance(v, list | tuple) and len(v) == 3:
            return f"{one(v[0])} [{one(v[1])}, {one(v[2])}]"
        return one(v)
    return fmt


def band(lo_hi: Any) -> str:
    """A 95 % band ``[lo, hi]`` as ``lo–hi``, or an empty string for no band."""
    if isinstance(lo_hi, list | tuple) and len(lo_hi) == 2:
        return f"{lo_hi[0]:.2f}–{lo_hi[1]:.2f}"
    return ""


def bullets(items: Any, where: str) -> str:
    """A list of strings as a Markdown bullet list; ResultsError for anything else."""
    if not isinstance(items, list) or not items or not all(isinstance(i, str) for i in items):
        raise ResultsError(f"{where}: expected a non-empty list of strings")
    return "\n".join(f"- {i}" for i in items)


def joined(digits: int = 2) -> Format:
    """A list of numbers as ``a / b / c``."""
    one = num(digits)

    def fmt(v: Any) -> str:
        return " / ".join(one(x) for x in v) if isinstance(v, list) else one(v)
    return fmt


def text(v: Any) -> str:
    return "–" if v is None else str(v)


def yes_no(v: Any) -> str:
    return "yes" if v else "no"


@dataclass(frozen=True)
class Column:
    header: str
    path: str
    fmt: Format = text
    optional: bool = False  # a missing value prints as "–" instead of failing


def render_table(rows: Sequence[Any], columns: Sequence[Column], where: str) -> str:
    """The Markdown table of ``rows`` under ``columns``; ResultsError when a row lacks a required value."""
    if not rows:
        raise ResultsError(f"{where}: no rows")
    lines = ["| " + " | ".join(c.header for c in columns) + " |", "|" + "---|" * len(columns)]
    for i, row in enumerate(rows):
        cells = []
        for c in columns:
            try:
                value = get(row, c.path, f"{where}, row {i}")
            except ResultsError:
                if not c.optional:
                    raise
                value = None
            cells.append(c.fmt(value).replace("|", "\\|"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def load(path: Path) -> dict[str, Any]:
    """A results JSON file; ResultsError when it is missing or not a JSON object."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ResultsError(f"{path}: missing (run docs/hooks/run_benches.py {path.stem})") from None
    except json.JSONDecodeError as exc:
        raise ResultsError(f"{path}: not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ResultsError(f"{path}: expected a JSON object")
    return data


def produced_by(data: dict[str, Any], where: str) -> str:
    """One line saying which command produced the figures (the ``produced_by`` stamp of run_benches.py)."""
    stamp = get(data, "produced_by", where)
    load = stamp.get("load_avg_1min_at_start")
    loaded = f", load average {load} at its start" if load is not None else ""
    if stamp.get("exit_status"):
        loaded += f"; the bench exited {stamp['exit_status']}: it judged a criterion failed"
    wall = get(stamp, "wall_s", where)
    took = "wall time not recorded" if wall is None else f"{wall:.0f} s wall time"
    return (f"*Produced by `{get(stamp, 'command', where)}` on {get(stamp, 'date', where)} "
            f"({took} on a shared 2-core machine{loaded}).*")
