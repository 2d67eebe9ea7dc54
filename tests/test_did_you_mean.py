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
