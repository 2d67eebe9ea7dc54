"""One vocabulary (issue 50): the retired names of a paper ("seed 000"), of a figure flag (``--figure``) and of
compose's output flag (``-o``/``--output``) appear in no page of the docs and no ``--help``; the old flags
still work with a warning."""
from __future__ import annotations

import argparse
import functools
import re
from pathlib import Path

import pytest

from zentrack.cli import BENCHMARKS, COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[1]
RETIRED = {
    r"\b[Ss]eed 00[0-4]\b": "a paper is 'paper N' (docs/cli.md), never 'seed 00N'",
    r"\bpaper00[0-4]\b": "a paper's bench is 'paperN' (bench paper0), never 'paper00N'",
    r"--figure\b": "a figure is written with --plot",
    r"zentrack compose\b[^\n`]*\s(-o|--output)\s": "compose writes to --out",
}


def without_the_table_of_old_names(text: str) -> str:
    """A page without docs/cli.md's section that lists the old names (the one place that names them)."""
    start = text.find("## One name for each thing")
    if start < 0:
        return text
    end = text.find("\n## ", start + 1)
    return text[:start] + (text[end:] if end >= 0 else "")


@functools.lru_cache(maxsize=1)
def _texts() -> list[tuple[str, str]]:
    pages = [(str(p.relative_to(ROOT)), without_the_table_of_old_names(p.read_text()))
             for p in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]]
    helps = []
    for words in [[c[0]] for c in COMMANDS] + [["bench", b[0]] for b in BENCHMARKS]:
        parser = build_parser(words)
        for word in words:
            parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
        helps.append((f"zentrack {' '.join(words)} --help", parser.format_help()))
    return pages + helps


@pytest.mark.parametrize("pattern", RETIRED)
def test_no_retired_name_in_the_docs_or_any_help(pattern):
    found = [f"{where}: {m.group(0)!r}" for where, text in _texts() for m in re.finditer(pattern, text)]
    assert not found, f"{RETIRED[pattern]}: {found[:10]}"


def test_the_old_flags_still_work_with_a_warning(tmp_path, capsys):
    from zentrack.cli import main

    assert main(["compose", "--nodes", "2", "-o", str(tmp_path / "c.yml")]) == 0
    err = capsys.readouterr().err
    assert "-o " in err and "is deprecated" in err and "use --out" in err and (tmp_path / "c.yml").exists()
    assert main(["compose", "--nodes", "2", "--output", str(tmp_path / "d.yml")]) == 0
    err = capsys.readouterr().err
    assert "--output" in err and "is deprecated" in err and "use --out" in err and (tmp_path / "d.yml").exists()


def test_a_retired_bench_name_still_runs_the_bench_with_a_warning(capsys):
    from zentrack.cli import main

    with pytest.raises(SystemExit) as done:
        main(["bench", "paper003", "--help"])
    assert done.value.code == 0
    out, err = capsys.readouterr()
    assert "bench paper003 is deprecated" in err and "use bench paper3" in err
    assert "usage: zentrack bench paper3" in out
