"""The fusion-rule interface: what nodes share in each round of a step and how a receiver combines it.

One step of a node with a rule of L = ``rounds(step)`` rounds (paper 0 Algorithm 2 lines 9-10, repeated)::

    message = rule.share(1, node_filter.blocks(shared))        # round 1: the prediction's information pairs
    for l in 1..L:
        fused = rule.combine(l, weights, stacked messages)     # own message first (stack_messages)
        if l < L:
            message = rule.mix(l, weights, stacked messages, present, fused)   # round l + 1's message
    prior = node_filter.from_fused(fused, like=shared)         # after round L: the next prior

By default a message (a :class:`RoundContribution`) is the node's information blocks and the next round's
message is the fused estimate in information form (CI repeated). Consensus rules (paper 2) share other variables:
:meth:`FusionRule.share` turns the filter's blocks into the rule's message blocks (e.g. ``(Y, y)`` and ``(P, x)``,
named by :meth:`FusionRule.message_dims`), :meth:`FusionRule.mix` averages them round after round, and
:meth:`FusionRule.combine` turns the averages into an estimate (after every round, so a node that must stop early
still has one).

``combine`` works on stacks exactly like :func:`~zentrack.fusion.covariance_intersection.ci_fuse`: ``weights``
``(R, receivers, senders)`` or ``(receivers, senders)``, per block an
:class:`~zentrack.fusion.linalg.InformationPair` of ``(R, senders, n, n)`` / ``(R, senders, n)``, and an
optional ``present`` mask of the pairs that arrived.  A tracker process calls it with R = 1, one receiver and
its S senders (own first); the batched simulator with the whole network (receivers = senders = M).

A rule with ``exchanges_scans = True`` (paper 2 forwards its scans to the neighbours before the local update)
puts them into :attr:`RoundContribution.scans`; with ``relays_scans`` as well, the message it fuses comes from
the prior updated with the scans of the two-hop neighbourhood (each node relays its neighbours' scans).  A rule
with ``fuses_posterior = True`` (paper 4) is given the local posterior instead of its prediction, and the node
predicts the fused result to get the next prior. A rule that needs each receiver's own message finds it at
sender index ``i`` for receiver ``i``: the batched simulator stacks every node as receiver and sender, a tracker
puts its own message first.  :data:`RULE_REGISTRY` finds rules by name; every module file of this package is
imported when it is first used, so a new rule is one new file.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..linalg import GaussianState, InformationPair, to_information
from ..registry import Param, Registry
from ..scan import Scan

Array = np.ndarray


@dataclass
class RoundContribution:
    """What one node contributes to one round, in process: its information blocks and, for scan-exchanging
    rules, its scans. A tracker puts the blocks on the wire as a
    :class:`~zentrack.transport.messages.RoundMessage` (``prior/<i>``) and the scans as scan messages."""

    blocks: dict[str, InformationPair]
    scans: list[Scan] = field(default_factory=list)


class FusionRule(ABC):
    """A fusion rule with one or more rounds per step (see the module docstring)."""

    name: str = "rule"
    #: True when the rule forwards scans to the neighbours before the local update (paper 2)
    exchanges_scans: bool = False
    #: True when nodes share their *posterior* and the fused estimate is predicted afterwards (paper 4's
    #: consensus on information and on measurements fuse before the time update); False: the usual order,
    #: nodes share their prediction and the fused estimate is the next prior
    fuses_posterior: bool = False
    #: True (rules that exchange scans, ``relay_scans``) when every node also relays its neighbours' scans of
    #: the step once it has them, and shares (round 1) its prior updated with every scan within two hops; its
    #: estimate keeps the one-hop update, made before the relayed scans arrive (see ``relay_scans`` in the
    #: README's "Accuracy against the limit")
    relays_scans: bool = False

    def rounds(self, step: int) -> int:
        """L >= 1, the number of exchange rounds at ``step``."""
        return 1

    def share(self, round: int, blocks: Mapping[str, InformationPair], scans: Sequence[Scan] = ()) -> RoundContribution:
        """The message of round 1 from the filter's information ``blocks`` (unbatched or stacked): by default
        the blocks themselves, and the scans when the rule exchanges scans."""
        return RoundContribution(dict(blocks), list(scans) if self.exchanges_scans else [])

    def message_dims(self, block_dims: Mapping[str, int]) -> dict[str, int]:
        """The blocks (name -> dimension) of this rule's messages for a filter sharing ``block_dims``."""
        return dict(block_dims)

    def mix(
        self,
        round: int,
        weights: Array,
        messages: Mapping[str, InformationPair],
        present: Array | None,
        fused: Mapping[str, GaussianState] | None = None,
    ) -> dict[str, InformationPair]:
        """The message of round ``round + 1`` per receiver, stacked like ``messages`` (``(R, receivers, ...)``):
        by default the fused estimate in information form (``fused``: what :meth:`combine` returned for this
        round, if the caller has it; else it is computed here)."""
        if fused is None:
            fused = self.combine(round, weights, messages, present)
        return {name: to_information(state) for name, state in fused.items()}

    @abstractmethod
    def combine(
        self,
        round: int,
        weights: Array,
        messages: Mapping[str, InformationPair],
        present: Array | None = None,
    ) -> dict[str, GaussianState]:
        """Fuse, per block, the stacked pairs the senders shared in ``round`` (shapes in the module docstring)."""

    def combine_one(self, round: int, weights: Array, messages: Sequence[Mapping[str, tuple[Array, Array]]]
                    ) -> dict[str, GaussianState]:
        """:meth:`combine` for one receiver (a tracker): ``weights`` ``(S,)`` for its S messages (own first), each
        a map of unbatched blocks ``(Y, y)``; every message present. By default the messages are stacked
        into ``(1, S, ...)`` and :meth:`combine` does the work; a rule may override this with a path of
        identical results that avoids the stacking (:class:`~zentrack.fusion.rules.ci.CovarianceIntersection`)."""
        w = np.asarray(weights, dtype=float)[None, :]
        return self.combine(round, w, stack_pairs(messages), np.ones_like(w, dtype=bool))

    def message_estimate(self, round: int, blocks: Mapping[str, tuple[Array, Array]]) -> tuple[Array, Array] | None:
        """The estimate one unbatched round-``round`` message carries, as an information pair ``(Y, y)``, for a
        receiver's gate (:mod:`~zentrack.fusion.gate`) to check against its own message; None when the round's
        messages are not estimates of the state (averages of increments or moments), which are not gated. By
        default the ``state`` block: the filter's own estimate, or a fused one in later rounds."""
        return blocks.get("state")

    def scan_information(self, row: Array, receiver: int) -> Array:
        """For a rule that exchanges scans: per origin node ``j``, the factor ``c_j`` by which ``receiver``
        scales the information of ``j``'s scan in its local update (it divides the scan's noise covariance
        by ``c_j``), from the receiver's row ``(M,)`` of :meth:`network_weights`. By default every scan counts
        in full (measurement sharing)."""
        return np.ones(np.shape(row)[-1])

    def network_weights(self, weights: Array, adjacency: Array) -> Array:
        """The ``(M, M)`` matrix :meth:`combine` gets for a network with diffusion ``weights`` and ``adjacency``
        (by default the diffusion weights)."""
        return weights


