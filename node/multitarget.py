"""A many-target tracker's schedule as a state machine free of I/O: the step of its multi-target tracker, the
track list it publishes, the neighbours' lists it fuses, and when.

Like :class:`~zentrack.node.schedule.NodeSchedule` it is fed messages (:meth:`MultiTargetSchedule.handle`) and
wake-ups (:meth:`MultiTargetSchedule.advance`), reads an injected clock and publishes through an injected
``send(channel, payload)``; ``node/process.py`` moves the bytes. The mathematics is
:class:`~zentrack.fusion.multitarget.network.NetworkTracker`'s. One step k (:class:`MtPhase`)::

    AWAIT_MEAS    step k's scan arrives (or the coast deadline passes: every track coasts)
                  -> the local tracker's step; the track list of step k goes out on ``tracks/<i>``
                  (bearing sensors: the scan goes out on ``scan/<i>`` first, and
    [AWAIT_SCANS] every live neighbour's scan of step k is in, or the scan deadline passes
                  -> the local tracker's step on the neighbours' scans, then its own: one bearing sensor
                  sees no range, so its tracks are started by triangulation and held by every scan)
    AWAIT_LISTS   every live neighbour's list of step k is in (lockstep: every participating neighbour's), or
                  the fusion window ends (realtime: just before step k + 1's sample)
                  -> the lists are fused into the tracks; the neighbours' targets it does not hold are queued
                  as tracks for step k + 1 (a restarted node takes its tracks back this way)
    AWAIT_MEAS    step k + 1

A list published after step k's deadline counts as a deadline miss (``miss`` on the list). A node that joins a
realtime run under way (a restart) starts at the current step with no track. Neighbours' lists and scans are
decoded and checked (:class:`~zentrack.transport.track_messages.TrackList`,
:class:`~zentrack.transport.scan_messages.ForwardedScan`): a malformed, forged, oversized or duplicated one is
refused and counted by its reason, and nothing of it reaches the tracker (``node/mt_admission.py``).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from enum import StrEnum

import numpy as np

from zentrack.config.node_config import NodeConfig
from zentrack.fusion.models import make_plant
from zentrack.fusion.multitarget.network import NetworkTracker, TrackerSettings
from zentrack.fusion.scan import Scan
from zentrack.fusion.track_to_track import TrackEstimate
from zentrack.node.counters import COUNTERS_EVERY_STEPS, RejectLog
from zentrack.node.mt_admission import MtAdmission
from zentrack.node.run_control import ControlledRun, Membership, StopConfirm, start_conflicts
from zentrack.node.timing import COAST_MARGIN_S, StepTiming
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Measurement, Start
from zentrack.transport.scan_messages import ForwardedScan
from zentrack.transport.track_messages import MAX_TRACKS, TrackList

log = logging.getLogger("zentrack.node")



class MtPhase(StrEnum):
    """Where a many-target tracker is in its step."""

    IDLE = "idle"  #: before ``ctl/start``
    AWAIT_MEAS = "await_meas"  #: waiting for step k's scan, or the deadline to coast
    AWAIT_SCANS = "await_scans"  #: (bearing sensors) own scan sent; waiting for the neighbours' scans of step k
    AWAIT_LISTS = "await_lists"  #: list of step k out; waiting for the neighbours' lists of step k


#: phase -> the phases it may move to
MT_TRANSITIONS: dict[MtPhase, frozenset[MtPhase]] = {
    MtPhase.IDLE: frozenset({MtPhase.AWAIT_MEAS}),
    MtPhase.AWAIT_MEAS: frozenset({MtPhase.AWAIT_LISTS, MtPhase.AWAIT_SCANS}),
    MtPhase.AWAIT_SCANS: frozenset({MtPhase.AWAIT_LISTS}),
    MtPhase.AWAIT_LISTS: frozenset({MtPhase.AWAIT_MEAS}),
}


def tracker_settings(cfg: NodeConfig) -> TrackerSettings:
    """The multi-target tracker a node's slice describes (ValueError for a single-target slice)."""
    if cfg.multitarget is None:
        raise ValueError(f"node {cfg.node}: its configuration is not a many-target one")
    return TrackerSettings(cfg.filter, make_plant(cfg.plant, cfg.ts, cfg.plant_params), cfg.measurement,
                           np.asarray(cfg.p0, dtype=float), cfg.ts, **cfg.multitarget)


