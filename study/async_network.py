"""A network of trackers whose sensors have their own rates, phases, clocks and latencies, simulated in one process:
what ``zentrack bench async`` measures (issue 52).

**The sensors.** Node i's sensor samples at its own rate (cycled over the nodes from ``rates_hz``: 1, 4 and 10 Hz by
default) with its phase spread over its period (the golden-ratio sequence), stamps its detections with a clock
``offset_s`` off (drawn within the setting's bound, seeded) and publishes each after a latency (uniform 10-300 ms by
default), a share ``reorder`` of them one sample period later still (so they arrive after the next one):
:func:`~zentrack.truth.simulation.sensor_stream.sensor_stream`, which samples the scenario's truth between its steps.
Every run has its own stream seed (``SeedSequence([seed, run])``). The trackers are **told their sensors' clock
offsets** (a calibrated or disciplined clock: ``node/detections.py``'s ``SensorLink.offset_s``), so a detection's
time on the tracker's clock is ``stamp - offset`` (the live tracker can also estimate them; the simulation does not).

**The trackers.** Every node runs the scenario's node filter on its own sensor's detections and, at every fusion tick
``t_k = k ts`` (the scenario's sample period), publishes its estimate of ``t_k`` and fuses it with its ring
neighbours' by the scenario's fusion rule (covariance intersection, one round, the scenario's weights; the rule's
``combine_one``, as a tracker calls it). What a tracker does with a detection that arrives after its estimate has
moved past the detection's time is the method (:mod:`zentrack.study.async_methods`). Events are processed in wall
time: a detection when it arrives, tick k at ``t_k`` plus the method's publication lag (a tick before a detection at
the same instant). An estimate's **age** is how far behind the wall clock it is when published: the publication
lag plus the processor time the tick took the tracker before publishing.

**The bound** (:func:`timed_bound`): the PCRLB of every sensor's measurements, each at its true time
(:func:`~zentrack.study.pcrlb.pcrlb_timed`), at each tick: what the best estimator of the whole network could know at
``t_k`` from everything measured before it.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from zentrack.fusion.estimates import Estimate
from zentrack.fusion.models import plant_over
from zentrack.fusion.rules import FusionRule
from zentrack.fusion.scan import Scan
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.sensor_stream import (
    Latency,
    SensorStreamSpec,
    SimulatedDetection,
    sensor_stream,
    state_at,
)

from .async_methods import DEFAULT_LAG_S, DEFAULT_MAX_LAG_S, AsyncMethod, MethodCounts, NodeModel, make_method
from .async_methods.base import Refuse
from .pcrlb import pcrlb_timed
from .simulator import NetworkResult

Array = np.ndarray
#: the golden ratio's fractional part: phases (and offsets) spread over their range without two alike
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class AsyncSettings:
    """The sensors' timing and the methods' settings (module docstring)."""

    rates_hz: tuple[float, ...] = (1.0, 4.0, 10.0)
    latency: Latency = Latency("uniform", 0.01, 0.3)
    reorder: float = 0.1
    offset_s: float = 0.2  #: clock offsets within +- this
    lag_s: float = DEFAULT_LAG_S  #: the fixed lag
    max_lag_s: float = DEFAULT_MAX_LAG_S  #: how far back re-processing and the OOSM update go

    def latest_s(self) -> float:
        """The longest a detection takes to arrive: the latency's top plus, if any are reordered, one period of the
        slowest sensor."""
        return self.latency.high_s + (1.0 / min(self.rates_hz) if self.reorder > 0 else 0.0)


def stream_specs(nodes: int, settings: AsyncSettings, seed: int) -> list[SensorStreamSpec]:
    """Node i's sensor (module docstring): rate ``rates_hz[i % len]``, phase ``frac((i + 1/2) golden) / rate``, clock
    offset uniform within ``+- offset_s`` (seeded by ``seed``)."""
    offsets = np.random.default_rng(np.random.SeedSequence([seed, 52, 1])).uniform(
        -settings.offset_s, settings.offset_s, nodes)
    specs = []
    for i in range(nodes):
        rate = settings.rates_hz[i % len(settings.rates_hz)]
        specs.append(SensorStreamSpec(i, rate, phase_s=((i + 0.5) * GOLDEN % 1.0) / rate, offset_s=float(offsets[i]),
                                      latency=settings.latency, reorder=settings.reorder))
    return specs


def run_detections(scn: ScenarioData, specs: Sequence[SensorStreamSpec], seed: int, run: int
                   ) -> list[list[SimulatedDetection]]:
    """Every node's detections in run ``run`` (its own stream seed), in the order each sensor measures them."""
    stream_seed = int(np.random.SeedSequence([seed, run]).generate_state(1)[0])
    return [sensor_stream(scn, spec, stream_seed, run) for spec in specs]


