"""One tracker's estimation state, free of I/O: local update, prediction, and CI fusion of received pairs.

The process loop (``node/process.py``) feeds it measurements and neighbours' information pairs and decides
*when* to fuse; this class decides *what* the numbers are, with the same fusion-core calls the batched
simulator makes, so a lockstep cluster reproduces ``zentrack sim`` exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zentrack.fusion.filters import LocalFilter
from zentrack.fusion.fusion_rules import ci_fuse
from zentrack.fusion.linalg import GaussianState, InformationPair, to_information
from zentrack.fusion.scenario import ScenarioData
from zentrack.fusion.simulator import build_filter

#: a node whose prior is more than this many steps old (a freeze, a cut link, a truth stall) warms up: it
#: prefers its neighbours' fresh pairs to its own prediction, which it still shares flagged ``warm``
MAX_COAST_STEPS = 5
#: a prior older than this (a very long freeze) is dropped instead of predicted forward
MAX_CATCH_UP_STEPS = 3000


@dataclass
class Pair:
    """An information pair (Y, y) = (P^-1, P^-1 x) for one step, as sent on ``prior/<i>``."""

    step: int
    matrix: np.ndarray
    vector: np.ndarray
    warm: bool = False  #: the sender had no recent measurement: its own prediction, not a fresh estimate


class Tracker:
    """Node ``node_id`` of ``scn``: its sensor, noise, neighbours and weight row, and its current prior."""

    def __init__(self, scn: ScenarioData, node_id: int, kind: str = "teskf", qbar: float = 1e-6,
                 theta: float | None = None) -> None:
        if not 0 <= node_id < scn.nodes:
            raise ValueError(f"node id {node_id} is outside the scenario's 0..{scn.nodes - 1}")
        self.id = node_id
        self.filter: LocalFilter = build_filter(scn, kind, qbar=qbar, theta=theta)
        self.sensors = scn.sensors[node_id : node_id + 1, None, :]
        self.noise_cov = scn.noise_cov[node_id : node_id + 1]
        self.weights = scn.weights[node_id]
        self.neighbours = [int(j) for j in np.flatnonzero(scn.adjacency[node_id])]
        self._x0 = scn.x0_estimate[0:1]
        self._p0 = scn.p0
        self._lumped_var = scn.lumped_var
        self.prior: GaussianState | None = None
        self.prior_step: int | None = None
        self.state_dim = self.filter.state_dim
        self.kinematic_dim = self.filter.kinematic_dim
        self.measurement_dim = scn.measurements.shape[-1]

    def cold_start(self, step: int = 0) -> None:
        """The configured initial prior (Assumption 1) for ``step``."""
        self.prior = self.filter.initial_state(self._x0, self._p0, self._lumped_var)
        self.prior_step = step

    def catch_up(self, step: int) -> bool:
        """Bring the prior to ``step`` by prediction alone (after missed steps). False if there is none
        or it is older than :data:`MAX_CATCH_UP_STEPS` (then it is dropped)."""
        if self.prior is None or self.prior_step is None or self.prior_step > step:
            return False
        if step - self.prior_step > MAX_CATCH_UP_STEPS:
            self.prior, self.prior_step = None, None
            return False
        while self.prior_step < step:
            self.prior = self.filter.predict(self.prior)
            self.prior_step += 1
        return True

    def update(self, z: np.ndarray | None) -> GaussianState:
        """Local correction of the current prior with ``z`` (None: coast, the posterior is the prior)."""
        assert self.prior is not None
        if z is None:
            return self.prior
        return self.filter.update(self.prior, z[None, :], self.sensors, self.noise_cov)

    def kinematic(self, state: GaussianState) -> GaussianState:
        return self.filter.kinematic(state)

    def predict_pair(self, post: GaussianState, step: int) -> Pair:
        """Local time update and the information pair to broadcast for ``step`` (Algorithm 2 lines 8-9)."""
        pair = to_information(self.filter.predict(post))
        return Pair(step, pair.matrix[0], pair.vector[0])

    def own_pair(self, step: int) -> Pair | None:
        """The current prior as an information pair for ``step`` (predicted forward if needed), flagged warm:
        what a warming node shares so that a network whose nodes all warm at once can still fuse."""
        if not self.catch_up(step) or self.prior_step != step:
            return None
        pair = to_information(self.prior)
        return Pair(step, pair.matrix[0], pair.vector[0], warm=True)

    def fuse(self, step: int, own: Pair | None, received: dict[int, Pair]) -> int:
        """CI-fuse ``own`` and the neighbours' pairs for ``step`` (row renormalised over what is present).

        Pairs from nodes that are not configured neighbours are ignored; so is every pair flagged ``warm``
        when ``own`` is fresh (a stale prediction only dilutes a fresh estimate). Without any pair the prior
        is dropped (the node will warm-start). Returns the number of pairs fused.
        """
        if own is not None and not own.warm:
            received = {j: p for j, p in received.items() if not p.warm}
        senders, mats, vecs = [], [], []
        if own is not None:
            senders.append(self.id)
            mats.append(own.matrix)
            vecs.append(own.vector)
        for j in sorted(received):
            if j in self.neighbours and received[j].step == step:
                senders.append(j)
                mats.append(received[j].matrix)
                vecs.append(received[j].vector)
        if not senders:
            self.prior, self.prior_step = None, None
            return 0
        w = self.weights[senders][None, :]
        pair = InformationPair(np.stack(mats)[None], np.stack(vecs)[None])
        fused = ci_fuse(w, pair, np.ones_like(w, dtype=bool))
        self.prior = GaussianState(fused.mean[0], fused.cov[0])
        self.prior_step = step
        return len(senders)
