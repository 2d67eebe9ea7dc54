"""Every ``zentrack`` command in the README's and the docs' code blocks is one the command line takes as written
(issue 50): its subcommand, flags, choices and values parse (a renamed flag, a retired name or a bad value in
the docs fails here); lines that show a form with placeholders (``NAME|PATH``, ``[--nodes N]``, ``<out>``) are
the syntax, not a command, and are left out."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from zentrack.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PLACEHOLDER = re.compile(r"\||\[|<|\.\.\.|\b[A-Z]{2,}\b(?!\.)|\$")


def doc_commands() -> list[tuple[str, str]]:
    found = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        for block in re.findall(r"```(?:bash|sh|console)?\n(.*?)```", page.read_text(), re.S):
            for line in block.replace("\\\n", " ").splitlines():  # (a command continued over lines is one)
                command = line.split(" #", 1)[0].strip()
                if command.startswith(".venv/bin/zentrack "):
                    command = command[len(".venv/bin/"):]
                if command.startswith("zentrack ") and not PLACEHOLDER.search(command):
                    found.append((page.relative_to(ROOT).as_posix(), command))
    return found


COMMANDS = doc_commands()


def test_the_docs_show_commands():
    assert len(COMMANDS) >= 30


@pytest.mark.parametrize(("page", "command"), COMMANDS, ids=[f"{p}:{c[:60]}" for p, c in COMMANDS])
def test_a_docs_command_parses_as_written(page, command, capsys):
    argv = shlex.split(command)[1:]
    try:
        build_parser(argv).parse_args(argv)
    except SystemExit as exc:
        if exc.code == 0 and ("--help" in argv or "--version" in argv):
            return  # (the help or the version, printed)
        pytest.fail(f"{page}: `{command}` does not parse (exit {exc.code}): {capsys.readouterr().err.strip()}")


@pytest.mark.parametrize("command", ["run", "sim"])
def test_the_fusion_param_examples_of_the_help_are_accepted_by_their_rules(command):
    """``run --help`` and ``sim --help``: "--fusion-param ... (e.g. share_scans=true for ci; omega=10 for
    hcmci)": each example names its rule and is a parameter of it (the help once showed omega=10 with the
    default rule, which refused it; sim's showed both without a rule until issue 50's last look)."""
    import argparse

    from zentrack.common.argtypes import fusion_param, fusion_params_with

    parser = build_parser([command])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    action = next(a for a in sub._actions if "--fusion-param" in a.option_strings)
    text = " ".join(getattr(action, "full_help", action.help).split())  # (a --help-all flag)
    examples = re.findall(r"(\w+=\w+) for ([\w-]+)", text)
    assert len(examples) >= 2 and len(examples) == len(re.findall(r"\w+=\w+", text)), text
    for pair, rule in examples:
        fusion_params_with(rule, {}, [fusion_param(pair)])  # raises ValueError if the rule refuses it