def tracker_time(det: SimulatedDetection, spec: SensorStreamSpec) -> float:
    """``det``'s measurement time on its tracker's clock: its stamp less the offset the tracker was told."""
    return det.stamp - spec.offset_s


def tick_times(scn: ScenarioData) -> Array:
    """The fusion ticks ``t_k = k ts``, one per truth sample."""
    return np.arange(scn.steps) * scn.ts


def interval_plant(scn: ScenarioData) -> Callable[[float], tuple[Array, Array]]:
    """``dt -> (A, Q)`` of the scenario's plant over ``dt`` (:func:`~zentrack.fusion.models.plant_over`), kept."""
    kept: dict[float, tuple[Array, Array]] = {}

    def over(dt: float) -> tuple[Array, Array]:
        key = round(dt, 9)
        if key not in kept:
            plant = plant_over(scn.plant, scn.ts, key, scn.plant_params)
            kept[key] = (np.asarray(plant.A, dtype=float), np.asarray(plant.Q, dtype=float))
        return kept[key]

    return over


def timed_bound(scn: ScenarioData, detections: Sequence[Sequence[Sequence[SimulatedDetection]]]) -> Array:
    """The PCRLB ``(R, K, n, n)`` at the ticks of every run (``detections[r][i]``: run r, node i), every detected
    measurement at its true time (module docstring)."""
    over = interval_plant(scn)
    model = scn.measurement_model()
    ticks = tick_times(scn)
    out = np.empty((scn.runs, scn.steps, scn.truth.shape[-1], scn.truth.shape[-1]))
    for r, nodes in enumerate(detections):
        seen = sorted((d.t, i) for i, dets in enumerate(nodes) for d in dets if d.returns.shape[0] > 0)
        times = np.array([t for t, _ in seen])
        who = np.array([i for _, i in seen], dtype=int)
        states = state_at(scn, r, times)
        out[r] = pcrlb_timed(states, times, scn.sensors[who], np.asarray(scn.noise_cov)[who], ticks, over, scn.p0,
                             model)
    return out


class RingFusion:
    """Each tracker's single-round fusion with its neighbours, as ``Tracker.fuse`` makes its last round: the rule's
    round-1 message of each estimate (``rule.share`` of the filter's blocks), combined by ``rule.combine_one`` over
    its own message first and its neighbours' (in index order) with its row of the rule's weights, back to an
    estimate by the filter's ``from_fused``."""

    def __init__(self, scn: ScenarioData, node: NodeModel, rule: FusionRule) -> None:
        self.node, self.rule = node, rule
        weights = np.asarray(rule.network_weights(scn.weights, scn.adjacency), dtype=float)
        self.neighbours = [[int(j) for j in np.flatnonzero(scn.adjacency[i]) if j != i] for i in range(scn.nodes)]
        self.weights = [weights[i, [i, *self.neighbours[i]]] for i in range(scn.nodes)]

    def message(self, est: Estimate) -> dict[str, tuple[Array, Array]]:
        return {name: (p.matrix, p.vector) for name, p in self.rule.share(1, self.node.filter.blocks(est)).blocks.items()}

    def fuse(self, i: int, own: Estimate, theirs: Sequence[dict[str, tuple[Array, Array]]],
             mine: dict[str, tuple[Array, Array]] | None = None) -> Estimate:
        """Node i's ``own`` estimate fused with its neighbours' messages ``theirs`` (``mine``: ``own``'s message,
        if it was made already)."""
        blocks = self.rule.combine_one(1, self.weights[i], [self.message(own) if mine is None else mine, *theirs])
        return self.node.filter.from_fused(blocks, own)

    def again(self, i: int, theirs: Sequence[dict[str, tuple[Array, Array]]]) -> Refuse:
        """The function that fuses another own estimate of node i with the same neighbours' messages ``theirs``."""
        def refuse(est: Estimate) -> Estimate:
            return self.fuse(i, est, theirs)
        return refuse


