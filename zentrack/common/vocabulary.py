"""One vocabulary: the filter and fusion-rule names every command takes (``--filter teskf --fusion ci`` in sim and
run alike, ``centralized`` for sim's one centre), with ``zentrack sim``'s old combined names (``dteskf``,
``cteskf``) as deprecated aliases."""
from __future__ import annotations

import argparse

from zentrack.common.argtypes import registered
from zentrack.common.deprecation import deprecated
from zentrack.common.suggest import names_chosen_by
from zentrack.fusion.defaults import CENTRALIZED

#: why a live run (truth and a tracker process per node) refuses the centralized filter
CENTRALIZED_NOT_LIVE = (f"--fusion {CENTRALIZED}: the centralized filter (one centre with every node's measurements) "
                        "runs only in the batched simulator, `zentrack sim`; a live run has a tracker per sensor")


def combined_filter(registry, name: str) -> tuple[str, str] | None:
    """``zentrack sim``'s old combined names: ``d<filter>`` (distributed: the filter with the ``--fusion`` rule)
    -> ``(filter, "distributed")``, ``c<filter>`` -> ``(filter, CENTRALIZED)``; None for any other name (a
    registered name is never read as a combined one: ``ckf`` is the cubature filter)."""
    if name in registry or len(name) < 2 or name[0] not in "dc" or name[1:] not in registry:
        return None
    return name[1:], "distributed" if name[0] == "d" else CENTRALIZED


def live_filter(registry):
    """An argparse type: a local filter of a live run, by its registered name (``--filter teskf``); sim's old
    ``d<filter>`` still works with a deprecation notice, ``c<filter>`` is refused with the reason."""

    def parse(text: str) -> str:
        combined = combined_filter(registry, text)
        if combined is not None and combined[1] == CENTRALIZED:
            raise argparse.ArgumentTypeError(f"{text} is the centralized {combined[0]}: {CENTRALIZED_NOT_LIVE}")
        if combined is not None:
            deprecated(f"--filter {text}", f"--filter {combined[0]} (the fusion rule comes from --fusion)")
            return combined[0]
        return registered(registry)(text)

    parse.__name__ = registry.kind
    names_chosen_by(parse, registry.names)
    return parse


def fusion_name(registry):
    """An argparse type: a registered fusion rule or ``centralized`` (which a live run then refuses, naming why)."""

    def parse(text: str) -> str:
        return registered(registry, extra=(CENTRALIZED,))(text)

    parse.__name__ = registry.kind
    names_chosen_by(parse, lambda: [*registry.names(), CENTRALIZED])
    return parse
