"""What a tracker could know while faults split the network: the bound of the sensors within its reach.

A soak judges a tracker fault by the hit tracker's error in the fault's window over the fault-free run's at the same
steps (:mod:`zentrack.cluster.soak.accuracy`). When other faults overlap it and cut the tracker off from most of
the network -- on a ring, one neighbour killed and the other frozen, or a link cut two hops away -- no estimator in
that tracker can match the fault-free run: it has fewer sensors to estimate from. This module measures how far the
limit itself moved, so that a window is judged against what its tracker could reach (issue 54 item 2):

- **Reach** (:func:`reach`): at one step, a tracker that is up and linked reaches the trackers connected to it
  through up, linked trackers (its component of the communication graph); a tracker that is down (killed, frozen,
  drained) reaches what its up, linked neighbours reach (what it warm-starts from when it returns); a cut tracker
  reaches itself alone. The states come from the fault windows (:func:`tracker_states`): a kill, freeze or drain
  from its start to its undo, a cut likewise; faults of the truth, the router or a sensor change no one's reach.
- **Bound** (:meth:`ReachBound.ratios`): the posterior Cramér-Rao bound (:func:`zentrack.study.pcrlb.pcrlb_per_run`,
  Tichavsky et al. 1998 eq. 21) along the run's truth, from the network's bound just before the window, with the
  measurements of only the sensors in reach at each step. A window's **bound ratio** is the RMS over its steps
  (where the faulty run has an estimate) of ``sqrt(trace)`` of that bound's position block, over the same for the
  network's bound (every sensor, every step): 1 when the faults leave the tracker every sensor, above 1 by as much
  as they took its information away.
- The approximation: when a split heals, the recursion credits the tracker with its new component's measurements
  from then on, not with what the other side learnt while apart, so its bound comes back more slowly than a
  centralised fusion of both sides would (on ``patrol``, whose process noise forgets in a few steps, within ten
  steps of the heal).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from zentrack.cluster.soak.fault_kinds import fault_of
from zentrack.fusion.measurement import MeasurementModel
from zentrack.study.pcrlb import pcrlb_per_run

Array = np.ndarray

#: the measurements whose bound the study tools compute
BOUNDED = ("bearing", "point", "linear")
#: the kinds of fault that take a tracker down for their window (it neither measures nor passes anything on)
DOWN_KINDS = ("kill", "freeze", "drain")
#: the kinds that cut a tracker's links for their window (it still measures)
CUT_KINDS = ("cut",)


def tracker_states(windows: Sequence[Mapping], steps: int, nodes: int) -> tuple[Array, Array]:
    """``(down, cut)``, each ``(steps, nodes)`` booleans: which trackers each fault window (kind, node, start, end as
    :func:`~zentrack.cluster.soak.faults.fault_windows` gives them) takes down or cuts off, from its start to the
    step before its end."""
    down = np.zeros((steps, nodes), dtype=bool)
    cut = np.zeros((steps, nodes), dtype=bool)
    for w in windows:
        kind = fault_of(w["kind"], w["node"]).name
        if isinstance(w["node"], int) and kind in DOWN_KINDS + CUT_KINDS:  # a drain is recorded per tracker moved
            (down if kind in DOWN_KINDS else cut)[max(0, int(w["start"])):min(steps, int(w["end"])), w["node"]] = True
    return down, cut


def reach(adjacency: Array, down: Array, cut: Array, node: int) -> Array:
    """``(M,)`` booleans: the trackers whose sensors ``node`` reaches at one step (module docstring), from the
    graph's ``adjacency`` ``(M, M)`` and that step's ``down`` and ``cut`` ``(M,)``."""
    up = ~down & ~cut
    linked = np.asarray(adjacency, dtype=bool) & up[:, None] & up[None, :]
    np.fill_diagonal(linked, False)
    if down[node]:  # what it warm-starts from when it returns: its up, linked neighbours' components
        seeds = [int(j) for j in np.flatnonzero(np.asarray(adjacency, dtype=bool)[node]) if up[j] and j != node]
    else:  # up: its component (cut: no links, itself alone)
        seeds = [node]
    seen = np.zeros(len(up), dtype=bool)
    seen[seeds] = True
    frontier = list(seeds)
    while frontier:
        nxt = np.flatnonzero(linked[frontier].any(axis=0) & ~seen)
        seen[nxt] = True
        frontier = list(nxt)
    return seen


@dataclass(frozen=True)
class ReachBound:
    """A single-target run's geometry and motion, for the bound of the sensors within a tracker's reach: the truth
    ``(K, n)``, sensors ``(M, 3)``, noise ``(M, m, m)``, the graph ``(M, M)``, the plant's ``A`` and ``Q``, the
    prior ``p0``, the measurement model and which sensors measured (``present`` ``(K, M)``, None: all)."""

    truth: Array
    sensors: Array
    noise_cov: Array
    adjacency: Array
    transition: Array
    process_cov: Array
    p0: Array
    measurement: MeasurementModel
    present: Array | None = None

    @classmethod
    def of(cls, scn: Any, truth: Array | None = None) -> ReachBound | None:
        """From a simulated single-target run (:class:`~zentrack.truth.simulation.scenario.ScenarioData`; ``truth``
        ``(K, n)`` replaces its first run's, e.g. the truth a soak recorded); None for many targets, moving sensors
        or a plant or measurement without a bound (no linear ``A`` and ``Q`` of the state's size)."""
        if not hasattr(scn, "motion_model") or scn.sensor_track is not None or scn.measurement not in BOUNDED:
            return None
        plant = scn.motion_model()
        a, q = getattr(plant, "A", None), getattr(plant, "Q", None)
        path = np.asarray(scn.truth[0] if truth is None else truth, dtype=float)
        n = path.shape[-1]
        if a is None or q is None or np.shape(a) != (n, n) or np.shape(q) != (n, n):
            return None
        present = np.asarray(scn.present[0], dtype=bool)
        present = np.pad(present, ((0, max(0, len(path) - len(present))), (0, 0)), constant_values=True)[:len(path)]
        return cls(path, np.asarray(scn.sensors, dtype=float), np.asarray(scn.noise_cov, dtype=float),
                   np.asarray(scn.adjacency) != 0, np.asarray(a, dtype=float), np.asarray(q, dtype=float),
                   np.asarray(scn.p0, dtype=float), scn.measurement_model(), present)

    def _bound(self, truth: Array, present: Array, p0: Array) -> Array:
        """``(R, L, n, n)``: the bound along ``truth`` ``(R, L, n)`` with the sensors ``present`` ``(R, L, M)``."""
        return pcrlb_per_run(truth, self.sensors, self.transition, self.process_cov, p0, self.noise_cov,
                             self.measurement, present)

    def traces(self, windows: Sequence[Mapping], after: int, steps: int) -> list[WindowBound | None]:
        """Per window, the trace of the position bound of its tracker's reach and of the network's at each of its
        steps (:class:`WindowBound`); None for a fault of the truth, the router or a sensor (they take the same from
        every tracker). A window runs from its start to ``after`` steps past its end, within ``steps``."""
        k, m = min(steps, len(self.truth)), len(self.sensors)
        runs = [(n, w["node"], int(w["start"]), min(k, int(w["end"]) + after + 1)) for n, w in enumerate(windows)
                if isinstance(w["node"], int) and 1 <= int(w["start"]) < k]  # a drain: one per tracker moved
        out: list[WindowBound | None] = [None] * len(windows)
        if not runs:
            return out
        every = np.ones((1, k, m), dtype=bool) if self.present is None else self.present[None, :k]
        network = self._bound(self.truth[None, :k], every, self.p0)[0]  # (K, n, n)
        down, cut = tracker_states(windows, k, m)
        span = max(hi - lo for _, _, lo, hi in runs)
        at = np.array([np.clip(np.arange(lo, lo + span), 0, k - 1) for _, _, lo, _ in runs])
        present = np.array([[reach(self.adjacency, down[s], cut[s], i) for s in row]
                            for (_, i, _, _), row in zip(runs, at, strict=True)])
        if self.present is not None:
            present &= self.present[at]
        prior = np.array([self.process_cov + self.transition @ network[lo - 1] @ self.transition.T
                          for _, _, lo, _ in runs])
        split = position_trace(self._bound(self.truth[at], present, prior))
        whole = position_trace(network)
        for j, (n, i, lo, hi) in enumerate(runs):
            out[n] = WindowBound(i, lo, hi, split[j, :hi - lo], whole[lo:hi])
        return out

    def ratios(self, windows: Sequence[Mapping], have: Array, after: int) -> list[float]:
        """Each window's bound ratio (module docstring): 1.0 for a fault of the truth, the router or a sensor, or
        a window without estimates; ``have`` ``(K, M)``: where the faulty run has an estimate."""
        return [1.0 if b is None else b.ratio(have) for b in self.traces(windows, after, have.shape[0])]


@dataclass(frozen=True)
class WindowBound:
    """One window's bounds: its tracker, its steps ``lo`` to ``hi - 1``, and per step the trace of the position
    bound of the sensors in the tracker's reach (``split``) and of every sensor (``network``), m²."""

    node: int
    lo: int
    hi: int
    split: Array
    network: Array

    def ratio(self, have: Array) -> float:
        """The bound ratio over the steps where the tracker has an estimate (``have`` ``(K, M)``), at least 1; 1.0
        without any."""
        mask = have[self.lo:self.hi, self.node]
        a, b = self.split[mask], self.network[mask]
        if not len(a) or not np.all(np.isfinite(a)) or b.mean() <= 0:
            return 1.0
        return max(1.0, float(np.sqrt(a.mean() / b.mean())))


def position_trace(bound: Array) -> Array:
    """The trace of the position block (the first three components) of each bound ``(..., n, n)``."""
    return np.trace(bound[..., :3, :3], axis1=-2, axis2=-1)
