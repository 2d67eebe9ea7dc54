"""Old spellings that still work for one release: one line on stderr each time one is used.

The standard library only: every process command's flags use it (a health check imports nothing else).
"""
from __future__ import annotations

import argparse
import sys


def deprecated(old: str, new: str, prog: str = "zentrack") -> None:
    """The one line on stderr of an old spelling that still works for one release."""
    print(f"{prog}: warning: {old} is deprecated and goes in the next release; use {new}", file=sys.stderr)


class DeprecatedFlag(argparse.Action):
    """An old flag spelling (``use``: the new flag): sets the new flag's ``dest`` and says so on stderr. Hidden
    from ``--help`` unless given a help text."""

    def __init__(self, option_strings, dest, use: str, **kwargs) -> None:
        kwargs.setdefault("help", argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kwargs)
        self.use = use

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        deprecated(f"{option_string} {values}", f"{self.use} {values}", parser.prog)
        setattr(namespace, self.dest, values)