#: the parameter of every rule that can relay scans (see :attr:`FusionRule.relays_scans`)
RELAY_SCANS = Param("relay_scans", bool, False,
                    help="also relay the neighbours' scans; the shared prior uses every scan within two hops")


def stack_pairs(messages: Sequence[Mapping[str, tuple[Array, Array]]]) -> dict[str, InformationPair]:
    """Stack one receiver's messages (own first), each a map of unbatched blocks ``(Y, y)``, per block into
    ``(1, S, n, n)`` / ``(1, S, n)`` pairs."""
    return {name: InformationPair(np.stack([m[name][0] for m in messages])[None],
                                  np.stack([m[name][1] for m in messages])[None])
            for name in messages[0]}


def stack_messages(messages: Sequence[RoundContribution]) -> dict[str, InformationPair]:
    """Stack one receiver's messages (own first) per block into ``(1, S, n, n)`` / ``(1, S, n)`` pairs."""
    if not messages:
        raise ValueError("no message to stack (a node always has its own)")
    names = list(messages[0].blocks)
    for msg in messages[1:]:
        if list(msg.blocks) != names:
            raise ValueError(f"messages carry different blocks: {names} and {list(msg.blocks)}")
    return stack_pairs([{name: (p.matrix, p.vector) for name, p in msg.blocks.items()} for msg in messages])


def next_round_blocks(fused: Mapping[str, GaussianState]) -> dict[str, InformationPair]:
    """One receiver's :meth:`FusionRule.combine` output (each block one estimate) back in information form,
    unbatched ``(n, n)`` / ``(n,)``: the blocks it shares in the next round."""
    out = {}
    for name, state in fused.items():
        n = state.mean.shape[-1]
        if state.mean.size != n:
            raise ValueError(f"block {name!r}: expected one fused estimate, got mean shape {state.mean.shape}")
        pair = to_information(GaussianState(state.mean.reshape(1, n), state.cov.reshape(1, n, n)))
        out[name] = InformationPair(pair.matrix[0], pair.vector[0])
    return out


def unstack_message(stacked: Mapping[str, InformationPair]) -> dict[str, InformationPair]:
    """One receiver's :meth:`FusionRule.mix` output ``(1, 1, n, n)`` / ``(1, 1, n)`` per block as the unbatched
    ``(n, n)`` / ``(n,)`` blocks it sends in the next round."""
    out = {}
    for name, pair in stacked.items():
        n = pair.vector.shape[-1]
        if pair.vector.size != n or pair.matrix.size != n * n:
            raise ValueError(f"block {name!r}: expected one receiver's message, got shape {pair.vector.shape}")
        out[name] = InformationPair(pair.matrix.reshape(n, n), pair.vector.reshape(n))
    return out


#: fusion rules by name; a factory is ``factory(**params) -> FusionRule``
RULE_REGISTRY: Registry[FusionRule] = Registry("fusion rule", discover=__package__)


def make_rule(rule: str | FusionRule, params: Mapping[str, object] | None = None) -> FusionRule:
    """A rule instance: ``rule`` itself, or the registered rule of that name built with ``params``."""
    if isinstance(rule, FusionRule):
        if params:
            raise ValueError("parameters go with a rule name, not with a rule instance")
        return rule
    return RULE_REGISTRY.create(rule, params)
