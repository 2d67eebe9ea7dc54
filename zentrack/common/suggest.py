""""Did you mean" for a mistyped word (a flag, a subcommand, a scenario name), one implementation for all."""
from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable


def close_match(word: str, candidates: Iterable[str]) -> str | None:
    """The candidate nearest to ``word`` (``difflib``'s ratio at least 0.6), or None."""
    found = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return found[0] if found else None


def did_you_mean(word: str, candidates: Iterable[str]) -> str:
    """``"; did you mean 'exp2'?"`` for the nearest candidate, "" when none is near."""
    match = close_match(word, candidates)
    return f"; did you mean {match!r}?" if match else ""


def names_chosen_by(parse: object, names: Callable[[], Iterable[str]]) -> None:
    """Mark the argparse type ``parse`` as choosing one of ``names()`` (read by the test that mistypes every
    name a command line chooses, tests/test_did_you_mean.py)."""
    parse.valid_names = names  # type: ignore[attr-defined]


def with_hint(exc: BaseException) -> str:
    """``exc``'s message, with "did you mean" when it names an unknown word among known choices (a registry's
    :class:`~zentrack.fusion.registry.UnknownName`)."""
    word, choices = getattr(exc, "word", None), getattr(exc, "choices", None)
    if isinstance(word, str) and choices:
        return f"{exc}{did_you_mean(word, choices)}"
    return str(exc)
