"""Readable in a terminal (issue 50): every command's ``--help`` fits 50 lines of an 80-column terminal, with a
one-line usage; ``--help-all`` adds the advanced flags, which still parse and get a "did you mean"."""
from __future__ import annotations

import argparse
import importlib

import pytest

from zentrack.cli import ADVANCED, BENCHMARKS, COMMANDS, advanced_of, build_parser

NAMES = [c[0] for c in COMMANDS] + [f"bench {b[0]}" for b in BENCHMARKS]


def _sub(name: str) -> argparse.ArgumentParser:
    words = name.split()
    parser = build_parser(words)
    for word in words:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[word]
    return parser


@pytest.mark.parametrize("name", NAMES)
def test_help_fits_fifty_lines_of_80_columns(name, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    text = _sub(name).format_help()
    assert len(text.splitlines()) <= 50, f"zentrack {name} --help is {len(text.splitlines())} lines"
    assert text.splitlines()[0].startswith(f"usage: zentrack {name} [options]")
    for action in _sub(name)._actions:  # (a positional argument is in the one-line usage: `zentrack view PATH.rrd`)
        if not action.option_strings and not isinstance(action, argparse._SubParsersAction):
            shown = action.metavar or ("{" + ",".join(map(str, action.choices)) if action.choices else action.dest)
            assert shown in text.splitlines()[0], (name, text.splitlines()[0])
    assert "ais-nyharbor-cameras" not in text, "the scenario catalogue is listed once, by `zentrack scenarios`"


@pytest.mark.parametrize("name", [c[0] for c in COMMANDS if c[0] in ADVANCED])
def test_help_all_shows_every_flag_and_each_advanced_one_exists(name, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    p = _sub(name)
    flags = {s for a in p._actions for s in a.option_strings if s.startswith("--")}
    advanced = advanced_of(name, importlib.import_module(next(c[2] for c in COMMANDS if c[0] == name)))
    assert set(advanced) <= flags, f"ADVANCED lists flags zentrack {name} does not have"
    short = p.format_help()
    with pytest.raises(SystemExit) as done:
        p.parse_args(["--help-all"])
    assert done.value.code == 0
    full = capsys.readouterr().out
    for flag in advanced:
        assert not any(line.lstrip().startswith(flag + " ") or line.strip() == flag for line in short.splitlines()), \
            f"--help shows the advanced {flag}"
        assert any(line.lstrip().startswith(flag) for line in full.splitlines()), f"--help-all does not show {flag}"
    assert len(full.splitlines()) > len(short.splitlines())


def test_a_mistyped_advanced_flag_gets_the_nearest(capsys):
    from zentrack.cli import main

    with pytest.raises(SystemExit) as done:
        main(["run", "--qbr", "1", "--out", "x"])
    assert done.value.code == 2
    assert "did you mean '--qbar'?" in capsys.readouterr().err
