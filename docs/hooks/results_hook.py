"""MkDocs hook: put generated content where a page asks for it.

- ``<!-- results: BENCH TABLE -->`` becomes the Markdown table ``TABLE`` rendered from
  ``docs/results/BENCH.json`` (a benchmark's own JSON, written by ``docs/hooks/run_benches.py``), followed
  by a line naming the command that produced it. The renderers are in ``results_papers.py``,
  ``results_runtime.py``, ``results_capacity.py``, ``results_real.py`` and ``results_soak.py``.
- ``<!-- wire-protocol -->`` becomes the wire-protocol reference generated from the typed messages
  (``wire_protocol.py``).
- ``<!-- data-path-files -->`` becomes the list of every file one measurement's path enters, from the truth to
  the viewer, made by following the calls (``data_path.py``).

A marker that names an unknown table, a missing file or a missing key stops the build with one line saying
which (mkdocs' PluginError), so no page is built with a stale or empty table.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import data_path
import results_capacity
import results_papers
import results_real
import results_runtime
import results_soak
import wire_protocol
from results_tables import Column, ResultsError, get, load, num, produced_by, render_table

RESULTS_DIR = Path(__file__).resolve().parent.parent / "results"
# a marker is a line of its own (one quoted in a code span or block is left alone)
MARKER = re.compile(r"^<!--\s*results:\s*(\S+)\s+(\S+)\s*-->[ \t]*$", re.M)
WIRE_MARKER = "<!-- wire-protocol -->"
PROVENANCE_MARKER = "<!-- results-provenance -->"
DATA_PATH_MARKER = "<!-- data-path-files -->"
RENDERERS = {**results_papers.RENDERERS, **results_runtime.RENDERERS, **results_capacity.RENDERERS,
             **results_real.RENDERERS, **results_soak.RENDERERS}


def render_marker(bench: str, table: str, results_dir: Path = RESULTS_DIR) -> str:
    """The table ``table`` of ``results_dir/bench.json`` and its provenance line; ResultsError if it cannot."""
    renderer = RENDERERS.get((bench, table))
    if renderer is None:
        known = ", ".join(f"{b} {t}" for b, t in sorted(RENDERERS))
        raise ResultsError(f"unknown results table {bench!r} {table!r} (known: {known})")
    path = results_dir / f"{bench}.json"
    data = load(path)
    where = f"{path.name} ({table})"
    return renderer(data, where) + "\n\n" + produced_by(data, where.replace(")", ": produced_by)"))


def provenance(results_dir: Path = RESULTS_DIR) -> str:
    """A table of every results JSON: the file, the command that wrote it, its wall time and date."""
    rows = []
    for path in sorted(results_dir.glob("*.json")):
        stamp = get(load(path), "produced_by", path.name)
        rows.append({"file": f"`results/{path.name}`", **stamp})
    return render_table(rows, [Column("file", "file"), Column("command", "command", lambda c: f"`{c}`"),
                               Column("wall time (s)", "wall_s", num(0)), Column("date", "date"),
                               Column("load at start", "load_avg_1min_at_start", num(1), optional=True)],
                        "results provenance")


def expand(markdown: str, results_dir: Path = RESULTS_DIR) -> str:
    """``markdown`` with every marker replaced."""
    out = MARKER.sub(lambda m: render_marker(m.group(1), m.group(2), results_dir), markdown)
    for marker, render in ((PROVENANCE_MARKER, lambda: provenance(results_dir)),
                           (WIRE_MARKER, wire_protocol.render_page), (DATA_PATH_MARKER, data_path.render_files)):
        line = re.compile(rf"^{re.escape(marker)}[ \t]*$", re.M)
        if line.search(out):
            out = line.sub(lambda _m, r=render: r(), out)
    return out


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    from mkdocs.exceptions import PluginError

    try:
        return expand(markdown)
    except (ResultsError, wire_protocol.WireDocError) as exc:
        raise PluginError(f"{page.file.src_path}: {exc}") from None
