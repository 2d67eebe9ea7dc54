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


def test_the_fusion_param_examples_of_run_help_are_accepted_by_their_rules():
    """``run --help``: "--fusion-param ... (e.g. share_scans=true for ci; omega=10 for hcmci)": each example is
    a parameter of the rule it names (the help once showed omega=10 with the default rule, which refused it)."""
    import argparse

    from zentrack.common.argtypes import fusion_param, fusion_params_with
    from zentrack.config.run_setup import add_scenario_arguments

    probe = argparse.ArgumentParser()
    add_scenario_arguments(probe)
    text = next(a.help for a in probe._actions if "--fusion-param" in a.option_strings)
    examples = re.findall(r"(\w+=\w+) for ([\w-]+)", text)
    assert len(examples) >= 2, text
    for pair, rule in examples:
        fusion_params_with(rule, {}, [fusion_param(pair)])  # raises ValueError if the rule refuses it
