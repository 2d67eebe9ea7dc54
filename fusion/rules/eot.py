"""Paper 4's consensus rules for extended objects as tracker processes run them: ``eot-ci`` and ``eot-cm``.

Both fuse *posteriors* (``fuses_posterior``: the paper's Algorithms 2-3 run the consensus between the
correction and the time update) with ``rounds`` = L rounds of the convex combination (Definition 1) per
scan.  The paper runs the L rounds after every single point (``n_k x L`` exchanges per scan,
:mod:`zentrack.study.eot_network` reproduces that for the benchmark); a tracker runs them once per scan,
after its local correction with all of its scan's points (sequential MEM information-filter update), so a
scan costs L exchanges whatever the number of points.

- ``eot-ci`` (consensus on information, Algorithm 2 step 2): every round ``Omega_s <- sum_j pi_sj Omega_j``,
  ``q_s <- sum_j pi_sj q_j`` on the whole state (the kinematic and extent blocks are independent, so this is
  the paper's blockwise combination).  The orientation is an angle: before averaging, each sender's
  ``alpha`` is moved by a multiple of 2 pi to within pi of the receiver's own (``q`` re-formed as
  ``q_j + Omega_j[:, a] d``), so the fused orientation continues the node's own and never jumps at +-pi.
- ``eot-cm`` (consensus on measurements, Algorithm 3, eqs. 25-28): the filter shares its posterior and the
  scan's information increment; the rule averages the increments for L rounds and each node adds ``omega``
  times the result to its own prior information (``omega = |G|``, the node count, ref. [36]).  A receiver's
  own message is at sender index ``i`` for receiver ``i`` (:mod:`zentrack.fusion.rules.base`).
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..covariance_intersection import renormalise_rows
from ..defaults import MAX_ROUNDS
from ..linalg import GaussianState, InformationPair, from_information, spd_inverse
from ..measurement import wrap_angle
from ..registry import Param
from .base import RULE_REGISTRY, FusionRule, RoundContribution

Array = np.ndarray

#: the orientation's index in the extended-object state [m1, m2, v1, v2, alpha, l1, l2]
ALPHA_INDEX = 4


def _weights(weights: Array, present: Array | None, runs: int) -> Array:
    w = renormalise_rows(weights, present) if present is not None else np.asarray(weights, dtype=float)
    return np.broadcast_to(w, (runs,) + w.shape[-2:]) if w.ndim == 2 else w


def aligned_average(weights: Array, pair: InformationPair, index: int) -> InformationPair:
    """``sum_j w_ij (Omega_j, q_j)`` per receiver with component ``index`` of every sender's mean moved by a
    multiple of 2 pi to within pi of the receiver's own (sender ``i`` for receiver ``i``).  ``weights (R, recv, send)``,
    ``pair (R, send, n, n) / (R, send, n)``."""
    mean = np.einsum("rsij,rsj->rsi", spd_inverse(pair.matrix), pair.vector)
    angle = mean[..., index]  # (R, send)
    ref = angle[:, : weights.shape[1]]  # each receiver's own angle (sender i for receiver i): no jump at +-pi
    shift = ref[:, :, None] + wrap_angle(angle[:, None, :] - ref[:, :, None]) - angle[:, None, :]  # (R, recv, send)
    vectors = pair.vector[:, None] + pair.matrix[:, None, :, :, index] * shift[..., None]  # (R, recv, send, n)
    return InformationPair(np.einsum("rij,rjkl->rikl", weights, pair.matrix), np.einsum("rij,rijk->rik", weights, vectors))


class ConsensusOnInformation(FusionRule):
    """``eot-ci``: L rounds of the convex combination of posterior information per scan (module docstring)."""

    name = "eot-ci"
    fuses_posterior = True

    def __init__(self, rounds: int = 1, angle_index: int = ALPHA_INDEX) -> None:
        if rounds < 1:
            raise ValueError(f"rounds must be >= 1, got {rounds}")
        self._rounds, self.angle_index = int(rounds), int(angle_index)

    def rounds(self, step: int) -> int:
        return self._rounds

    def message_estimate(self, round: int, blocks: Mapping[str, tuple[Array, Array]]) -> tuple[Array, Array] | None:
        """Not gated: an ellipse's orientation is defined modulo pi, so two equal shapes can differ by pi in
        alpha, and relays' early-round estimates legitimately sit far from a sensor's."""
        return None

    def share(self, round: int, blocks: Mapping[str, InformationPair], scans=()) -> RoundContribution:
        if "state" not in blocks:
            raise ValueError(f"{self.name}: the filter shares no 'state' block (got {sorted(blocks)})")
        return RoundContribution({"state": blocks["state"]})

    def message_dims(self, block_dims: Mapping[str, int]) -> dict[str, int]:
        return {"state": block_dims["state"]}

    def combine(self, round: int, weights: Array, messages: Mapping[str, InformationPair],
                present: Array | None = None) -> dict[str, GaussianState]:
        pair = messages["state"]
        w = _weights(weights, present, pair.vector.shape[0])
        return {"state": from_information(aligned_average(w, pair, self.angle_index))}


class ConsensusOnMeasurements(FusionRule):
    """``eot-cm``: L rounds of averaging the scan's information increments, then ``omega`` times the average
    added to the own prior information (module docstring)."""

    name = "eot-cm"
    fuses_posterior = True

    def __init__(self, rounds: int = 1, omega: float = 20.0) -> None:
        if rounds < 1:
            raise ValueError(f"rounds must be >= 1, got {rounds}")
        if not (np.isfinite(omega) and omega > 0):
            raise ValueError(f"omega must be positive, got {omega}")
        self._rounds, self.omega = int(rounds), float(omega)

    def rounds(self, step: int) -> int:
        return self._rounds

    def message_estimate(self, round: int, blocks: Mapping[str, tuple[Array, Array]]) -> tuple[Array, Array] | None:
        return None  # increments and priors of other nodes, not estimates to compare with the own one

    def share(self, round: int, blocks: Mapping[str, InformationPair], scans=()) -> RoundContribution:
        if "state" not in blocks or "increment" not in blocks:
            raise ValueError(f"{self.name}: needs a filter that shares its scan's 'increment' with its 'state' "
                             f"(e.g. mem-if); got blocks {sorted(blocks)}")
        post, inc = blocks["state"], blocks["increment"]
        return RoundContribution({"prior": InformationPair(post.matrix - inc.matrix, post.vector - inc.vector),
                                  "increment": inc})

    def message_dims(self, block_dims: Mapping[str, int]) -> dict[str, int]:
        return {"prior": block_dims["state"], "increment": block_dims["state"]}

    @staticmethod
    def _own(pair: InformationPair, receivers: int) -> InformationPair:
        return InformationPair(pair.matrix[:, :receivers], pair.vector[:, :receivers])

    def mix(self, round: int, weights: Array, messages: Mapping[str, InformationPair], present: Array | None,
            fused: Mapping[str, GaussianState] | None = None) -> dict[str, InformationPair]:
        inc = messages["increment"]
        w = _weights(weights, present, inc.vector.shape[0])
        averaged = InformationPair(np.einsum("rij,rjkl->rikl", w, inc.matrix), np.einsum("rij,rjk->rik", w, inc.vector))
        return {"prior": self._own(messages["prior"], w.shape[1]), "increment": averaged}

    def combine(self, round: int, weights: Array, messages: Mapping[str, InformationPair],
                present: Array | None = None) -> dict[str, GaussianState]:
        mixed = self.mix(round, weights, messages, present)
        prior, inc = mixed["prior"], mixed["increment"]
        return {"state": from_information(InformationPair(prior.matrix + self.omega * inc.matrix,
                                                          prior.vector + self.omega * inc.vector))}


RULE_REGISTRY.register(
    "eot-ci", ConsensusOnInformation,
    (Param("rounds", int, 1, lo=1, hi=MAX_ROUNDS, help="consensus rounds per scan (L)"),
     Param("angle_index", int, ALPHA_INDEX, lo=0, hi=63, help="the state component averaged as an angle")),
    "paper 4 consensus on information: L convex-combination rounds on the posterior information per scan",
)
RULE_REGISTRY.register(
    "eot-cm", ConsensusOnMeasurements,
    (Param("rounds", int, 1, lo=1, hi=MAX_ROUNDS, help="consensus rounds per scan (L)"),
     Param("omega", float, 20.0, lo=1e-9, help="the scale of the averaged increments: the node count |G|")),
    "paper 4 consensus on measurements: L rounds on the scans' information increments, omega x the average added",
)
