"""Small helpers to summarise Monte Carlo figures, print aligned tables and write JSON reports (every command and
bench prints and writes through them)."""
from __future__ import annotations

import json
import math
import os
import textwrap
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from zentrack.common.atomic import write_text_atomically


def stats(values: Iterable[float]) -> dict:
    """Median and inter-quartile range of ``values`` (inf counts as worst; NaN is dropped)."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=float)
    if v.size == 0:
        return {"median": float("nan"), "q25": float("nan"), "q75": float("nan"), "n": 0}
    q25, med, q75 = np.percentile(v, [25, 50, 75]) if np.all(np.isfinite(v)) else _inf_percentiles(v)
    return {"median": float(med), "q25": float(q25), "q75": float(q75), "n": int(v.size)}


def _inf_percentiles(v: np.ndarray) -> tuple[float, float, float]:
    s = np.sort(v)
    idx = [int(round(p * (len(s) - 1))) for p in (0.25, 0.5, 0.75)]
    return tuple(float(s[i]) for i in idx)  # type: ignore[return-value]


def fmt_stats(st: dict, digits: int = 3) -> str:
    """``median [q25, q75]``, or just the value when there is one sample."""
    if st["n"] == 0:
        return "n/a"
    if st["n"] == 1:
        return fmt_num(st["median"], digits)
    return f"{fmt_num(st['median'], digits)} [{fmt_num(st['q25'], digits)}, {fmt_num(st['q75'], digits)}]"


def fmt_num(x: float, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    if math.isinf(x):
        return "diverged"
    return f"{x:.{digits}f}" if abs(x) < 1e5 else f"{x:.3g}"


#: the widest line a table or a legend prints (a terminal of 120 columns); the full figures are in the JSON
MAX_WIDTH = 120


def table(headers: Sequence[str], rows: Sequence[Sequence[str]], max_width: int = MAX_WIDTH) -> str:
    """A plain aligned text table; one wider than ``max_width`` is split into tables one under the other, each
    with the first column (what the rows are) and as many of the next columns as fit."""
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    parts: list[list[int]] = [[0]]
    for i in range(1, len(headers)):
        if sum(widths[j] + 2 for j in parts[-1]) + widths[i] > max_width and len(parts[-1]) > 1:
            parts.append([0])
        parts[-1].append(i)

    def block(cols: list[int]) -> str:
        line = lambda cells: "  ".join(str(cells[j]).ljust(widths[j]) for j in cols).rstrip()  # noqa: E731
        return "\n".join([line(headers), line(["-" * w for w in widths]), *(line(r) for r in rows)])

    return "\n\n".join(block(cols) for cols in parts)


def wrapped(text: str, width: int = MAX_WIDTH) -> str:
    """``text`` as lines of at most ``width`` characters (a legend under a table)."""
    return textwrap.fill(text, width=width)


def write_json(path: str | os.PathLike, payload: dict) -> Path:
    """Write ``payload`` as JSON atomically (inf/NaN written as strings so any JSON reader accepts it)."""
    return write_text_atomically(path, json.dumps(_jsonable(payload), indent=2) + "\n")


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else ("inf" if x > 0 else "-inf" if x < 0 else "nan")
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    return x


def figure_path(plot: str | None, json_path: str | None) -> Path | None:
    """Where a benchmark draws its figure: ``--plot`` when given, else beside ``--json`` (``.png``), else nowhere."""
    if plot:
        return Path(plot)
    return Path(json_path).with_suffix(".png") if json_path else None
