"""A mistyped flag, subcommand, choice or scenario name gets a "did you mean" (issue 31): one line, exit 2,
from every subcommand's parser (``zentrack.cli.OneLineParser``, ``zentrack.common.suggest``)."""
from __future__ import annotations

import pytest

from zentrack.cli import main


def exit_code(args: list[str]) -> int:
    """The exit status of ``zentrack ARGS`` run in-process (argparse's SystemExit or main's return value)."""
    try:
        return main(list(args))
    except SystemExit as exc:
        return int(exc.code or 0)


def _typo(flag: str) -> str:
    """A flag with two letters after the dashes swapped: ``--steps`` -> ``--tseps``."""
    body = flag[2:]
    return "--" + body[1] + body[0] + body[2:]


def _subcommands() -> list[list[str]]:
    from zentrack.cli import BENCHMARKS, COMMANDS

    return [[c[0]] for c in COMMANDS] + [["bench", b[0]] for b in BENCHMARKS]


@pytest.mark.parametrize("words", _subcommands(), ids=" ".join)
def test_every_subcommand_suggests_the_flag_a_typo_meant(words, capsys):
    """Before: ``zentrack: error: unrecognized arguments: --tseps 10`` from the top-level parser, no hint."""
    from zentrack.cli import build_parser

    parser = build_parser(words)
    sub = parser._subparsers._group_actions[0].choices[words[0]]  # type: ignore[union-attr]
    if len(words) == 2:
        sub = sub._subparsers._group_actions[0].choices[words[1]]
    flag = next(f for f in sub.flags() if f != "--help" and len(f) > 5 and _typo(f) not in sub.flags())
    assert exit_code([*words, _typo(flag), "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err]
    assert err.startswith(f"zentrack {' '.join(words)}: error: unrecognized argument {_typo(flag)}; did you mean")
    assert f"did you mean '{flag}'?" in err, err


@pytest.mark.parametrize("args, hint", [(["rn"], "did you mean 'run'?"), (["bench", "acuracy"], "did you mean 'accuracy'?"),
                                        (["sim", "--scenario", "exp22"], "(did you mean 'exp2'?)"),
                                        (["sim", "--scenario", "seckf-trun"], "(did you mean 'seckf-turn'?)"),
                                        (["run", "--out", "x", "--timing", "realtme"], "did you mean 'realtime'?")])
def test_a_mistyped_subcommand_choice_or_scenario_name_gets_a_did_you_mean(args, hint, capsys):
    assert exit_code(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and hint in err, err


def test_a_word_nothing_resembles_gets_no_guess(capsys):
    assert exit_code(["sim", "--qqqqqqqq"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unrecognized argument --qqqqqqqq (see zentrack sim --help)" in err and "did you mean" not in err


def _chooser_actions():
    """(words, flag or None for a positional, a valid name) for every argument of every command that chooses
    among names: argparse ``choices``, or a type marked with the names it takes (``names_chosen_by``)."""
    import argparse

    from zentrack.cli import build_parser

    found = []
    for words in _subcommands():
        parser = build_parser(words)
        sub = parser._subparsers._group_actions[0].choices[words[0]]  # type: ignore[union-attr]
        if len(words) == 2:
            sub = sub._subparsers._group_actions[0].choices[words[1]]
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
                continue
            names = list(action.choices) if action.choices else list(getattr(action.type, "valid_names", list)())
            names = [str(n) for n in names if len(str(n)) >= 4]
            if names:
                flag = next((s for s in action.option_strings if s.startswith("--")), None)
                found.append((words, flag, max(names, key=len)))
    return found


CHOOSERS = _chooser_actions()


def test_the_commands_choose_among_names_in_many_places():
    flags = {flag for _, flag, _ in CHOOSERS}
    assert len(CHOOSERS) >= 25 and {"--filter", "--fusion", "--scenario", "--timing", "--methods", None} <= flags


@pytest.mark.parametrize("words, flag, name", CHOOSERS, ids=[f"{' '.join(w)} {f or 'positional'}" for w, f, _ in CHOOSERS])
def test_every_name_a_command_chooses_gets_a_did_you_mean(words, flag, name, capsys):
    """Generated over every command's arguments: a name with its last letter doubled is refused in one line
    that suggests the name."""
    typo = name + name[-1]
    assert exit_code([*words, *([flag] if flag else []), typo]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and f"did you mean '{name}'?" in err, err
