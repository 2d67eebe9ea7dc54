"""The in-memory network the schedule tests step by hand (tests/test_node_schedule*.py, and the tests of the
relay, the clock offset, the latency budget and the fast paths): three realtime nodes, a shared clock and a bus.

No Zenoh and no processes: messages are encoded with the real wire codec and delivered by hand, so every
transition is checked deterministically."""
from __future__ import annotations

from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.node.diffusion.fusion_policy import CONFLICT_SETTLE_S as SETTLE
from zentrack.node.diffusion.tracker import Tracker
from zentrack.node.schedule import NodeSchedule
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.transport import wire
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Measurement, Start
from zentrack.transport.wire import Message
from zentrack.truth.simulation.simulate import simulate

__all__ = ["FRAC", "SETTLE", "T0", "TS", "Net", "deadline", "ests", "run_steps"]

TS, FRAC, T0 = 0.1, 0.5, 1000.0


class Net:
    """Three realtime nodes on a ring (everyone neighbours everyone), a shared clock and a hand-driven bus.

    ``fusion_after_deadline``: False (the default here) pins the schedule in which round 1 goes out with the
    estimate, which most phase tests below step through; None lets the node decide from the timing, as a
    tracker process does (the tests of fusion after the deadline)."""

    def __init__(self, nodes: int = 3, steps: int = 200, cold_after: int = 20,
                 fusion_after_deadline: bool | None = False, configure=None, filter_kind: str = "teskf",
                 **more) -> None:
        self.scn = simulate(builtin_spec("exp2", nodes=nodes, steps=steps), runs=1, seed=3)
        self.setup = RunSetup.from_data(self.scn, filter_kind, 1e-6, None, "realtime", FRAC, "test", **more)
        self.keys = Keys("unit")
        self.now = T0 - 1.0
        self.sent: list[tuple[int, str, bytes]] = []
        self.configure = configure  # configure(cfg): changes node cfg.node's slice before it is built
        self.nodes = [self._make(i, cold_after, fusion_after_deadline) for i in range(nodes)]
        self.frozen: set[int] = set()  # SIGSTOPped nodes: they neither receive nor act

    def _make(self, i: int, cold_after: int, fusion_after_deadline: bool | None = False) -> NodeSchedule:
        cfg = self.setup.node_config(i)
        if self.configure is not None:
            self.configure(cfg)
            cfg.validate()
        return NodeSchedule.diffusion(self.keys, cfg, Tracker(cfg), clock=lambda: self.now,
                            send=lambda ch, data, i=i: self.sent.append((i, ch, data)), cold_after=cold_after,
                            incarnation=100 + i, fusion_after_deadline=fusion_after_deadline)

    def msg(self, tag: str, key: str, payload: bytes) -> Message:
        return Message(tag, key, payload, self.now)

    def start(self, who=None) -> None:
        start = Start(T0, TS, self.scn.steps, "realtime", tuple(list(range(len(self.nodes)))), FRAC,
                                  self.scn.x0_estimate[0]).encode()
        for i in who if who is not None else range(len(self.nodes)):
            node = self.nodes[i]
            for j in range(len(self.nodes)):
                node.handle(self.msg("alive", self.keys.alive(j), b"put"))
            node.handle(self.msg("alive", self.keys.alive("truth"), b"put"))
            node.handle(self.msg("start", self.keys.start, start))

    def measure(self, k: int, who=None) -> None:
        for i in who if who is not None else range(len(self.nodes)):
            if i in self.frozen:
                continue
            z = self.scn.measurements[0, k, i]
            self.nodes[i].handle(self.msg("meas", self.keys.meas(i), Measurement(k, k * TS, i, z, None, self.now).encode()))

    def deliver(self) -> list[tuple[int, str, dict]]:
        """Hand every prior sent so far to the sender's neighbours; return what was sent (decoded)."""
        out, sent, self.sent = [], self.sent, []
        for i, ch, data in sent:
            out.append((i, ch, wire.unpack(data)))
            if ch in ("prior", "scan"):
                key = self.keys.prior(i) if ch == "prior" else self.keys.scan(i)
                for j, node in enumerate(self.nodes):
                    if i in node.payload.tracker.neighbours and j not in self.frozen:
                        node.handle(self.msg(ch, key, data))
        return out

    def at(self, t: float) -> None:
        self.now = t
        for j, node in enumerate(self.nodes):
            if j not in self.frozen:
                node.advance()


def deadline(k: int) -> float:
    return T0 + (k + FRAC) * TS


def run_steps(net: Net, first: int, last: int, measured=lambda k, i: True) -> list[tuple[int, str, dict]]:
    """Steps first..last at realtime: measurements at t_k (where ``measured``), priors delivered, deadlines."""
    log = []
    for k in range(first, last + 1):
        net.at(T0 + k * TS + 0.001)
        net.measure(k, [i for i in range(len(net.nodes)) if measured(k, i)])
        net.at(T0 + k * TS + 0.002)
        log += net.deliver()
        net.at(deadline(k) - COAST_MARGIN_S)  # coasting nodes act here
        log += net.deliver()
        net.at(deadline(k))  # fusion after the deadline shares round 1 here
        log += net.deliver()
        net.at(deadline(k) + 0.001)
        log += net.deliver()
    return log


def ests(log, k=None):
    return [(i, m) for i, ch, m in log if ch == "est" and (k is None or m["k"] == k)]
