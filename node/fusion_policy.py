"""Which of the neighbours' round messages a tracker fuses: the gate, equivocations and the outvote rule.

Each (step, round, sender) keeps up to ``MAX_COPIES`` distinct messages (admission, ``node/admission.py``).
When a round is fused, each copy goes through the tracker's gate against the node's own message of that round
(a chi-square test with the covariance-intersection bound, ``fusion/gate.py``), and per sender:

- exactly one copy passes: it is fused;
- none passes: the sender is left out of the round (counted ``gated``);
- two or more distinct copies pass: the sender is left out of the round (counted ``equivocations``).

The gate trusts the node's own message, so a node whose own estimate has gone wrong (inconsistent after a
freeze or an overloaded stretch) would refuse every honest neighbour from then on and never come back. So a
node that the gate shows to be the odd one out is ``outvoted``: it fuses the refused neighbours' messages
without its own message in that round (counted ``outvoted``) when either

- at least two senders, more than half of those heard in the round, had every copy refused, each sent one
  copy, and those copies pass the gate against each other (they agree with each other, not with us); or
- every sender heard was refused in ``OUTVOTED_STREAK`` consecutive rounds: with a single neighbour nobody can
  tell which of the two is wrong (both see the same refusals), so the node lifts its gate for that round and
  fuses the refused messages with its own (counted ``gate_lifted``); CI keeps the result consistent if
  either was, and the two estimates meet.

In realtime a forger cannot trigger this: a sender is "refused" only when none of its copies passes, and the
real copy of a node that is right passes; only a node's own wrong estimate, or an adversary who can also
suppress the real messages, makes every copy fail. Lockstep fuses once every neighbour has sent any copy, so
forged copies that arrive before most neighbours' real ones, and agree with each other, can outvote a node for
a round: lockstep is a study mode for a trusted bus (``--secure`` where forgers are possible).

Why this rule: without authentication (insecure mode) a receiver cannot tell the sender's copy from a forged
one, so arrival order must not decide. A forger that sends first cannot evict the real message (the real one
is not refused as a duplicate), a grossly false copy never passes the gate, and a plausible false copy can at
most remove that neighbour from one round: CI over fewer neighbours stays consistent. In realtime a round
counts a sender as in once one of its copies passes the gate, so a forged early copy does not make the node
fuse before the real one arrives; lockstep waits for any copy (nothing there ever times out).
"""
from __future__ import annotations

import logging
from collections.abc import Callable

from zentrack.node.counters import Counters
from zentrack.node.tracker import Pair

log = logging.getLogger("zentrack.node")

#: consecutive rounds in which the gate refused every sender heard, after which the node is outvoted
OUTVOTED_STREAK = 5

#: the copies received per sender for one (step, round)
Copies = dict[int, list[Pair]]


class FusionPolicy:
    """Node ``node``'s choice of messages per round; ``gate(own, other)`` is the tracker's gate."""

    def __init__(self, node: int, lockstep: bool, gate: Callable[[Pair, Pair], bool], counters: Counters) -> None:
        self.node, self.lockstep, self.gate, self.counters = node, lockstep, gate, counters
        self.refused_streak = 0  # consecutive rounds in which the gate refused every sender heard

    def passing(self, received: Copies, own: Pair | None) -> Copies:
        """Per sender, the copies of its round message that pass the gate against ``own`` (checked once each)."""
        out = {}
        for sender, copies in received.items():
            if own is None:  # nothing to check against (a warm start): every copy counts, nothing is cached
                out[sender] = list(copies)
                continue
            for c in copies:
                if c.gated is None:
                    c.gated = self.gate(own, c)
            out[sender] = [c for c in copies if c.gated]
        return out

    def heard(self, received: Copies, own: Pair | None) -> set[int]:
        """The senders whose round message is in: any copy in lockstep, a copy that passes the gate in realtime."""
        if self.lockstep:
            return set(received)
        return {j for j, passing in self.passing(received, own).items() if passing}

    def chosen(self, key: tuple[int, int], received: Copies, own: Pair | None) -> tuple[dict[int, Pair], bool]:
        """The message fused per sender for ``key`` = (step, round) (the rule in the module docstring), and
        whether this node is outvoted (then the messages are the refused senders' ones and its own message is
        left out); counts the messages the gate refused (``gated``), the senders left out for sending two that
        pass (``equivocations``) and the rounds in which the node was ``outvoted``."""
        counters = self.counters
        chosen: dict[int, Pair] = {}
        refused_senders: dict[int, list[Pair]] = {}
        for sender, passing in self.passing(received, own).items():
            refused = len(received[sender]) - len(passing)
            if refused and not counters.gated:
                log.warning("node %d: the gate refused a message from node %d for step %d round %d; further "
                            "refusals are counted under 'gated'", self.node, sender, key[0], key[1])
            counters.gated += refused
            if len(passing) == 1:
                chosen[sender] = passing[0]
            elif passing:
                counters.equivocations += 1
                log.warning("node %d: %d different messages from node %d for step %d round %d pass the gate; "
                            "none is fused", self.node, len(passing), sender, key[0], key[1])
            elif not all(c.warm for c in received[sender]):
                refused_senders[sender] = [c for c in received[sender] if not c.warm]
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
