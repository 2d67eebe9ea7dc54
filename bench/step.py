"""``zentrack bench step``: the Python a tracker's main thread runs per step, in microseconds, piece by piece.

No Zenoh and no processes: N :class:`~zentrack.node.schedule.NodeSchedule` objects (each with its
:class:`~zentrack.node.diffusion.tracker.Tracker`) run paper 0 Experiment 2 in lockstep in this process, their messages
encoded with the real wire codec and handed over by an in-memory bus. Two kinds of figure:

- *node step*: the time spent inside the schedules' ``handle`` and ``advance`` calls (decoding and checking the measurement
  and the neighbours' priors, the local update, the estimate, the prediction and its pair, the gate, the CI
  fusion, the encoding), divided by N x steps; the bus itself is not counted;
- *pieces*: each of those calls alone on one node's real messages, in a tight loop, and beside the CI fusion
  the general (stacked, batched) code path that the single-receiver path replaces, on the same messages.

Figures are medians over rounds. A tight loop is cheaper than a tracker process, whose core idles between
steps (about 2x per call on these machines), so compare ratios, not absolute values, with a live run.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Callable

import numpy as np

from zentrack.common.argtypes import float_in, positive_int
from zentrack.common.report import fmt_num, table, write_json
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.defaults import DEFAULT_FILTER, DEFAULT_FUSION
from zentrack.fusion.gate import ci_gate_passes, information_mean_cov
from zentrack.fusion.rules import FusionRule
from zentrack.node.diffusion.payload import DiffusionPayload
from zentrack.node.diffusion.tracker import Pair, Tracker
from zentrack.node.schedule import NodeSchedule
from zentrack.transport.codec import MAX_ROUNDS, Message
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Start
from zentrack.truth.simulation.simulate import simulate

#: the idle comparison's steps and rounds (every call waits the gap, so it runs far fewer than the busy figure)
IDLE_STEPS, IDLE_ROUNDS = 40, 3
T0 = 1000.0  # the lockstep run's start time (no deadlines in lockstep: only its value in the messages)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=positive_int, default=10, help="trackers in the in-process network (default 10)")
    p.add_argument("--steps", type=positive_int, default=300, help="lockstep steps per round (default 300)")
    p.add_argument("--rounds", type=positive_int, default=5, help="timing rounds; the median is kept (default 5)")
    p.add_argument("--filter", default=DEFAULT_FILTER, help=f"local filter (default {DEFAULT_FILTER}, the DTESKF node)")
    p.add_argument("--idle-ms", type=float_in(0.0, 1000.0, "milliseconds"), default=0.0,
                   help="also time the node step with this idle gap before every call, as a tracker process idles "
                        "between its messages (its caches go cold): on fewer steps, the ratio printed (default 0: off)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


class LockstepNetwork:
    """N schedules on an in-memory bus, stepped in lockstep; ``busy`` accumulates the time inside them."""

    def __init__(self, nodes: int, steps: int, filter_kind: str, fusion: str = DEFAULT_FUSION,
                 fusion_params: dict | None = None, seed: int = 0, adjacency: np.ndarray | None = None) -> None:
        spec = builtin_spec("exp2", nodes=nodes, steps=steps)
        if adjacency is not None:  # another graph than the ring (weights from the scenario's rule for it)
            spec = dataclasses.replace(spec, graph="explicit", adjacency=np.asarray(adjacency, dtype=int).tolist())
        self.scn = simulate(spec, runs=1, seed=seed)
        self.setup = RunSetup.from_data(self.scn, filter_kind, mode="lockstep", source="bench step", fusion=fusion,
                                        fusion_params=dict(fusion_params or {}))
        self.keys = Keys("bench")
        self.outbox: list[tuple[int, str, bytes]] = []
        self.nodes = [self._node(i) for i in range(nodes)]
        self.busy = 0.0
        self.idle_s = 0.0  # a gap before every call (the caches of a process that idles between messages)
        start = Start(T0, self.scn.ts, steps, "lockstep", tuple(range(nodes)), 0.5, self.scn.x0_estimate[0]).encode()
        for node in self.nodes:
            for j in range(nodes):
                node.handle(Message("alive", self.keys.alive(j), b"put", T0))
            node.handle(Message("alive", self.keys.alive("truth"), b"put", T0))
            node.handle(Message("start", self.keys.start, start, T0))
        self.estimates: list[bytes] = []
        self.priors: list[tuple[int, bytes]] = []

    def _node(self, i: int) -> NodeSchedule[DiffusionPayload]:
        cfg = self.setup.node_config(i)

        def send(channel: str, data: bytes) -> None:
            self.outbox.append((i, channel, data))

        return NodeSchedule.diffusion(self.keys, cfg, Tracker(cfg), clock=time.perf_counter, send=send, incarnation=i)

    def _handle(self, node: NodeSchedule[DiffusionPayload], msg: Message) -> None:
        if self.idle_s:
            time.sleep(self.idle_s)
        t = time.perf_counter()
        node.handle(msg)
        node.advance()  # as the process loop does after each message
        self.busy += time.perf_counter() - t

    def step(self, k: int) -> None:
        for i, node in enumerate(self.nodes):
            z = self.scn.measurements[0, k, i]
            meas = Measurement(k, k * self.scn.ts, i, z, None, 0.0).encode()
            self._handle(node, Message("meas", self.keys.meas(i), meas, 0.0))
        while self.outbox:
            sent, self.outbox = self.outbox, []
            for i, channel, data in sent:
                if channel == "est":
                    self.estimates.append(data)
                    continue
                if channel == "prior":
                    self.priors.append((i, data))
                key = self.keys.prior(i) if channel == "prior" else self.keys.scan(i)
                for node in self.nodes:
                    if i in node.payload.tracker.neighbours:
                        self._handle(node, Message(channel, key, data, 0.0))


def _median_us(fn: Callable[[], object], count: int, rounds: int) -> float:
    fn()
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        for _ in range(count):
            fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)) / count * 1e6


def node_step_us(args: argparse.Namespace, idle_s: float = 0.0, steps: int | None = None,
                 rounds: int | None = None) -> tuple[float, LockstepNetwork]:
    results, net = [], None
    steps = steps or args.steps
    for _ in range(rounds or args.rounds):
        net = LockstepNetwork(args.nodes, steps, args.filter)
        net.idle_s = idle_s
        for k in range(steps):
            net.step(k)
        steps_done = min(node.payload.counters.steps for node in net.nodes)
        refused = sum(sum(node.ctx.rejects.counts.values()) for node in net.nodes)
        lonely = sum(node.payload.state.last_fused <= 1 for node in net.nodes)
        if steps_done != steps or refused or lonely:
            raise RuntimeError(f"the lockstep network did not run as a network: {steps_done} of {steps} steps, "
                               f"{refused} messages refused, {lonely} nodes fused alone at the end")
        results.append(net.busy / (args.nodes * steps) * 1e6)
    assert net is not None
    return float(np.median(results)), net


def pieces_us(net: LockstepNetwork, rounds: int, count: int = 2000) -> dict[str, float]:
    """Each piece of a step alone, on node 0's real messages of the run just made."""
    node = net.nodes[0]
    tracker = node.payload.tracker
    k = net.scn.steps // 2
    sender = tracker.neighbours[0]
    dims = tracker.block_dims
    prior = next(data for i, data in net.priors
                 if i == sender and RoundMessage.decode(data, sender, dims, max_round=MAX_ROUNDS).k == k)
    meas = Measurement(k, k * net.scn.ts, 0, net.scn.measurements[0, k, 0], None, 0.0).encode()
    decoded = RoundMessage.decode(prior, sender, dims)
    post = tracker.prior
    assert post is not None
    scans = [tracker.scan(k, net.scn.measurements[0, k, 0][None])]
    own = tracker.predict_pair(post, k + 1)
    theirs = {j: Pair(k + 1, decoded.blocks) for j in tracker.neighbours}
    kin = tracker.kinematic(post)
    mine = information_mean_cov(*own.blocks["state"])
    other = information_mean_cov(*decoded.blocks["state"])
    assert mine is not None and other is not None
    messages = [own.blocks] + [p.blocks for p in theirs.values()]
    weights = tracker.weights[[tracker.id, *tracker.neighbours]]
    pieces: dict[str, Callable[[], object]] = {
        "decode measurement": lambda: Measurement.decode(meas, 0, tracker.measurement_dim),
        "decode prior": lambda: RoundMessage.decode(prior, sender, dims),
        "local update": lambda: tracker.update(scans),
        "predict + pair": lambda: tracker.predict_pair(post, k + 1),
        "encode estimate": lambda: EstimateMessage(k, k * net.scn.ts, 0, kin.mean, kin.cov, t_pub=0.0,
                                                   counters=node.snapshot()).encode(),
        "encode prior": lambda: RoundMessage(k + 1, 0.0, 0, 1, own.blocks, 0.0).encode(),
        "gate: message estimate": lambda: information_mean_cov(*decoded.blocks["state"]),
        "gate: test": lambda: ci_gate_passes(mine[0], mine[1], other[0], other[1], 1e9),
        f"CI of {len(messages)} pairs, one receiver": lambda: tracker.rule.combine_one(1, weights, messages),
        f"CI of {len(messages)} pairs, stacked (general path)": lambda: FusionRule.combine_one(tracker.rule, 1, weights, messages),
    }
    saved = (tracker.prior, tracker.prior_step)
    out = {name: _median_us(fn, count, rounds) for name, fn in pieces.items()}
    tracker.prior, tracker.prior_step = saved
    return out


