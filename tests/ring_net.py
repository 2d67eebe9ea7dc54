"""An in-memory ring of realtime trackers on ``patrol`` with the soak's tracker faults applied by hand: a tracker
killed (and restarted as a new process would be), frozen (SIGSTOP: it neither hears nor acts) or cut off (its
messages neither leave nor arrive). Built on :mod:`tests.schedule_net`'s bus and clock: the real node schedule,
the real wire codec, no Zenoh and no processes, so a fault's every step is deterministic
(tests/test_soak_reach.py)."""
from __future__ import annotations

import numpy as np
from schedule_net import FRAC, T0, TS, Net, deadline

from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.schedule import NodeSchedule
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Measurement
from zentrack.truth.simulation.simulate import simulate


class RingNet(Net):
    """``nodes`` realtime trackers on ``scenario``'s ring (``patrol``: bearing-only) for ``steps`` steps."""

    def __init__(self, nodes: int = 8, steps: int = 400, seed: int = 0, scenario: str = "patrol") -> None:
        self.scn = simulate(builtin_spec(scenario, nodes=nodes, steps=steps), runs=1, seed=seed)
        self.setup = RunSetup.from_data(self.scn, "teskf", 1e-6, None, "realtime", FRAC, "test")
        self.keys = Keys("unit")
        self.now = T0 - 1.0
        self.sent: list[tuple[int, str, bytes]] = []
        self.configure = None
        self.incarnation = 100
        self.nodes = [self._new(i) for i in range(nodes)]
        self.frozen: set[int] = set()
        self.cut: set[int] = set()
        self.dead: set[int] = set()
        #: (steps, nodes) position error of every estimate published (NaN: none) and its NEES (position, velocity)
        self.err = np.full((steps, nodes), np.nan)
        self.nees = np.full((steps, nodes), np.nan)

    def _new(self, i: int) -> NodeSchedule:
        self.incarnation += 1
        cfg = self.setup.node_config(i)
        return NodeSchedule.diffusion(self.keys, cfg, Tracker(cfg), clock=lambda: self.now,
                                      send=lambda ch, data, i=i: self.sent.append((i, ch, data)), cold_after=20,
                                      incarnation=self.incarnation, fusion_after_deadline=None)

    def _acts(self, i: int) -> bool:
        return i not in self.frozen and i not in self.dead

    def restart(self, i: int) -> None:
        """Tracker ``i`` back as a new process (no state), told the run's start as the truth's start message does."""
        self.nodes[i] = self._new(i)
        self.dead.discard(i)
        self.start(who=[i])

    def deliver(self) -> list:
        sent, self.sent = self.sent, []
        for i, ch, data in sent:
            if ch == "est":
                self._score(EstimateMessage.decode(data, i))
            if ch not in ("prior", "scan") or i in self.cut:
                continue
            key = self.keys.prior(i) if ch == "prior" else self.keys.scan(i)
            for j, node in enumerate(self.nodes):
                if self._acts(j) and j not in self.cut and i in node.payload.tracker.neighbours:
                    node.handle(self.msg(ch, key, data))
        return []

    def _score(self, m: EstimateMessage) -> None:
        d = m.x[:6] - self.scn.truth[0, m.k, :6]
        self.err[m.k, m.sender] = float(np.linalg.norm(d[:3]))
        self.nees[m.k, m.sender] = float(d @ np.linalg.solve(m.P[:6, :6], d))

    def at(self, t: float) -> None:
        self.now = t
        for j, node in enumerate(self.nodes):
            if self._acts(j):
                node.advance()

    def measure(self, k: int, who=None) -> None:
        for i in range(len(self.nodes)):
            if self._acts(i):
                z = self.scn.measurements[0, k, i]
                self.nodes[i].handle(self.msg("meas", self.keys.meas(i),
                                              Measurement(k, k * TS, i, z, None, self.now).encode()))

    def step(self, k: int) -> None:
        """Step ``k`` in realtime: measurements at t_k, messages delivered, the deadline, the step's end."""
        for t in (T0 + k * TS + 0.001, T0 + k * TS + 0.002, deadline(k) - COAST_MARGIN_S, deadline(k),
                  deadline(k) + 0.001, T0 + (k + 1) * TS - 0.001):
            self.at(t)
            if t == T0 + k * TS + 0.001:
                self.measure(k)
            self.deliver()
