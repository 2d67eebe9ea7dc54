"""Paper 2's fusion rules: consensus on information and moments, then inverse or fast covariance intersection.

Every rule here forwards the node's scan to its neighbours first (``exchanges_scans``: the local filter, e.g.
``srcif``, updates with its own and its neighbours' measurements, paper 2 Section 2.2), then fuses:

- ``dce-ici`` (the paper's method, Algorithm 1): L rounds of average consensus on four variables, the
  information pair ``(Y, y)`` and the moment pair ``(P, x)`` (paper 2 eqs. 52-61, "parallel consensus
  iteration"), then at each node the distributed multi-estimate ICI (eqs. 62-63)
  ``Y_F = N Ybar - (N - 1) Pbar^-1``, ``y_F = N ybar - (N - 1) Pbar^-1 xbar`` with N the network size.
- ``dce-fci``: L rounds of consensus on ``(c Y, c y)`` and ``c = tr(Y)``, then ``Y_F = mean(cY) / mean(c)``:
  covariance intersection with the information-trace weights (weights proportional to the trace of the
  information matrix, paper 2 eq. 41: :func:`~zentrack.fusion.covariance_intersection.information_trace_weights`) over
  the network, consistent for any number of rounds (CI with convex weights).
- ``diff-ici`` / ``diff-fci``: one round over the neighbourhood (diffusion) with uniform weights: multi-
  estimate ICI of the n_i estimates a node holds (own and neighbours', N = n_i) / fast CI of them.
- ``local``: no fusion at all (each node keeps its own estimate; the paper's "Local").

``rounds = "auto"`` stands for L* = ln(N - 1) / ln(1 / lambda_2) of the consensus weights, at least the graph's
diameter (:func:`zentrack.fusion.consensus_weights.consensus_rounds`); it needs the whole graph, so the run's setup
resolves it (:func:`resolve_rounds`) before any node is configured. A round whose messages are late is fused
over what arrived, rows renormalised (:func:`~zentrack.fusion.covariance_intersection.renormalise_rows`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..covariance_intersection import ci_fuse, information_trace, mix_information, renormalise_rows
from ..defaults import MAX_ROUNDS
from ..ici import ici_from_averages
from ..linalg import GaussianState, InformationPair, from_information, mat_vec, spd_inverse
from ..registry import Param
from ..scan import Scan
from .base import RELAY_SCANS, RULE_REGISTRY, FusionRule, RoundContribution

Array = np.ndarray


def _one_block(names: Sequence[str], rule: str) -> None:
    if list(names) != ["state"]:
        raise ValueError(f"fusion rule {rule!r} fuses one Gaussian block 'state', got blocks {sorted(names)}")


class _ConsensusRule(FusionRule):
    """L rounds of (weighted) averaging of the rule's message blocks; subclasses say what is averaged and how
    an estimate is made of the averages."""

    exchanges_scans = True
    #: "network": consensus weights over the graph, N = network size; "neighbourhood": one round, uniform
    #: weights over the node and its neighbours, N = the estimates a node fuses
    scope = "network"

    def __init__(self, rounds: int | str = "auto", relay_scans: bool = False) -> None:
        if not (rounds == "auto" or (isinstance(rounds, int) and 1 <= rounds <= MAX_ROUNDS)):
            raise ValueError(f"rounds must be 'auto' or 1..{MAX_ROUNDS}, got {rounds!r}")
        self._rounds = rounds
        self.relays_scans = bool(relay_scans)
        self.network_size: int | None = None

    def rounds(self, step: int) -> int:
        if self._rounds == "auto":
            raise ValueError(f"fusion rule {self.name!r}: rounds = 'auto' is resolved from the whole graph "
                             "(zentrack.fusion.rules.consensus.resolve_rounds) before the rule runs")
        return int(self._rounds)

    def network_weights(self, weights: Array, adjacency: Array) -> Array:
        """The consensus weights (network scope) or uniform weights over each neighbourhood; also records N."""
        self.network_size = int(np.shape(weights)[-1])
        if self.scope == "network":
            return weights
        near = (np.asarray(adjacency) != 0) | np.eye(self.network_size, dtype=bool)
        return near / near.sum(axis=-1, keepdims=True)

    def _average(self, weights: Array, messages: Mapping[str, InformationPair], present: Array | None
                 ) -> dict[str, InformationPair]:
        w = renormalise_rows(weights, present)
        return {name: mix_information(w, pair) for name, pair in messages.items()}

    def _count(self, weights: Array, present: Array | None) -> Array:
        """N per receiver ``(R|1, receivers)``: the network size, or the estimates each receiver fuses."""
        w = np.asarray(weights, dtype=float)
        if self.scope == "network":
            if self.network_size is None:
                raise ValueError(f"fusion rule {self.name!r}: network_weights() was not called (N unknown)")
            return np.full(w.shape[:-1] if w.ndim == 3 else (1,) + w.shape[:-1], float(self.network_size))
        used = (w > 0) if present is None else (w > 0) & present
        return used.sum(axis=-1).astype(float).reshape((-1,) + used.shape[-2:-1])

    def mix(self, round: int, weights: Array, messages: Mapping[str, InformationPair], present: Array | None,
            fused: Mapping[str, GaussianState] | None = None) -> dict[str, InformationPair]:
        """Round ``round + 1``'s message: this round's averages (paper 2 eq. 52)."""
        return self._average(weights, messages, present)


class ConsensusICI(_ConsensusRule):
    """``dce-ici`` (and ``diff-ici`` with ``scope = "neighbourhood"``): see the module docstring."""

    name = "dce-ici"

    def message_dims(self, block_dims: Mapping[str, int]) -> dict[str, int]:
        _one_block(list(block_dims), self.name)
        return {"state": block_dims["state"], "moment": block_dims["state"]}

    def share(self, round: int, blocks: Mapping[str, InformationPair], scans: Sequence[Scan] = ()) -> RoundContribution:
        """``(Y, y)`` and ``(P, x) = (Y^-1, Y^-1 y)`` (the four consensus variables, paper 2 eqs. 58-61)."""
        _one_block(list(blocks), self.name)
        info = blocks["state"]
        cov = spd_inverse(info.matrix)
        moment = InformationPair(cov, mat_vec(cov, info.vector))
        return RoundContribution({"state": info, "moment": moment}, list(scans))

    def message_estimate(self, round: int, blocks: Mapping[str, tuple[Array, Array]]) -> tuple[Array, Array] | None:
        """Round 1's ``state`` block is the node's own estimate; later rounds carry consensus averages."""
        return blocks.get("state") if round == 1 else None

    def combine(self, round: int, weights: Array, messages: Mapping[str, InformationPair],
                present: Array | None = None) -> dict[str, GaussianState]:
        """The averages of this round, fused by ICI (paper 2 eqs. 62-63,
        :func:`~zentrack.fusion.ici.ici_from_averages`)."""
        avg = self._average(weights, messages, present)
        state, moment = avg["state"], avg["moment"]
        fused = ici_from_averages(state.matrix, state.vector, moment.matrix, moment.vector,
                                  self._count(weights, present), check=False)
        return {"state": from_information(fused)}


class DiffusionICI(ConsensusICI):
    name = "diff-ici"
    scope = "neighbourhood"


class ConsensusFastCI(_ConsensusRule):
    """``dce-fci`` (and ``diff-fci``): consensus on ``(tr(Y) Y, tr(Y) y)`` and ``tr(Y)``, then CI."""

    name = "dce-fci"

    def message_dims(self, block_dims: Mapping[str, int]) -> dict[str, int]:
        _one_block(list(block_dims), self.name)
        return {"state": block_dims["state"], "trace": 1}

    def share(self, round: int, blocks: Mapping[str, InformationPair], scans: Sequence[Scan] = ()) -> RoundContribution:
        """The trace-weighted information pair and the trace (the information-trace weights' unnormalised
        weight, paper 2 eq. 41)."""
        _one_block(list(blocks), self.name)
        info = blocks["state"]
        c = information_trace(info.matrix)[..., None]
        return RoundContribution({"state": InformationPair(c[..., None] * info.matrix, c * info.vector),
                                  "trace": InformationPair(c[..., None], c)}, list(scans))

    def message_estimate(self, round: int, blocks: Mapping[str, tuple[Array, Array]]) -> tuple[Array, Array] | None:
        """Round 1's estimate is the ``state`` block over its trace; later rounds carry consensus averages."""
        if round != 1 or "state" not in blocks or "trace" not in blocks:
            return None
        c = float(np.ravel(blocks["trace"][1])[0])
        return (blocks["state"][0] / c, blocks["state"][1] / c) if c > 0 else None

    def combine(self, round: int, weights: Array, messages: Mapping[str, InformationPair],
                present: Array | None = None) -> dict[str, GaussianState]:
        """CI with the information-trace weights over the averages: ``sum_j a_j c_j Y_j / sum_j a_j c_j``."""
        avg = self._average(weights, messages, present)
        c = avg["trace"].vector  # (..., 1)
        return {"state": from_information(InformationPair(avg["state"].matrix / c[..., None], avg["state"].vector / c))}


