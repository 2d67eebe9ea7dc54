"""A track-oriented Poisson multi-Bernoulli mixture (PMBM) filter: the many-target density of one node's scans.

García-Fernández, Williams, Granström & Svensson 2018 ("Poisson multi-Bernoulli mixture filter: direct derivation
and implementation", IEEE TAES 54(4); the track-oriented form of Williams 2015). The density of the targets is a
Poisson point process (PPP) of the targets never detected, times a mixture of multi-Bernoulli densities, one per
**global hypothesis**. Each target ever detected (or each return that may have been one) is a **track**; a track
holds its **single-target hypotheses** (leaves), each a Bernoulli: existence probability ``r``, Gaussian
``(m, P)`` and a log weight; a global hypothesis picks one leaf per track, and its weight is the product of its
leaves' weights, normalised over the global hypotheses.

Prediction (Theorem 1): the PPP's weights times the survival probability ``P_S``, its components predicted, the
birth intensity added; every leaf's ``r`` times ``P_S``, its Gaussian predicted.

Update with one scan of returns ``z_1..z_J`` (Theorem 2; ``P_D``, Poisson clutter of density ``lambda``):

- a leaf ``(r, m, P, w)`` not detected: ``r (1 - P_D) / (1 - r P_D)``, the same Gaussian, weight
  ``w (1 - r P_D)``; detected by a return ``z_j`` in its gate: ``r = 1``, the Kalman update of ``(m, P)`` by
  ``z_j`` (the node's own filter), weight ``w r P_D N(z_j; h(m), S)``;
- each return starts a new track with two leaves: it is a target first detected now, ``r_j = e_j / rho_j``,
  ``rho_j = e_j + lambda``, ``e_j = sum_c w_c P_D N(z_j; h(m_c), S_c)`` over the PPP's components, the Gaussian
  the moment-matched mixture of the components' updates weighed by ``w_c P_D N_c / e_j``, weight ``rho_j``; or
  it is another track's return: ``r = 0``, weight 1;
- the PPP's weights times ``1 - P_D`` (undetected still).

Each global hypothesis then branches into the assignments of the scan's returns to its tracks' leaves (a track
takes at most one return; a return no track takes is its new track's): with every leaf's missed child and every
return's new track as the baseline, an assignment's weight is that baseline times ``prod a_ij``,
``a_ij = w_ij^detected / (w_i^missed rho_j)``, so the ``k`` best are Murty's ``k`` best events on ``log a``
(:func:`~zentrack.fusion.multitarget.murty.k_best_events`); hypothesis ``g`` of weight ``W_g`` gets
``ceil(K W_g)`` of them (Granström, Fatemi & Svensson 2020's allocation). Then the global hypotheses below
``prune_weight`` are dropped and at most ``max_hypotheses`` kept, the leaves no hypothesis uses dropped, and a
track whose every leaf has ``r`` below ``prune_existence`` dropped.

The estimate: the tracks of the best global hypothesis whose leaf's ``r`` is at least ``estimate_existence``
(no M-of-N confirmation: existence says when a target is there). Pure: arrays in, arrays out; the node's filter
(any registered batched :class:`~zentrack.fusion.filters.base.LocalFilter`) predicts and updates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..filters.base import LocalFilter
from ..linalg import GaussianState
from ..measurement import MeasurementModel
from ..scan import Scan
from .combine import mixture_moments, updated_by_returns
from .gating import gate_gamma, scan_likelihood
from .murty import k_best_events

Array = np.ndarray


@dataclass(frozen=True)
class PmbmSettings:
    """The filter's parameters (module docstring); ``birth_*``: the Gaussian mixture of the birth intensity added
    at each prediction (weights ``(C,)``: expected new targets per step, means ``(C, n)``, covariances
    ``(C, n, n)``)."""

    detection_prob: float
    clutter_density: float
    survival_prob: float = 0.99
    gate_prob: float = 0.999
    max_hypotheses: int = 20
    prune_weight: float = 1e-4
    prune_existence: float = 1e-3
    estimate_existence: float = 0.5
    #: the PPP's components below this weight are dropped at each prediction (undetected for long: nothing left)
    prune_ppp: float = 1e-6
    #: a sensor's range (m): a target beyond it is not in its view, so its scan does not miss it (P_D 0)
    max_range: float = math.inf

    def __post_init__(self) -> None:
        checks = {"detection_prob": 0 < self.detection_prob < 1, "clutter_density": 0 < self.clutter_density < math.inf,
                  "survival_prob": 0 < self.survival_prob <= 1, "gate_prob": 0 < self.gate_prob < 1,
                  "max_hypotheses": self.max_hypotheses >= 1, "prune_weight": 0 <= self.prune_weight < 1,
                  "prune_existence": 0 <= self.prune_existence < 1,
                  "estimate_existence": 0 < self.estimate_existence <= 1, "prune_ppp": 0 <= self.prune_ppp < 1,
                  "max_range": self.max_range > 0}
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"PMBM: {name} = {getattr(self, name)!r} is out of range")


@dataclass(frozen=True)
class UniformIntensity:
    """Undetected targets spread evenly over what the sensors watch (point sensors: the return is the position):
    their density at the start (``initial``) and added at each prediction (``birth``), in units of the clutter
    density (targets per unit of measurement volume over ``lambda``), and a new track's velocity spread
    (``velocity_std``, m/s per axis). A return's first-detection weight is ``D lambda P_D``; its track's Gaussian
    the return itself (noise ``R``) with velocity 0 and that spread: the posterior of a flat prior. A scan does not
    say which part of the region it looked at, so the density takes its misses once a step, at the prediction
    (``(1 - P_D)``: every place watched by at least one sensor a step), not at each scan (sensors of small views
    would wipe out the density of the places they never see)."""

    initial: float
    birth: float
    velocity_std: float

    def __post_init__(self) -> None:
        if not (self.initial >= 0 and self.birth >= 0 and self.velocity_std > 0):
            raise ValueError("PMBM uniform intensity: initial and birth >= 0, velocity_std > 0")


@dataclass
class Ppp:
    """The undetected targets' intensity: a Gaussian mixture (weights ``(C,)``, ``state`` ``(C, n)``)."""

    weights: Array
    state: GaussianState