class MultiTargetSchedule(MtAdmission, ControlledRun):
    """Node ``cfg.node``'s many-target schedule (module docstring)."""

    def __init__(self, keys: Keys, cfg: NodeConfig, clock: Callable[[], float], send: Callable[[str, bytes], None],
                 incarnation: int = 0) -> None:
        self.keys, self.clock, self.send, self.incarnation = keys, clock, send, incarnation
        self.id, self.mode, self.neighbours = cfg.node, cfg.mode, list(cfg.neighbours)
        # ids are (born step, node, serial): a node restarted within the step of its last ids must not issue them
        # again, so a realtime node's serials start at its start time in microseconds (they only grow); lockstep
        # starts at 0 (its ids are those of the in-process network, tests/test_multitarget_live.py)
        first_serial = 0 if cfg.mode == "lockstep" else int(time.time() * 1e6)
        self.network = NetworkTracker(cfg.node, tracker_settings(cfg), first_serial)
        self.exchange = self.network.settings.exchanges_scans  # bearing sensors: scans to and from the neighbours
        #: whose scans it takes: its neighbours of its own kind (a mixed network's point radars send none)
        self.scan_from = (list(self.neighbours) if cfg.scan_neighbours is None else list(cfg.scan_neighbours)) \
            if self.exchange else []
        self.measurement_dim = cfg.measurement_dim
        if cfg.sensor is None:
            raise ValueError(f"node {cfg.node}: a many-target node needs a sensor (relays track one target)")
        self.sensor_position = np.asarray(cfg.sensor.position, dtype=float)
        self.noise_cov = np.asarray(cfg.sensor.noise_cov, dtype=float)
        self.timing = StepTiming(cfg.mode, cfg.deadline_frac, cfg.ts, budget=cfg.latency_budget_ms / 1000)
        self.rejects = RejectLog(self.id, clock)
        self.members, self.stop_confirm = Membership(), StopConfirm()
        self.dropped: dict[str, int] = {}
        self.counters = {"meas_rx": 0, "lists_rx": 0, "late": 0, "coasted": 0, "misses": 0, "steps": 0,
                         "partial_fusions": 0, "takeovers": 0, "scans_rx": 0, "partial_scans": 0}
        self.steps: int | None = None
        self.participants: set[int] | None = None
        self.start_payload: bytes | None = None
        self.start_fields: Start | None = None
        self.stopped = False
        self.phase = MtPhase.IDLE
        self.step = 0
        self.early: list[Message] = []  # messages before the start
        self.scans: dict[int, tuple[Measurement, float]] = {}  # own measurements by step (and receive time)
        self.lists: dict[int, dict[int, list[TrackEstimate]]] = {}  # step -> sender -> its tracks
        self.nb_scans: dict[int, dict[int, Scan | None]] = {}  # step -> sender -> its scan (None: it has none)
        self._own: tuple[Measurement | None, float | None] | None = None  # (exchange) step k's own, until its step
        self._fused = 0  # the neighbours' lists the last fusion took

    # ------------------------------------------------------------------ what the process reads
    t0 = property(lambda self: self.timing.t0)
    ts = property(lambda self: self.timing.ts)
    live = property(lambda self: self.members.live)
    truth_gone_since = property(lambda self: self.members.truth_gone_since)

    def subscriptions(self) -> list[tuple[str, str]]:
        """``(key, tag)`` of what the node hears besides the control keys: its measurements, its neighbours'
        lists (and, bearing sensors, their scans)."""
        keys = self.keys
        return [(keys.meas(self.id), "meas"), *[(keys.tracks(j), "tracks") for j in self.neighbours],
                *[(keys.scan(j), "scan") for j in self.scan_from]]

    def publications(self) -> dict[str, tuple[str, bool]]:
        """channel -> ``(key, express)``."""
        return {"tracks": (self.keys.tracks(self.id), True),
                **({"scan": (self.keys.scan(self.id), True)} if self.exchange else {})}

    def flood_rate(self) -> float:
        """Messages per second and key the flood guard lets through: 4x one per step, plus 20."""
        return 4.0 / (self.ts or 0.1) + 20.0

    def done(self) -> bool:
        return self.stopped or (self.mode == "lockstep" and self.steps is not None and self.step >= self.steps)

    def snapshot(self) -> dict:
        """The counters as published every few lists and written to ``node-<i>.json``."""
        return {**self.counters, "rejected": dict(self.rejects.counts), "dropped": dict(self.dropped),
                "tracks": len(self.network.tracker.tracks), "incarnation": self.incarnation}

    def timeout(self) -> float:
        """How long to wait for a message before the next timed action (at most 0.2 s, at least 1 ms)."""
        if self.mode != "realtime" or self.timing.t0 is None or (self.steps is not None and self.step >= self.steps):
            return 0.2
        wait = self._due(self.step) - self.clock()
        return min(0.2, max(0.001, wait))

    def _due(self, k: int) -> float:
        """When the current phase of step k stops waiting (realtime)."""
        if self.phase is MtPhase.AWAIT_MEAS:
            return self.timing.deadline(k) - COAST_MARGIN_S
        if self.phase is MtPhase.AWAIT_SCANS:
            return self.timing.scan_deadline(k, 1)
        return self.timing.fusion_window_end(k + 1)

    # ------------------------------------------------------------------ messages
    def handle(self, msg: Message) -> None:
        """One message: validated, then kept or acted on; a bad one is counted under its reason."""
        try:
            tag = msg.tag
            if tag == "alive":
                self._on_alive(msg.key, msg.payload == b"put")
            elif tag == "start":
                self._on_start(Start.decode(msg.payload), msg.payload)
            elif tag == "stop":
                self._on_stop(msg.payload)
            elif tag in ("meas", "tracks", "scan"):
                if self.timing.t0 is None:
                    if len(self.early) < 8 * (len(self.neighbours) + 1):
                        self.early.append(msg)
                    return
                {"meas": self._on_meas, "tracks": self._on_list, "scan": self._on_scan}[tag](msg)
        except WireError as err:
            self.rejects.add(msg.tag, err)

    def _on_start(self, start: Start, payload: bytes) -> None:
        if start.mode != self.mode:
            raise WireError("schema", f"run mode {start.mode} differs from this node's {self.mode}")
        if self.start_fields is not None:
            diff = start_conflicts(start, self.start_fields)
            if diff:
                raise WireError("conflict", f"a start that contradicts the run under way ({', '.join(diff)})")
            return
        self.timing.t0, self.steps, self.timing.ts = start.t0, start.steps, start.ts
        self.participants, self.start_fields, self.start_payload = set(start.participants), start, payload
        now = self.clock()
        fresh = self.mode == "lockstep" or now < self.timing.deadline(0) - COAST_MARGIN_S
        self.step = 0 if fresh else max(0, self.timing.k_now(now))
        self._enter(MtPhase.AWAIT_MEAS)
        log.info("node %d: %s at step %d, %d participants, %d neighbours", self.id,
                 "cold start" if fresh else "joined the run under way", self.step, len(self.participants),
                 len(self.neighbours))
        early, self.early = self.early, []
        for msg in early:
            self.handle(msg)

    # ------------------------------------------------------------------ steps
    def _enter(self, phase: MtPhase) -> None:
        if phase is not self.phase and phase not in MT_TRANSITIONS[self.phase]:
            raise RuntimeError(f"no transition from {self.phase.value} to {phase.value}")
        self.phase = phase

    def advance(self) -> None:
        """Take the transitions that are due now."""
        self._check_pending_stop()
        for _ in range(4):
            before = (self.phase, self.step)
            if self.steps is not None and self.step >= self.steps:
                return
            if self.phase is MtPhase.AWAIT_MEAS:
                self._try_step()
            elif self.phase is MtPhase.AWAIT_SCANS:
                self._try_scans()
            elif self.phase is MtPhase.AWAIT_LISTS:
                self._try_fuse()
            if (self.phase, self.step) == before:
                return

    def _try_step(self) -> None:
        now, k = self.clock(), self.step
        realtime = self.mode == "realtime"
        if realtime and self.timing.k_now(now) > k + 1:  # fell behind (stalled): go on at the current step
            self.counters["misses"] += self.timing.k_now(now) - k  # steps k .. k_now - 1 are skipped
            self.step = k = self.timing.k_now(now)
        got = self.scans.pop(k, None)
        if got is None and not (realtime and now >= self._due(k)):
            return
        meas, t_recv = got if got is not None else (None, None)
        if not self.exchange:
            self._local_step(k, meas, t_recv, [])
            return
        returns = None if meas is None else meas.returns  # "no scan" goes out too: nobody need wait for it
        self.send("scan", ForwardedScan(k, k * self.network.settings.ts, self.id, self.id, returns,
                                        None if returns is None else self.sensor_position,
                                        None if returns is None else self.noise_cov, self.clock()).encode())
        self._own = (meas, t_recv)
        self._enter(MtPhase.AWAIT_SCANS)

    def _try_scans(self) -> None:
        """Bearing sensors: step k's own scan is out; step once the neighbours' are in (or their deadline)."""
        k = self.step
        held = self.nb_scans.get(k, {})
        complete = self._waited(held, self.scan_from)
        if complete is None:
            return
        self.counters["partial_scans"] += not complete
        assert self._own is not None
        (meas, t_recv), self._own = self._own, None
        others = [sc for j in self.scan_from if (sc := held.get(j)) is not None]  # the neighbours' order, as in-process
        self._local_step(k, meas, t_recv, others)

    def _local_step(self, k: int, meas: Measurement | None, t_recv: float | None, others: list[Scan]) -> None:
        """The local tracker's step k on the neighbours' scans ``others`` and the own measurement (None: none in
        time), then the track list of step k goes out."""
        realtime = self.mode == "realtime"
        last = self.network.step
        if last is not None and k <= last:  # cannot happen: a step is taken once
            raise RuntimeError(f"node {self.id}: step {k} after {last}")
        scan = None
        if meas is not None and meas.returns is not None:
            scan = Scan(k, self.id, meas.returns, self.sensor_position, self.noise_cov)
        t0 = time.perf_counter()
        if self.exchange:  # the neighbours' scans, then the own
            self.network.local_step(k, others + ([scan] if scan is not None else []))
        else:
            self.network.local_step(k, scan)
        update_us = (time.perf_counter() - t0) * 1e6
        self.counters["coasted"] += scan is None
        t_pub = self.clock()
        miss = realtime and t_pub > self.timing.deadline(k)
        self.counters["misses"] += miss
        self.counters["steps"] += 1
        self.counters["takeovers"] = self.network.takeovers
        counters = self.snapshot() if self.counters["steps"] % COUNTERS_EVERY_STEPS == 1 else None
        tracks = TrackList.of(k, k * self.network.settings.ts, self.id, self.network.estimates(limit=MAX_TRACKS), t_pub,
                              t_meas_pub=None if meas is None else meas.t_pub,
                              t_recv=t_recv,
                              update_us=update_us, fused=self._fused, coasted=scan is None, miss=miss,
                              counters=counters)
        self.send("tracks", tracks.encode())
        self._enter(MtPhase.AWAIT_LISTS)

    def expected(self) -> set[int]:
        """Whose lists (and scans) step k waits for."""
        return self.members.expected(self.neighbours, self.participants, self.mode == "lockstep")

    def _waited(self, held: Mapping[int, object], among: list[int] | None = None) -> bool | None:
        """Whether the wait for the neighbours' messages of the step (``among`` them: all) is over: True, every
        expected one is in; False, the phase's deadline passed without them (realtime); None, wait on."""
        expected = self.expected() if among is None else self.expected() & set(among)
        if expected <= set(held):
            return True
        return False if self.mode == "realtime" and self.clock() >= self._due(self.step) else None

    def _try_fuse(self) -> None:
        k = self.step
        held = self.lists.get(k, {})
        complete = self._waited(held)
        if complete is None:
            return
        self.counters["partial_fusions"] += not complete
        self.network.fuse(held)
        self._fused = len(held)
        for step in [s for s in self.lists if s <= k]:
            del self.lists[step]
        for step in [s for s in self.scans if s <= k]:
            del self.scans[step]
        for step in [s for s in self.nb_scans if s <= k]:
            del self.nb_scans[step]
        self.step = k + 1
        self._enter(MtPhase.AWAIT_MEAS)