class DiffusionFastCI(ConsensusFastCI):
    name = "diff-fci"
    scope = "neighbourhood"


class LocalOnly(FusionRule):
    """``local``: scans are shared, estimates are not fused (each node keeps its own: the paper's Local)."""

    name = "local"
    exchanges_scans = True

    def message_estimate(self, round: int, blocks: Mapping[str, tuple[Array, Array]]) -> tuple[Array, Array] | None:
        return None  # neighbours' estimates get weight 0: nothing to gate

    def network_weights(self, weights: Array, adjacency: Array) -> Array:
        return np.eye(np.shape(weights)[-1])

    def combine(self, round: int, weights: Array, messages: Mapping[str, InformationPair],
                present: Array | None = None) -> dict[str, GaussianState]:
        w = renormalise_rows(weights, present)
        return {name: ci_fuse(w, pair) for name, pair in messages.items()}


def resolve_rounds(rule: str, params: Mapping[str, object], weights: Array, adjacency: Array) -> dict[str, object]:
    """``params`` with ``rounds = "auto"`` replaced by the graph's L* (at least its diameter)."""
    if params.get("rounds") != "auto":
        return dict(params)
    from ..consensus_weights import consensus_rounds

    return {**params, "rounds": int(min(consensus_rounds(weights, adjacency), MAX_ROUNDS))}


