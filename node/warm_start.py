"""How a warming tracker rejoins: the choice it makes at the end of each fusion window.

A node warms when it has no usable prior (a restart) or a stale one (more than ``MAX_COAST_STEPS`` without a
measurement: a freeze, a cut link, a truth or router stall). While warming it publishes its own (stale)
prediction every step flagged ``warm``, if it has one. At the end of the fusion window it takes, in this order:

1. the neighbours' fresh pairs (``WARM_START``): their estimates beat its stale prediction;
2. its own prediction fused with the warm pairs that arrived (``RESUME_OWN``);
3. with no state of its own, the warm pairs (``WARM_START_FROM_WARMING``);
4. nothing: it tries again at the next step, and after ``cold_after`` empty steps (or at once with no
   neighbours) takes the configured initial prior (``COLD_START``).

So a network in which every node warms at once recovers at the first window's end: every node that has a
state fuses at least its own pair.
"""
from __future__ import annotations

from enum import Enum

#: a warming node with no state of its own that hears nothing for this many steps cold-starts
COLD_AFTER_STEPS = 20


class WarmChoice(Enum):
    WARM_START = "warm start from the neighbours' fresh pairs"
    RESUME_OWN = "resumed from its own prediction and the warm pairs"
    WARM_START_FROM_WARMING = "warm start from warming neighbours' pairs"
    COLD_START = "cold start: no neighbour has a state"
    WAIT = "nothing to start from yet"


def warm_choice(fresh: int, own: bool, warm: int, neighbours: int, empty_steps: int, cold_after: int) -> WarmChoice:
    """The choice (module docstring) from how many fresh and warm pairs came (``fresh``, ``warm``: all the
    pairs chosen, fresh ones included), whether the node has its own prediction, how many neighbours it has
    and for how many steps it has waited with nothing."""
    if fresh:
        return WarmChoice.WARM_START
    if own:
        return WarmChoice.RESUME_OWN
    if warm:
        return WarmChoice.WARM_START_FROM_WARMING
    if not neighbours or empty_steps >= cold_after:
        return WarmChoice.COLD_START
    return WarmChoice.WAIT