def run(args: argparse.Namespace) -> int:
    print(f"in-process lockstep network: Experiment 2, {args.nodes} trackers ({args.filter}), {args.steps} steps, "
          f"{args.rounds} rounds", file=sys.stderr)
    step, net = node_step_us(args)
    degree = float(np.mean([len(node.payload.tracker.neighbours) for node in net.nodes]))
    pieces = pieces_us(net, args.rounds)
    print(f"\nTracker main thread, µs per node-step (mean degree {degree:.1f}): {step:.1f}")
    print(table(["piece (node 0's messages, tight loop)", "µs"], [[name, fmt_num(us, 1)] for name, us in pieces.items()]))
    names = list(pieces)
    ratio = pieces[names[-1]] / pieces[names[-2]]
    print(f"\nCI: the general path costs {ratio:.2f}x the single-receiver path")
    idle: dict[str, float] = {}
    if args.idle_ms:
        steps = min(args.steps, IDLE_STEPS)  # every call waits the gap: fewer steps, and the same steps again warm
        warm, _ = node_step_us(args, 0.0, steps, IDLE_ROUNDS)
        cold, _ = node_step_us(args, args.idle_ms / 1e3, steps, IDLE_ROUNDS)
        idle = {"idle_ms": args.idle_ms, "steps": steps, "us_per_node_step_busy": warm, "us_per_node_step_idle": cold,
                "idle_over_busy": cold / warm}
        print(f"\nNode step with {args.idle_ms:g} ms idle before every call: {cold:.1f} µs, against {warm:.1f} µs "
              f"without ({steps} steps, median of {IDLE_ROUNDS}): {cold / warm:.2f}x")
    if args.json:
        write_json(args.json, {"nodes": args.nodes, "steps": args.steps, "filter": args.filter, "mean_degree": degree,
                               "us_per_node_step": step, "pieces_us": pieces, "ci_general_over_one": ratio,
                               **({"idle": idle} if idle else {})})
    return 0
