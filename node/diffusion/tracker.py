"""One tracker's estimation state, free of I/O: local update from scans, prediction, and fusion rounds.

Built from the node's own configuration slice (:class:`~zentrack.config.node_config.NodeConfig`): the local
filter and the fusion rule come from their registries by name, so a new seed's filter or rule touches no file
here. The process loop (``node/schedule.py``) feeds it scans and neighbours' round messages and decides *when*
to fuse; this class decides *what* the numbers are, with the same fusion-core calls the batched simulator
makes, so a lockstep cluster reproduces ``zentrack sim`` exactly.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from zentrack.config.node_config import NodeConfig, deferred_generator
from zentrack.fusion.estimates import Estimate, GaussianEstimate
from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext, NodeFilter, make_node_filter
from zentrack.fusion.filters.interval import IntervalPredictor, update_at_times
from zentrack.fusion.gate import ci_gate_passes, gate_threshold, information_mean_cov, innovation_distances
from zentrack.fusion.isolation import fused_alone
from zentrack.fusion.linalg import GaussianState, cholesky_one
from zentrack.fusion.models import make_measurement, make_plant, plant_over
from zentrack.fusion.registry import load_plugins
from zentrack.fusion.rules import FusionRule, make_rule, stack_pairs, unstack_message
from zentrack.fusion.scan import Scan

#: what a filter or fusion rule may raise on extreme but finite input that passed every message check (a pose
#: of 1e150 m, a noise of 1e-300, an information block that contradicts the others): the node refuses the
#: update or the fusion, keeps its own estimate and counts it (``refused``) instead of dying
NUMERIC_ERRORS = (np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError, OverflowError, ValueError)
log = logging.getLogger("zentrack.node")

#: a node whose prior is more than this many steps old (a freeze, a cut link, a truth stall) warms up: it
#: prefers its neighbours' fresh pairs to its own prediction, which it still shares flagged ``warm``
MAX_COAST_STEPS = 5
#: a prior older than this (a very long freeze) is dropped instead of predicted forward
MAX_CATCH_UP_STEPS = 3000
#: sensors of their own: once one sensor's detections have all been outside the validation gate for this long (s of
#: measurement time), the next is taken whatever it says: a tracker that lost its target must not lock its sensor
#: out for good, and a flood of forged detections (rate-limited to a few a period) is not taken for that in 2 s
GATE_LIFT_S = 3.0

Blocks = dict[str, tuple[np.ndarray, np.ndarray]]


@dataclass
class Pair:
    """One round's message for one step: named information pairs (Y, y) = (P^-1, P^-1 x), as sent on
    ``prior/<i>`` (a plain Gaussian filter has the single block ``state``)."""

    step: int
    blocks: Blocks
    warm: bool = False  #: the sender had no recent measurement: its own prediction, not a fresh estimate
    round: int = 1
    raw: bytes = b""  #: the message as received (tells an exact replay from a conflicting copy)
    gated: bool | None = None  #: the receiver's gate verdict, once checked
    #: for the gate, once computed: (an estimate?, its (mean, covariance) or None if not positive definite)
    estimate: tuple[bool, tuple[np.ndarray, np.ndarray] | None] | None = None
    #: the step its sender gave it (sensors of their own: ``step`` is this tracker's it was mapped to)
    sent_step: int | None = None


class Tracker:
    """Node ``cfg.node``: its filter, fusion rule, sensor, neighbours and weight row, and its current prior."""

    def __init__(self, cfg: NodeConfig) -> None:
        load_plugins(cfg.plugins)
        self.cfg = cfg
        self.id = cfg.node
        self.role = cfg.role
        motion = make_plant(cfg.plant, cfg.ts, cfg.plant_params)
        linear = None if cfg.linear_matrix is None else np.asarray(cfg.linear_matrix, dtype=float)
        measurement = make_measurement(cfg.measurement, linear)
        self.measurement = measurement
        self.rng = cfg.rng()
        context = FilterContext(motion, measurement, np.asarray(cfg.p0, dtype=float), cfg.lumped_var, self.rng)
        self.filter: NodeFilter = make_node_filter(cfg.filter, context, cfg.filter_params)
        #: the filter over any interval (sensors of their own: predict to each detection's time)
        self.interval = IntervalPredictor(self.filter, cfg.ts, lambda dt: make_node_filter(
            cfg.filter, FilterContext(plant_over(cfg.plant, cfg.ts, dt, cfg.plant_params), measurement,
                                      context.p0, cfg.lumped_var, self.rng), cfg.filter_params))
        self.rule: FusionRule = make_rule(cfg.fusion, cfg.fusion_params)
        #: returns one scan may hold for this filter: a point-target filter takes one, a clutter or
        #: extended-object filter (registry tag ``scans`` / ``extent``) every one the wire allows (None)
        self.max_returns: int | None = None if FILTER_REGISTRY.entry(cfg.filter).tags & {"scans", "extent"} else 1
        self.neighbours = sorted(cfg.neighbours)
        # the rule's view of this node's weight row (e.g. independent fusion uses the adjacency instead)
        w, adj = np.zeros((cfg.nodes, cfg.nodes)), np.zeros((cfg.nodes, cfg.nodes))
        w[self.id] = cfg.weight_array()
        adj[self.id, self.neighbours] = 1.0
        self.weights = np.asarray(self.rule.network_weights(w, adj))[self.id]
        self.scan_factor = self.rule.scan_information(self.weights, self.id)  # (M,): per origin node
        if cfg.sensor is not None:
            self.sensor_position = np.asarray(cfg.sensor.position, dtype=float)
            self.noise_cov = np.asarray(cfg.sensor.noise_cov, dtype=float)
        self.x0: np.ndarray | None = None
        self.prior: Estimate | None = None
        self.prior_step: int | None = None
        self.state_dim = self.filter.state_dim
        self.kinematic_dim = self.filter.kinematic_dim
        self.measurement_dim = cfg.measurement_dim
        #: block name -> dimension of the information pairs exchanged (known once the start is)
        self.block_dims: dict[str, int] = self.rule.message_dims({name: self.state_dim for name in self.filter.block_names})
        self.gate_false_rejection = float(cfg.gate)
        #: the gate's bound per message dimension: the slice's, else computed when first needed
        self._gate_thresholds: dict[int, float] = {d: float(v) for d, v in enumerate(cfg.gate_thresholds, start=1)}
        self.shared: Estimate | None = None  # the estimate whose blocks this node shared last
        self.refused = {"update": 0, "fusion": 0}  # unusable results kept out (NUMERIC_ERRORS)
        #: sensors of their own: detections outside the validation gate, and since when each sensor's have all been
        self.gated_detections = 0
        self._gated_since: dict[int, float] = {}
        self.fused_round = 0  # the last round fused for prior_step (0: the prior is a local prediction)
        #: the prior came from a fusion without any neighbour's message: the next update holds what the own
        #: measurements cannot observe (:mod:`~zentrack.fusion.isolation`)
        self.isolated = False
        self._heard = np.zeros(cfg.nodes, dtype=bool)  # whose messages the rounds of the step being fused took
        self._neighbour_row = np.zeros(cfg.nodes, dtype=bool)
        self._neighbour_row[[j for j in self.neighbours if j != self.id]] = True

    # ------------------------------------------------------------------ the run's initial estimate
    def set_initial(self, x0: np.ndarray) -> None:
        """The run's initial estimate (from truth's ``ctl/start``; every node starts from the same one)."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.kinematic_dim,):
            raise ValueError(f"initial estimate has {x0.size} entries, the filter's kinematic state {self.kinematic_dim}")
        self.x0 = x0
        probe = self.filter.initial(x0, deferred_generator(0))  # a throwaway: the node's own generator is untouched
        self.block_dims = self.rule.message_dims({name: int(p.vector.shape[-1])
                                                  for name, p in self.filter.blocks(probe).items()})

    def cold_start(self, step: int = 0) -> None:
        """The configured initial prior (paper 0 Assumption 1) for ``step``."""
        if self.x0 is None:
            raise RuntimeError("cold start before the run's initial estimate is known")
        self.prior = self.filter.initial(self.x0, self.rng)
        self.prior_step = step
        self.isolated = False

    def rounds(self, step: int) -> int:
        return int(self.rule.rounds(step))

    # ------------------------------------------------------------------ local steps
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

    def scan(self, step: int, returns: np.ndarray, pose: np.ndarray | None = None) -> Scan:
        """This node's scan at ``step`` (the configured sensor position unless the message carried a pose)."""
        position = self.sensor_position if pose is None else pose
        return Scan(step, self.id, np.asarray(returns, dtype=float), np.asarray(position, dtype=float), self.noise_cov)

    def update(self, scans: list[Scan]) -> Estimate:
        """Local correction of the current prior with ``scans`` ([] = coast: the posterior is the prior)."""
        assert self.prior is not None
        return self.corrected(self.prior, scans)

    def update_over(self, t_from: float, t_to: float, timed: list[tuple[float, Scan]]) -> Estimate:
        """Sensors of their own: the current prior (valid at ``t_from``) corrected with each scan at its own time
        (``timed``: (time, scan) in time order, ``t_from <= time < t_to``), predicting to each, then predicted to
        ``t_to``: the estimate valid at ``t_to`` (paper 0 Algorithm 2 lines 6-8 with the update at each
        detection's time)."""
        assert self.prior is not None
        return update_at_times(self.prior, t_from, t_to, timed, self.interval, self.corrected_in_gate)

    def corrected_in_gate(self, est: Estimate, scans: list[Scan], t: float) -> Estimate:
        """``est`` corrected with one sensor's detection at ``t`` if its return lies in the validation gate at
        ``est`` (squared Mahalanobis distance of the innovation at most the chi-square bound of false-rejection
        probability ``cfg.gate``; :func:`~zentrack.fusion.gate.innovation_distances`), else ``est`` (counted
        ``gated``): a forged or broken detection that passed every check of time and form moves no estimate.
        Once a sensor's detections have all been outside for :data:`GATE_LIFT_S`, the next is taken anyway."""
        if self.gate_false_rejection <= 0 or len(scans) != 1 or scans[0].count != 1:
            return self.corrected(est, scans)
        scan = scans[0]
        kin = self.filter.kinematic(est)
        _, _, d2 = innovation_distances(self.measurement, GaussianState(kin.mean[None], kin.cov[None]), scan)
        if float(d2[0, 0]) > self._threshold(scan.dim) and t - self._gated_since.setdefault(scan.sensor, t) < GATE_LIFT_S:
            self.gated_detections += 1
            return est
        self._gated_since.pop(scan.sensor, None)
        return self.corrected(est, scans)

    def _threshold(self, dim: int) -> float:
        """The gate's chi-square bound for dimension ``dim`` (the slice's, else computed once)."""
        if dim not in self._gate_thresholds:
            self._gate_thresholds[dim] = gate_threshold(dim, self.gate_false_rejection)
        return self._gate_thresholds[dim]

    def corrected(self, est: Estimate, scans: list[Scan]) -> Estimate:
        """``est`` corrected with ``scans`` (none: ``est``); a result that is not finite and positive definite
        is refused (counted) and ``est`` kept."""
        if not scans:
            return est
        if self.rule.exchanges_scans:  # the rule's weight of each origin's information (hcmci: omega pi_ij)
            factor = self.scan_factor
            scans = [sc if factor[sc.sensor] == 1.0 else replace(sc, noise_cov=sc.noise_cov / factor[sc.sensor])
                     for sc in scans if factor[sc.sensor] > 0]
            if not scans:
                return est
        alone = getattr(self.filter, "update_isolated", None) if self.isolated else None
        try:
            post = self.filter.update(est, scans) if alone is None else alone(est, scans)
        except NUMERIC_ERRORS as exc:
            self._refused("update", f"{type(exc).__name__}: {exc}")
            return est
        if not self.usable(post):
            self._refused("update", "the posterior is not finite and positive definite")
            return est
        return post

    def usable(self, est: Estimate) -> bool:
        """Whether ``est``'s kinematic mean and covariance are finite and the covariance positive definite."""
        kin = self.filter.kinematic(est)
        # a sum propagates NaN and inf (one that overflows is no usable estimate either); potrf does not
        # reliably fail on a NaN, so the covariance is summed too
        if not math.isfinite(float(kin.mean.sum()) + float(kin.cov.sum())):
            return False
        return cholesky_one(kin.cov) is not None

    def _refused(self, what: str, why: str) -> None:
        """Count and log (the first of each kind) an update or fusion whose result is unusable."""
        self.refused[what] += 1
        if self.refused[what] == 1:
            log.warning("node %d: refused a %s (%s); keeping its own estimate (further ones counted as refused)",
                        self.id, what, why)

    def kinematic(self, est: Estimate) -> GaussianEstimate:
        return self.filter.kinematic(est)

    def diagnostics(self, est: Estimate) -> dict[str, np.ndarray]:
        """The filter's extras for viewers (particle subsample, association probabilities), if any."""
        return self.filter.diagnostics(est)

    def message_blocks(self, est: Estimate) -> Blocks:
        """The round-1 message of ``est``: the filter's information blocks as the fusion rule shares them."""
        return {name: (p.matrix, p.vector) for name, p in self.rule.share(1, self.filter.blocks(est)).blocks.items()}

    def _pair(self, est: Estimate, step: int, warm: bool = False) -> Pair:
        return Pair(step, self.message_blocks(est), warm=warm, round=1)

    def predict_pair(self, post: Estimate, step: int, predicted: bool = False) -> Pair:
        """Local time update and the round-1 message for ``step`` (paper 0 Algorithm 2 lines 8-9); a rule that
        fuses posteriors gets ``post`` itself (the time update follows the fusion). ``predicted``: ``post`` is
        already valid at ``step``'s time (sensors of their own: :meth:`update_over`)."""
        self.shared = post if self.rule.fuses_posterior or predicted else self.filter.predict(post)
        return self._pair(self.shared, step)

    def own_pair(self, step: int) -> Pair | None:
        """The current prior as a round-1 message for ``step`` (predicted forward if needed), flagged warm:
        what a warming node shares so that a network whose nodes all warm at once can still fuse.  None for a
        rule that fuses posteriors: a prior is not the posterior such a rule expects."""
        if self.rule.fuses_posterior:
            return None
        if not self.catch_up(step) or self.prior_step != step or self.prior is None:
            return None
        self.shared = self.prior
        return self._pair(self.prior, step, warm=True)

    # ------------------------------------------------------------------ fusion rounds
    def gate(self, own: Pair | None, pair: Pair) -> bool:
        """Whether a neighbour's message is statistically compatible with this node's own message of the same
        step and round (:func:`~zentrack.fusion.gate.ci_gate_passes`, false-rejection probability
        ``cfg.gate``). Always True without a gate, without a fresh own message (a warm start has nothing to
        check against) or when the rule's messages of that round are not estimates; False for a message whose
        information matrix is not positive definite."""
        if self.gate_false_rejection <= 0 or own is None or own.warm:
            return True
        (theirs_is, theirs_mc), (mine_is, mine_mc) = self._gate_estimate(pair), self._gate_estimate(own)
        if not (theirs_is and mine_is):  # the rule's messages of that round are not estimates
            return True
        if theirs_mc is None:
            return False
        if mine_mc is None:
            return True
        return ci_gate_passes(mine_mc[0], mine_mc[1], theirs_mc[0], theirs_mc[1], self._threshold(theirs_mc[0].shape[0]))

    def _gate_estimate(self, pair: Pair) -> tuple[bool, tuple[np.ndarray, np.ndarray] | None]:
        """Whether the rule's messages of that round are estimates, and if so the message's (mean, covariance)
        (None if its information matrix is not positive definite); computed once per message."""
        if pair.estimate is None:
            info = self.rule.message_estimate(pair.round, pair.blocks)
            pair.estimate = (info is not None, None if info is None else information_mean_cov(*info))
        return pair.estimate

    def fuse(self, step: int, own: Pair | None, received: dict[int, Pair], round: int = 1,
             final: bool | None = None) -> tuple[int, Pair | None]:
        """Round ``round`` of the fusion rule for ``step`` over ``own`` and the neighbours' messages (weights
        renormalised over what is present). Returns the number of messages fused and, unless this was the
        last round (``final``; by default round L), this node's message for the next round. Only the last
        round makes the prior; an earlier one only the next round's message.

        Messages from nodes that are not configured neighbours are ignored; so is every message flagged
        ``warm`` when ``own`` is fresh (a stale prediction only dilutes a fresh estimate). Without any message
        the prior is dropped (the node will warm-start).
        """
        if own is not None and not own.warm:
            received = {j: p for j, p in received.items() if not p.warm}
        senders, messages = [], []
        if own is not None:
            senders.append(self.id)
            messages.append(own)
        for j in sorted(received):
            if j in self.neighbours and received[j].step == step:
                senders.append(j)
                messages.append(received[j])
        if not senders:
            self.prior, self.prior_step = None, None
            return 0, None
        if round == 1:
            self._heard[:] = False
        self._heard[senders] = True
        w = self.weights[senders]
        if round >= self.rounds(step) if final is None else final:
            like = self.shared if self.shared is not None else self.prior
            try:
                fused = self.filter.from_fused(self.rule.combine_one(round, w, [m.blocks for m in messages]), like)
                if self.rule.fuses_posterior:  # the fused posterior of step - 1, predicted to ``step``
                    fused = self.filter.predict(fused)
                why = None if self.usable(fused) else "the fused estimate is not finite and positive definite"
            except NUMERIC_ERRORS as exc:
                why = f"{type(exc).__name__}: {exc}"
            if why is not None:  # the own shared estimate alone (predicted when the rule fuses posteriors)
                self._refused("fusion", why)
                if own is None or self.shared is None:  # nothing of its own to keep: the node warm-starts
                    self.prior, self.prior_step = None, None
                    return 0, None
                fused = self.filter.predict(self.shared) if self.rule.fuses_posterior else self.shared
            self.prior = fused
            self.prior_step = step
            self.fused_round = round
            self.isolated = bool(fused_alone(self._heard, self._neighbour_row))
            return len(senders), None
        stacked = stack_pairs([m.blocks for m in messages])
        try:
            mixed = unstack_message(self.rule.mix(round, w[None, :], stacked, np.ones((1, len(senders)), dtype=bool)))
            blocks = {name: (p.matrix, p.vector) for name, p in mixed.items()}
            why = None if all(np.isfinite(b[0]).all() and np.isfinite(b[1]).all() for b in blocks.values()) else (
                "the mixed message is not finite")
        except NUMERIC_ERRORS as exc:
            why = f"{type(exc).__name__}: {exc}"
        if why is not None:  # the next round goes on from this node's own message alone
            self._refused("fusion", why)
            if own is None:
                return 0, None
            blocks = own.blocks
        return len(senders), Pair(step, blocks, round=round + 1)