@dataclass
class Tracks:
    """Every track's leaves, stacked: leaf ``l`` belongs to track ``track[l]`` (its id ``ids[track[l]]``), with
    existence ``r[l]``, log weight ``log_w[l]`` and Gaussian ``state[l]``; ``hypotheses`` ``(G, T)`` the leaf of
    each track in each global hypothesis, ``log_weights`` ``(G,)`` theirs (normalised)."""

    ids: Array = field(default_factory=lambda: np.zeros(0, dtype=int))
    track: Array = field(default_factory=lambda: np.zeros(0, dtype=int))
    r: Array = field(default_factory=lambda: np.zeros(0))
    log_w: Array = field(default_factory=lambda: np.zeros(0))
    state: GaussianState | None = None
    hypotheses: Array = field(default_factory=lambda: np.zeros((1, 0), dtype=int))
    log_weights: Array = field(default_factory=lambda: np.zeros(1))
    #: per leaf, the filter's :attr:`Pmbm.clock` when its target was last detected (None: at 0 for every leaf)
    last_hit: Array | None = None

    def hit_clock(self) -> Array:
        """:attr:`last_hit`, one per leaf."""
        return self.last_hit if self.last_hit is not None and self.last_hit.size == self.r.size \
            else np.zeros(self.r.size, dtype=int)


def normalised_log(log_w: Array) -> Array:
    """``log_w`` less its log-sum-exp: log weights summing to one."""
    top = float(np.max(log_w))
    return log_w - (top + math.log(float(np.sum(np.exp(log_w - top)))))