_ROUNDS = Param("rounds", int, "auto", lo=1, hi=MAX_ROUNDS, keywords=("auto",),
                help="consensus rounds per step ('auto': L* of the graph's weights, at least its diameter)")
RULE_REGISTRY.register("dce-ici", ConsensusICI, (_ROUNDS, RELAY_SCANS),
                       "paper 2 DCE-ICI: scans shared, L rounds of consensus on (Y, y, P, x), inverse CI")
RULE_REGISTRY.register("dce-fci", ConsensusFastCI, (_ROUNDS, RELAY_SCANS),
                       "paper 2 DCE-FCI: scans shared, L rounds of consensus, CI with trace (fast CI) weights")


def _diff_ici(relay_scans: bool = False) -> DiffusionICI:
    return DiffusionICI(rounds=1, relay_scans=relay_scans)


def _diff_fci(relay_scans: bool = False) -> DiffusionFastCI:
    return DiffusionFastCI(rounds=1, relay_scans=relay_scans)


RULE_REGISTRY.register("diff-ici", _diff_ici, (RELAY_SCANS,),
                       "paper 2 Diff-ICI: scans shared, one round, multi-estimate ICI over the neighbourhood")
RULE_REGISTRY.register("diff-fci", _diff_fci, (RELAY_SCANS,),
                       "paper 2 Diff-FCI: scans shared, one round, fast CI over the neighbourhood")
RULE_REGISTRY.register("local", LocalOnly, (), "paper 2 Local: scans shared with the neighbours, no estimate fusion")
