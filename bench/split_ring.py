"""An in-memory ring of realtime trackers with the soak's tracker faults applied by hand (``zentrack bench split``,
tests/test_soak_reach.py).

A tracker here is what a tracker process runs -- the node schedule (:class:`~zentrack.node.schedule.NodeSchedule`)
around its :class:`~zentrack.node.diffusion.tracker.Tracker`, every message through the real wire codec -- on a
shared clock and a bus stepped by hand: no Zenoh and no processes, so every step of a fault is deterministic. A
tracker can be killed (it stops; :meth:`SplitRing.restart` brings a new one with no state, told the run's start as
the truth's start message tells a restarted process), frozen (SIGSTOP: it neither hears nor acts; thawed, its clock
has jumped) or cut off (its messages neither leave nor arrive). Every estimate published is scored against the
truth as it is sent: position error and the NEES of the kinematic state.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.schedule import NodeSchedule
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Measurement, Start
from zentrack.transport.wire import Message
from zentrack.truth.simulation.simulate import simulate

#: the bus's clock at step 0, and the share of a period before a step's deadline
T0, FRAC = 1000.0, 0.5


class SplitRing:
    """``nodes`` realtime trackers on ``scenario``'s ring for ``steps`` steps of its period (``fusion``,
    ``fusion_params``: the rule, as ``--fusion`` / ``--fusion-param``; default the scenario's)."""

    def __init__(self, nodes: int = 8, steps: int = 400, seed: int = 0, scenario: str = "patrol",
                 fusion: str | None = None, fusion_params: dict | None = None) -> None:
        self.scn = simulate(builtin_spec(scenario, nodes=nodes, steps=steps), runs=1, seed=seed)
        self.ts = self.scn.ts
        more = {} if fusion is None else {"fusion": fusion, "fusion_params": fusion_params or {}}
        self.setup = RunSetup.from_data(self.scn, "teskf", 1e-6, None, "realtime", FRAC, "split", **more)
        self.keys = Keys("split")
        self.now = T0 - 1.0
        self.sent: list[tuple[int, str, bytes]] = []
        self.incarnation = 0
        self.nodes = [self._new(i) for i in range(nodes)]
        self.frozen: set[int] = set()
        self.cut: set[int] = set()
        self.dead: set[int] = set()
        #: (steps, nodes): position error of every estimate published (NaN: none), NEES of its kinematic state
        self.err = np.full((steps, nodes), np.nan)
        self.nees = np.full((steps, nodes), np.nan)

    def _new(self, i: int) -> NodeSchedule:
        self.incarnation += 1
        cfg = self.setup.node_config(i)
        return NodeSchedule.diffusion(self.keys, cfg, Tracker(cfg), clock=self._clock, send=self._sender(i),
                                      cold_after=20, incarnation=self.incarnation, fusion_after_deadline=None)

    def _clock(self) -> float:
        return self.now

    def _sender(self, i: int) -> Callable[[str, bytes], None]:
        def send(channel: str, data: bytes) -> None:
            self.sent.append((i, channel, data))

        return send

    def _msg(self, tag: str, key: str, payload: bytes) -> Message:
        return Message(tag, key, payload, self.now)

    def _acts(self, i: int) -> bool:
        return i not in self.frozen and i not in self.dead

    def start(self, who: list[int] | None = None) -> None:
        """The truth's start message (and every peer alive) to ``who`` (default every tracker)."""
        n = len(self.nodes)
        start = Start(T0, self.ts, self.scn.steps, "realtime", tuple(range(n)), FRAC, self.scn.x0_estimate[0]).encode()
        for i in range(n) if who is None else who:
            for j in range(n):
                self.nodes[i].handle(self._msg("alive", self.keys.alive(j), b"put"))
            self.nodes[i].handle(self._msg("alive", self.keys.alive("truth"), b"put"))
            self.nodes[i].handle(self._msg("start", self.keys.start, start))

    def restart(self, i: int) -> None:
        """Tracker ``i`` back as a new process: no state, told the run's start."""
        self.nodes[i] = self._new(i)
        self.dead.discard(i)
        self.start([i])

    def _deliver(self) -> None:
        sent, self.sent = self.sent, []
        for i, ch, data in sent:
            if ch == "est":
                self._score(EstimateMessage.decode(data, i))
            if ch not in ("prior", "scan") or i in self.cut:
                continue
            key = self.keys.prior(i) if ch == "prior" else self.keys.scan(i)
            for j, node in enumerate(self.nodes):
                if self._acts(j) and j not in self.cut and i in node.payload.tracker.neighbours:
                    node.handle(self._msg(ch, key, data))

    def _score(self, m: EstimateMessage) -> None:
        d = m.x[:6] - self.scn.truth[0, m.k, :6]
        self.err[m.k, m.sender] = float(np.linalg.norm(d[:3]))
        self.nees[m.k, m.sender] = float(d @ np.linalg.solve(m.P[:6, :6], d))

    def _at(self, t: float) -> None:
        self.now = t
        for j, node in enumerate(self.nodes):
            if self._acts(j):
                node.advance()

    def step(self, k: int) -> None:
        """Step ``k`` in realtime: the measurements at t_k, the messages, the deadline, the step's end."""
        t_k, deadline = T0 + k * self.ts, T0 + (k + FRAC) * self.ts
        self._at(t_k + 0.001)
        for i in range(len(self.nodes)):
            if self._acts(i):
                z = self.scn.measurements[0, k, i]
                self.nodes[i].handle(self._msg("meas", self.keys.meas(i),
                                               Measurement(k, k * self.ts, i, z, None, self.now).encode()))
        self._deliver()
        for t in (t_k + 0.002, deadline - COAST_MARGIN_S, deadline, deadline + 0.001, t_k + self.ts - 0.001):
            self._at(t)
            self._deliver()


def run_split(start: int, after: int = 60, restart_after: int = 21, thaw_after: int = 51, cut_for: int = 51,
              **ring: Any) -> SplitRing:
    """The soak hour's faults of step 10800 from step ``start`` on an 8-tracker ring: node 0 cut for ``cut_for``
    steps, node 2 killed and restarted ``restart_after`` steps later, node 3 frozen and thawed ``thaw_after`` steps
    later; ``after`` steps past ``start`` in all. ``ring``: :class:`SplitRing`'s settings."""
    net = SplitRing(steps=start + after, **ring)
    net.start()
    for k in range(start + after):
        if k == start:
            net.cut.add(0)
            net.dead.add(2)
            net.frozen.add(3)
        if k == start + restart_after:
            net.restart(2)
        if k == start + thaw_after:
            net.frozen.discard(3)
        if k == start + cut_for:
            net.cut.discard(0)
        net.step(k)
    return net


def split_windows(start: int, restart_after: int = 21, thaw_after: int = 51, cut_for: int = 51) -> list[dict]:
    """:func:`run_split`'s faults as the soak's fault windows (:func:`~zentrack.cluster.soak.faults.fault_windows`)."""
    return [{"kind": "cut", "node": 0, "start": start, "end": start + cut_for, "undo": "heal"},
            {"kind": "kill", "node": 2, "start": start, "end": start + restart_after, "undo": "restart"},
            {"kind": "freeze", "node": 3, "start": start, "end": start + thaw_after, "undo": "thaw"}]