class Pmbm:
    """One node's PMBM filter (module docstring) on the node's ``local_filter`` and ``measurement`` model."""

    def __init__(self, local_filter: LocalFilter, measurement: MeasurementModel, settings: PmbmSettings,
                 birth: Ppp, initial: Ppp | None = None, uniform: UniformIntensity | None = None) -> None:
        self.filter, self.measurement, self.s, self.birth = local_filter, measurement, settings, birth
        self.ppp = initial if initial is not None else Ppp(birth.weights.copy(), birth.state)
        if uniform is not None and measurement.name != "point":
            raise ValueError(f"a uniform intensity of undetected targets takes point sensors, not {measurement.name}")
        #: the undetected targets spread evenly (None: the Gaussian mixture alone), and their density now
        self.uniform = uniform
        self.uniform_density = 0.0 if uniform is None else uniform.initial
        self.tracks = Tracks()
        self.gamma = gate_gamma(measurement.dim, settings.gate_prob)
        self._next_id = 0
        #: the predictions made so far: a leaf's :attr:`Tracks.last_hit` is on this clock
        self.clock = 0

    # ------------------------------------------------------------------ prediction (Theorem 1)
    def predict(self) -> None:
        """One sample period ahead: survival, the filter's prediction, the birth intensity added."""
        s, t = self.s, self.tracks
        kept = s.survival_prob * self.ppp.weights >= s.prune_ppp
        ppp = self.filter.predict(GaussianState(self.ppp.state.mean[kept], self.ppp.state.cov[kept]))
        self.ppp = Ppp(np.concatenate([s.survival_prob * self.ppp.weights[kept], self.birth.weights]),
                       GaussianState(np.concatenate([ppp.mean, self.birth.state.mean]),
                                     np.concatenate([ppp.cov, self.birth.state.cov])))
        if t.state is not None and t.r.size:
            t.r = s.survival_prob * t.r
            t.state = self.filter.predict(t.state)
        if self.uniform is not None:  # (its misses once a step: UniformIntensity)
            self.uniform_density = (s.survival_prob * (1 - s.detection_prob) * self.uniform_density
                                    + self.uniform.birth)
        self.clock += 1

    def add_tracks(self, state: GaussianState, r: Array) -> Array:
        """The ids of tracks started from priors ``state`` ``(B, n)`` (a neighbour's tracks of targets it does not
        hold) of existence ``r`` ``(B,)``: one leaf each, in every global hypothesis, not detected yet."""
        t, b = self.tracks, int(np.size(r))
        if b == 0:
            return np.zeros(0, dtype=int)
        ids, leaves, held = self._issue(b), t.r.size, t.ids.size
        n = self.filter.state_dim
        before = t.state if t.state is not None else GaussianState(np.zeros((0, n)), np.zeros((0, n, n)))
        self.tracks = Tracks(np.concatenate([t.ids, ids]), np.concatenate([t.track, held + np.arange(b)]),
                             np.concatenate([t.r, np.asarray(r, dtype=float)]), np.concatenate([t.log_w, np.zeros(b)]),
                             GaussianState(np.concatenate([before.mean, state.mean]),
                                           np.concatenate([before.cov, state.cov])),
                             np.hstack([t.hypotheses, np.tile(leaves + np.arange(b), (t.hypotheses.shape[0], 1))]),
                             t.log_weights, np.concatenate([t.hit_clock(), np.full(b, self.clock - 1)]))
        return ids

    # ------------------------------------------------------------------ update (Theorem 2)
    def update(self, scan: Scan) -> None:
        """Take one scan (module docstring)."""
        s, t, j = self.s, self.tracks, scan.count
        leaves = t.r.size
        pd = self._detection_prob(t.state, scan) if leaves else np.zeros(0)  # each leaf's P_D at its mean
        # the leaves' children: missed (index l), detected by return i (index leaves + pair)
        miss_r = t.r * (1 - pd) / (1 - t.r * pd)
        miss_log_w = t.log_w + np.log1p(-t.r * pd)
        pairs_l, pairs_j, det_log_w, det_state = np.zeros(0, int), np.zeros(0, int), np.zeros(0), None
        if leaves and j:
            assert t.state is not None  # (leaves have states)
            lik = scan_likelihood(self.measurement, t.state, scan, self.gamma)
            gated = lik.gated & (t.r[:, None] * pd[:, None] > 0)
            pairs_l, pairs_j = np.nonzero(gated)
            det_log_w = t.log_w[pairs_l] + np.log(t.r[pairs_l] * pd[pairs_l]) + lik.log_lik[pairs_l, pairs_j]
            if pairs_l.size:
                det_state = self._updated(GaussianState(t.state.mean[pairs_l], t.state.cov[pairs_l]), scan, pairs_j)
        # each return's new track: a first detection of an undetected target, or nothing
        new_r, new_log_rho, new_state = self._new_tracks(scan)
        self.ppp = Ppp((1 - self._detection_prob(self.ppp.state, scan)) * self.ppp.weights, self.ppp.state)
        # the global hypotheses' branches: Murty's k best assignments of each
        log_a = np.full((leaves, j), -np.inf)
        log_a[pairs_l, pairs_j] = det_log_w - miss_log_w[pairs_l] - new_log_rho[pairs_j]
        pair_index = np.full((leaves, j), -1)
        pair_index[pairs_l, pairs_j] = np.arange(pairs_l.size)
        n_tracks = t.ids.size
        children = []
        for g in range(t.hypotheses.shape[0]):
            chosen = t.hypotheses[g]
            k = max(1, math.ceil(s.max_hypotheses * math.exp(t.log_weights[g])))
            if n_tracks and j:
                events, _ = k_best_events(log_a[chosen], np.isfinite(log_a[chosen]), k)
            else:
                events = np.full((1, n_tracks), -1)
            for event in events:
                detected = event >= 0
                own = chosen.copy()
                own[detected] = leaves + pair_index[chosen[detected], event[detected]]
                taken = np.zeros(j, dtype=bool)
                taken[event[event >= 0]] = True
                children.append(np.concatenate([own, np.where(taken, 0, 1)]))  # new track: 0 nothing, 1 exists
        self._rebuild(children, miss_r, miss_log_w, pairs_l, det_log_w, det_state, new_r, new_log_rho, new_state)

    def _detection_prob(self, state: GaussianState | None, scan: Scan) -> Array:
        """P_D of each estimate of ``state`` for ``scan``'s sensor: the settings' within its range of the sensor
        (``max_range``), 0 beyond (a target out of a sensor's view is not missed by its scan)."""
        if state is None:
            return np.zeros(0)
        pd = np.full(state.mean.shape[0], self.s.detection_prob)
        if math.isfinite(self.s.max_range):
            pd[np.linalg.norm(state.mean[:, :3] - scan.pose, axis=1) > self.s.max_range] = 0.0
        return pd

    def _updated(self, prior: GaussianState, scan: Scan, returns: Array) -> GaussianState:
        """``prior`` ``(B, n)`` updated by the node's filter with the returns ``returns`` ``(B,)`` of ``scan``."""
        return updated_by_returns(self.filter, prior, scan, returns)

    def _new_tracks(self, scan: Scan) -> tuple[Array, Array, GaussianState | None]:
        """Each return's new track (module docstring): ``r_j``, ``log rho_j`` and the Gaussian."""
        j, pd, lam = scan.count, self.s.detection_prob, self.s.clutter_density
        c, flat = self.ppp.weights.size, self.uniform is not None and self.uniform_density > 0
        if j == 0 or (c == 0 and not flat):
            return np.zeros(j), np.full(j, math.log(lam)), None
        log_e_cj = np.zeros((0, j))
        means, covs, owner = [], [], []
        if c:
            lik = scan_likelihood(self.measurement, self.ppp.state, scan, math.inf)  # (C, J): every component
            pd_c = self._detection_prob(self.ppp.state, scan)
            log_e_cj = np.log(np.maximum(self.ppp.weights * pd_c, 1e-300))[:, None] + lik.log_lik
            comp, ret = np.repeat(np.arange(c), j), np.tile(np.arange(j), c)  # every (component, return) pair
            updated = self._updated(GaussianState(self.ppp.state.mean[comp], self.ppp.state.cov[comp]), scan, ret)
            means, covs, owner = [updated.mean], [updated.cov], [ret]
        if flat:  # the evenly spread ones: weight D lambda P_D at any return, the return itself as the Gaussian
            assert self.uniform is not None
            log_e_cj = np.vstack([log_e_cj, np.full((1, j), math.log(self.uniform_density * lam * pd))])
            n, v = self.filter.state_dim, self.uniform.velocity_std
            mean = np.zeros((j, n))
            mean[:, :3] = scan.returns
            cov = np.zeros((j, n, n))
            cov[:, :3, :3] = scan.noise_cov
            cov[:, 3:6, 3:6] = v * v * np.eye(3)
            if n > 6:  # (augmented filters: their extra states at the filter's prior)
                cov[:, 6:, 6:] = self.filter.initial_state(np.zeros((1, 6)), np.eye(6)).cov[0, 6:, 6:]
            means, covs, owner = [*means, mean], [*covs, cov], [*owner, np.arange(j)]
        top = log_e_cj.max(axis=0)
        log_e = top + np.log(np.exp(log_e_cj - top).sum(axis=0))
        log_rho = np.logaddexp(log_e, math.log(lam))
        weights = np.exp(np.concatenate([log_e_cj[:c].ravel(), log_e_cj[c:].ravel()]) - log_e[np.concatenate(owner)])
        mixed = mixture_moments(weights, np.concatenate(means), np.concatenate(covs), np.concatenate(owner), j)
        return np.exp(log_e - log_rho), log_rho, mixed

    def _rebuild(self, children: list[Array], miss_r: Array, miss_log_w: Array, pairs_l: Array, det_log_w: Array,
                 det_state: GaussianState | None, new_r: Array, new_log_rho: Array, new_state: GaussianState | None) -> None:
        """The new leaves and global hypotheses from the branches ``children`` (per branch: the child of each old
        track, then 0/1 per new track), pruned (module docstring)."""
        t, s = self.tracks, self.s
        leaves, n_old, j = t.r.size, t.ids.size, new_r.size
        n = self.filter.state_dim
        # every candidate leaf: old tracks' children (missed, detected), then the new tracks' (nothing, exists)
        cand_track = np.concatenate([t.track, t.track[pairs_l], np.repeat(n_old + np.arange(j), 2)])
        cand_r = np.concatenate([miss_r, np.ones(pairs_l.size), np.ravel(np.stack([np.zeros(j), new_r], axis=1))])
        cand_log_w = np.concatenate([miss_log_w, det_log_w, np.ravel(np.stack([np.zeros(j), new_log_rho], axis=1))])
        cand_hit = np.concatenate([t.hit_clock(), np.full(pairs_l.size + 2 * j, self.clock)])
        means = [t.state.mean if t.state is not None else np.zeros((0, n))]
        covs = [t.state.cov if t.state is not None else np.zeros((0, n, n))]
        if det_state is not None:
            means.append(det_state.mean)
            covs.append(det_state.cov)
        if j:
            blank = new_state if new_state is not None else GaussianState(np.zeros((j, n)), np.tile(np.eye(n), (j, 1, 1)))
            means.append(np.repeat(blank.mean, 2, axis=0))
            covs.append(np.repeat(blank.cov, 2, axis=0))
        cand_mean, cand_cov = np.concatenate(means), np.concatenate(covs)
        # the branches as candidate leaf indices per track (old tracks, then new), and their weights
        base = leaves + pairs_l.size
        hyp = np.array([np.concatenate([c[:n_old], base + 2 * np.arange(j) + c[n_old:]]) for c in children],
                       dtype=int).reshape(len(children), n_old + j)
        log_weights = normalised_log(cand_log_w[hyp].sum(axis=1)) if hyp.size else np.zeros(len(children))
        # prune the global hypotheses: the best max_hypotheses above prune_weight (the best always kept)
        order = np.argsort(-log_weights)[: s.max_hypotheses]
        order = order[(log_weights[order] >= math.log(max(s.prune_weight, 1e-300))) | (order == order[0])]
        hyp, log_weights = hyp[order], normalised_log(log_weights[order])
        # drop the tracks whose every used leaf has r below prune_existence, then the leaves no one uses
        keep_track = (cand_r[hyp] >= s.prune_existence).any(axis=0) if hyp.size else np.zeros(n_old + j, dtype=bool)
        hyp = hyp[:, keep_track]
        if hyp.shape[0] > 1:  # hypotheses that now pick the same leaves are one: their weights add
            hyp, inverse = np.unique(hyp, axis=0, return_inverse=True)
            top = log_weights.max()
            log_weights = top + np.log(np.bincount(np.ravel(inverse), np.exp(log_weights - top), hyp.shape[0]))
        used, remap = np.unique(hyp, return_inverse=True)
        ids = np.concatenate([t.ids, self._issue(j)])[keep_track]
        track_of_leaf = np.searchsorted(np.flatnonzero(keep_track), cand_track[used])
        log_w = cand_log_w[used]
        for tr in range(ids.size):  # a track's leaves' weights relative to its best (global weights unchanged)
            mine = track_of_leaf == tr
            log_w[mine] -= log_w[mine].max()
        self.tracks = Tracks(ids, track_of_leaf, cand_r[used], log_w, GaussianState(cand_mean[used], cand_cov[used]),
                             remap.reshape(hyp.shape), log_weights, cand_hit[used])

    def _issue(self, count: int) -> Array:
        ids = np.arange(self._next_id, self._next_id + count)
        self._next_id += count
        return ids

    # ------------------------------------------------------------------ output
    def estimates(self) -> tuple[Array, Array, GaussianState]:
        """The best global hypothesis's tracks whose existence is at least ``estimate_existence``: their ids
        ``(E,)``, existence probabilities ``(E,)`` and Gaussians."""
        t = self.tracks
        n = self.filter.state_dim
        if t.state is None or t.ids.size == 0:
            return np.zeros(0, dtype=int), np.zeros(0), GaussianState(np.zeros((0, n)), np.zeros((0, n, n)))
        leaves = t.hypotheses[int(np.argmax(t.log_weights))]
        leaves = leaves[t.r[leaves] >= self.s.estimate_existence]
        return t.ids[t.track[leaves]], t.r[leaves], GaussianState(t.state.mean[leaves], t.state.cov[leaves])