@dataclass
class RunRecord:
    """One run of one method: every tracker's published kinematic estimate at every tick (``mean`` ``(K, M, n)``,
    ``cov`` ``(K, M, n, n)``), its age ``(K, M)`` s, the processor time each tracker spent ``(M,)`` s, and the
    methods' counts (summed over the trackers)."""

    mean: Array
    cov: Array
    age: Array
    cpu_s: Array
    counts: MethodCounts = field(default_factory=MethodCounts)

    @property
    def detections(self) -> int:
        return self.counts.arrived


def simulate_run(scn: ScenarioData, run: int, detections: Sequence[Sequence[SimulatedDetection]],
                 specs: Sequence[SensorStreamSpec], method: str, node: NodeModel, fusion: RingFusion,
                 settings: AsyncSettings = AsyncSettings(),
                 observe: Callable[[int, list[AsyncMethod]], None] | None = None) -> RunRecord:
    """Run ``run`` of ``scn`` with every tracker using ``method`` on its node's ``detections`` (module docstring);
    ``observe(k, trackers)`` is called at every tick before it (tests look at the trackers there)."""
    m, ticks = scn.nodes, tick_times(scn)
    prior = node.filter.initial(np.asarray(scn.x0_estimate[run], dtype=float))
    trackers = [make_method(method, node, prior, 0.0, lag=settings.lag_s, max_lag=settings.max_lag_s)
                for _ in range(m)]
    lag = trackers[0].publish_lag
    last_wall = round(float(ticks[-1]) + lag, 9)
    # (wall time, 0 tick / 1 detection, measurement time, node, payload): a tick before a detection at one instant
    events: list[tuple[float, int, float, int, object]] = [
        (round(float(t_k) + lag, 9), 0, float(t_k), -1, k) for k, t_k in enumerate(ticks)]
    for i, dets in enumerate(detections):
        for det in dets:
            wall = round(trackers[i].arrival(det), 9)
            if wall <= last_wall:
                events.append((wall, 1, det.t, i, det))
    events.sort(key=lambda e: e[:4])
    nk = node.filter.kinematic_dim
    mean, cov = np.empty((scn.steps, m, nk)), np.empty((scn.steps, m, nk, nk))
    age, cpu = np.empty((scn.steps, m)), np.zeros(m)
    clock = time.process_time_ns
    for _, kind, _, i, payload in events:
        if kind == 1:
            assert isinstance(payload, SimulatedDetection)
            if payload.returns.shape[0] == 0:
                continue  # missed: nothing to update with
            scan = Scan(0, i, payload.returns, scn.sensors[i], scn.noise_cov[i])
            c0 = clock()
            trackers[i].detection(tracker_time(payload, specs[i]), scan)
            cpu[i] += (clock() - c0) * 1e-9
            continue
        k = payload
        assert isinstance(k, int)
        t_k = float(ticks[k])
        if observe is not None:
            observe(k, trackers)
        own, messages = [], []
        for i, tr in enumerate(trackers):
            c0 = clock()
            est = tr.share(k, t_k)
            spent = (clock() - c0) * 1e-9
            messages.append(fusion.message(est))
            cpu[i] += (clock() - c0) * 1e-9
            own.append(est)
            age[k, i] = lag + spent
            kin = node.filter.kinematic(est)
            mean[k, i], cov[k, i] = kin.mean, kin.cov
        for i, tr in enumerate(trackers):
            c0 = clock()
            theirs = [messages[j] for j in fusion.neighbours[i]]
            tr.fused(k, t_k, fusion.fuse(i, own[i], theirs, messages[i]), fusion.again(i, theirs))
            cpu[i] += (clock() - c0) * 1e-9
    record = RunRecord(mean, cov, age, cpu)
    for tr in trackers:
        record.counts.add(tr.counts)
    return record


def run_method(scn: ScenarioData, detections: Sequence[Sequence[Sequence[SimulatedDetection]]],
               specs: Sequence[SensorStreamSpec], method: str, node: NodeModel, fusion: RingFusion,
               settings: AsyncSettings = AsyncSettings()) -> tuple[NetworkResult, list[RunRecord]]:
    """Every run of ``scn`` with ``method``: the published estimates as a
    :class:`~zentrack.study.simulator.NetworkResult` (``(R, K, M, n)``, scored by
    :func:`~zentrack.study.simulator.evaluate` like the synchronous networks) and each run's record."""
    records = [simulate_run(scn, r, detections[r], specs, method, node, fusion, settings) for r in range(scn.runs)]
    result = NetworkResult(method, np.stack([rec.mean for rec in records]), np.stack([rec.cov for rec in records]),
                           np.full(scn.runs, -1))
    return result, records
