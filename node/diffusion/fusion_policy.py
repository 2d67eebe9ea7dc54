"""Which of the neighbours' round messages a tracker fuses: conflicts, the gate and the outvote rule.

Each (step, round, sender) keeps the first two distinct messages (admission, ``node/diffusion/admission.py``). When a
round is fused, per sender:

- two or more distinct copies are a **conflict**: the sender is left out of the round and every copy is
  counted (``conflicts``), whichever of them passes the gate;
- a single copy goes through the tracker's gate against the node's own message of that round (a chi-square
  test with the covariance-intersection bound, ``fusion/gate.py``): fused if it passes, else left out
  (counted ``gated``).

Why this rule: without authentication (insecure mode) a receiver cannot tell the sender's copy from a forged
one, so neither arrival order nor the gate may pick between copies (the gate trusts the node's own estimate,
which may be the wrong one). With two copies nobody wins. In realtime a round also waits
:data:`CONFLICT_SETTLE_S` after it starts before it fuses, even when every neighbour's message is in
(``node/diffusion/local_step.py``; at most a quarter of the round's time to its deadline, so rules with many rounds keep
their pace), and admission refuses a copy that comes before its sender could have made it (``early``). So a
forged copy is fused only when the sender's genuine message reaches this node more than that settle time
after the round started (late) or not at all (a crashed or partitioned node, which a
forger can impersonate in insecure mode): what a forger can do otherwise is take a sender out of a round, and
CI over fewer neighbours stays consistent. ``--secure`` stops forgers at the router.

The gate trusts the node's own message, so a node whose own estimate has gone wrong (inconsistent after a
freeze or an overloaded stretch) would refuse every honest neighbour from then on and never come back. So a
node that the gate shows to be the odd one out is ``outvoted``: it fuses the refused neighbours' messages
without its own message in that round (counted ``outvoted``) when either

- at least two senders, more than half of those heard in the round, had their one copy refused, and those
  copies pass the gate against each other (they agree with each other, not with us); or
- every sender heard was refused in ``OUTVOTED_STREAK`` consecutive rounds: with a single neighbour nobody can
  tell which of the two is wrong (both see the same refusals), so the node lifts its gate for that round and
  fuses the refused messages with its own (counted ``gate_lifted``); CI keeps the result consistent if
  either was, and the two estimates meet.

Lockstep fuses once every neighbour has sent any copy (nothing there ever times out), so a forged copy that
arrives before the real one is fused there: lockstep is a study mode for a trusted bus (``--secure`` where
forgers are possible).
"""
from __future__ import annotations

import logging
from collections.abc import Callable

from zentrack.node.counters import Counters
from zentrack.node.diffusion.tracker import Pair

log = logging.getLogger("zentrack.node")

#: consecutive rounds in which the gate refused every sender heard, after which the node is outvoted
OUTVOTED_STREAK = 5
#: realtime: a round fuses no sooner than this after it starts (at most a quarter of the round's time), so a genuine
#: copy trailing a forged one by less than this makes a conflict instead of losing the race
CONFLICT_SETTLE_S = 0.010

#: the copies received per sender for one (step, round)
Copies = dict[int, list[Pair]]


class FusionPolicy:
    """Node ``node``'s choice of messages per round; ``gate(own, other)`` is the tracker's gate."""

    def __init__(self, node: int, lockstep: bool, gate: Callable[[Pair, Pair], bool], counters: Counters) -> None:
        self.node, self.lockstep, self.gate, self.counters = node, lockstep, gate, counters
        self.refused_streak = 0  # consecutive rounds in which the gate refused every sender heard

    def passing(self, received: Copies, own: Pair | None) -> Copies:
        """Per sender with one copy, that copy if it passes the gate against ``own`` (checked once); senders
        in conflict (two copies or more) are left out."""
        out = {}
        for sender, copies in received.items():
            if len(copies) > 1:
                continue
            if own is None:  # nothing to check against (a warm start): every copy counts, nothing is cached
                out[sender] = list(copies)
                continue
            for c in copies:
                if c.gated is None:
                    c.gated = self.gate(own, c)
            out[sender] = [c for c in copies if c.gated]
        return out

    def heard(self, received: Copies, own: Pair | None) -> set[int]:
        """The senders whose round message is in: any copy in lockstep; in realtime one that passes the gate,
        or a conflict (nothing more to wait for: the sender is left out)."""
        if self.lockstep:
            return set(received)
        conflicted = {j for j, copies in received.items() if len(copies) > 1}
        return conflicted | {j for j, passing in self.passing(received, own).items() if passing}

    def chosen(self, key: tuple[int, int], received: Copies, own: Pair | None) -> tuple[dict[int, Pair], bool]:
        """The message fused per sender for ``key`` = (step, round) (the rule in the module docstring), and
        whether this node is outvoted (then the messages are the refused senders' ones and its own message is
        left out); counts the copies of senders in conflict (``conflicts``), the messages the gate refused
        (``gated``) and the rounds in which the node was ``outvoted``."""
        counters = self.counters
        chosen: dict[int, Pair] = {}
        refused_senders: dict[int, list[Pair]] = {}
        passing_copies = self.passing(received, own)
        for sender, copies in received.items():
            if len(copies) > 1:
                if not counters.conflicts:
                    log.warning("node %d: %d different messages from node %d for step %d round %d: none is fused "
                                "(a forger, or a node with two processes; further cases are counted under "
                                "'conflicts')", self.node, len(copies), sender, key[0], key[1])
                counters.conflicts += len(copies)
                continue
            passing = passing_copies[sender]
            if not passing and not counters.gated:
                log.warning("node %d: the gate refused a message from node %d for step %d round %d; further "
                            "refusals are counted under 'gated'", self.node, sender, key[0], key[1])
            counters.gated += 1 - len(passing)
            if passing:
                chosen[sender] = passing[0]
            elif not copies[0].warm:
                refused_senders[sender] = list(copies)
        if own is None or own.warm:
            return chosen, False
        majority, lifted = self.outvoters(refused_senders, heard=len(received))
        if lifted:
            if not counters.gate_lifted:
                log.warning("node %d: step %d round %d: every neighbour refused for %d rounds; fusing them with "
                            "our own estimate this round (further cases are counted under 'gate_lifted')",
                            self.node, key[0], key[1], OUTVOTED_STREAK)
            counters.gate_lifted += 1
            return {**chosen, **lifted}, False
        if not majority:
            return chosen, False
        if not counters.outvoted:
            log.warning("node %d: step %d round %d: the gate refused %d of %d neighbours that agree with each "
                        "other; fusing theirs without our own estimate (further cases are counted under "
                        "'outvoted')", self.node, key[0], key[1], len(majority), len(received))
        counters.outvoted += 1
        return majority, True

    def outvoters(self, refused: dict[int, list[Pair]], heard: int) -> tuple[dict[int, Pair], dict[int, Pair]]:
        """The refused senders' messages when they outvote this node, or else when the node lifts its gate
        after a streak of refusals (module docstring): ``(outvoting, lifted)``, at most one of them non-empty."""
        all_refused = bool(refused) and len(refused) == heard
        self.refused_streak = self.refused_streak + 1 if all_refused else 0
        single = {j: copies[0] for j, copies in refused.items() if len(copies) == 1}
        if len(single) >= 2 and 2 * len(single) > heard:
            pairs = list(single.values())
            if all(self.gate(a, b) for i, a in enumerate(pairs) for b in pairs[i + 1:]):
                self.refused_streak = 0
                return single, {}
        if single and self.refused_streak >= OUTVOTED_STREAK:
            self.refused_streak = 0
            return {}, single
        return {}, {}
