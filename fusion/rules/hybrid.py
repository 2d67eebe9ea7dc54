"""Hybrid consensus on measurements and information in one round per step (``hcmci``).

Battistelli, Chisci, Mugnai, Farina, Graziano, "Consensus-based linear and nonlinear filtering", IEEE TAC
60(5), 2015, Table III (HCMCI), with L = 1: node i fuses the neighbours' prior information pairs with the
consensus weights ``pi_ij`` (CI, as paper 0 Algorithm 2 line 10) and adds the neighbours' measurement
information averaged with the same weights and scaled by ``omega``::

    Omega_i = sum_j pi_ij Omega_j^-  +  omega * sum_j pi_ij H_j' R_j^-1 H_j
    q_i     = sum_j pi_ij q_j^-      +  omega * sum_j pi_ij H_j' R_j^-1 z_j

The measurement part is the local update with the forwarded scans, each scan's noise covariance divided by
``c_ij = omega pi_ij`` (:meth:`HybridConsensus.scan_information`), so a nonlinear filter linearises each
scan at the fused prior (the paper's extended variant). The prior part is done at the end of the previous
step on the predictions, as every diffusion rule here does, which is the same sum.

``omega``: "consistent" (the default) takes, per node, the largest value with every ``c_ij <= 1``
(``omega = 1 / max_j pi_ij``): no measurement is counted more than once, and with a CI prior the fused
covariance stays an upper bound of the error covariance. A number sets it for every node; the paper's
``omega = N`` (network size) makes the averaged measurement information unbiased once consensus has
converged, which one round does not do: it over-counts the neighbours' scans and is over-confident.
"""
from __future__ import annotations

import numpy as np

from ..registry import Param
from .base import RULE_REGISTRY
from .ci import CovarianceIntersection

Array = np.ndarray


class HybridConsensus(CovarianceIntersection):
    """HCMCI with one round: CI on the priors with ``pi_ij``, neighbours' scans weighted ``omega pi_ij``."""

    name = "hcmci"

    def __init__(self, omega: str | float = "consistent") -> None:
        super().__init__(rounds=1, share_scans=True)
        if omega != "consistent" and not (isinstance(omega, (int, float)) and np.isfinite(omega) and omega >= 1):
            raise ValueError(f"omega must be 'consistent' or a number >= 1, got {omega!r}")
        self.omega = omega

    def scan_information(self, row: Array, receiver: int) -> Array:
        row = np.asarray(row, dtype=float)
        if not np.isclose(row.sum(), 1.0) or np.any(row < 0):
            raise ValueError(f"hcmci needs a row-stochastic weight row, got {np.round(row, 4).tolist()}")
        omega = 1.0 / row.max() if self.omega == "consistent" else float(self.omega)
        return omega * row  # c_ij = omega pi_ij (0 where j is not a neighbour: its scan never arrives)


RULE_REGISTRY.register(
    "hcmci", HybridConsensus,
    (Param("omega", float, "consistent", lo=1.0, keywords=("consistent",),
           help="measurement scale: 'consistent' (1 / max_j pi_ij, every scan counted at most once) or a number >= 1"),),
    "hybrid consensus on measurements and information, one round (Battistelli et al. 2015): CI on the priors, "
    "the neighbours' scans with information omega * pi_ij",
)
