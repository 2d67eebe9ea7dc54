"""The many-target payload: the step of a multi-target tracker, the track list it publishes, the neighbours' lists
it fuses, and when; driven by :class:`~zentrack.node.schedule.NodeSchedule` like the single-target payload.

The mathematics is :class:`~zentrack.fusion.multitarget.network.NetworkTracker`'s. One step k
(:class:`~zentrack.node.phases.TrackListPhase`)::

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

With sensors of their own (``[sensor_timing]``, the slice's ``detections``), AWAIT_MEAS ends when step k's
window of detections is over (its end plus the lag): the local tracker's step takes them each at its own time
(``windows.py``) and the list, valid at ``t0 + k ts`` on this tracker's clock, goes out and is fused as above with
the neighbours' lists, each mapped from its sender's clock to this one's (``admission.py``). A list published after step
k's deadline counts as a deadline miss (``miss`` on the list). A node that joins a realtime run under way (a
restart) starts at the current step with no track, and with live neighbours holds back its list of that step: it
would hold one scan's tracks at most, and claim every other target gone (a soak of PMBM nodes on ``mt-50`` scored
such a list at 250 m GOSPA); it fuses its neighbours' lists of the step, and its next list holds their targets.
Neighbours' lists and scans are
decoded and checked (``admission.py``): a malformed, forged, oversized or duplicated one is refused and counted
by its reason, and nothing of it reaches the tracker.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Mapping

import numpy as np

from zentrack.config.node_config import NodeConfig
from zentrack.fusion.models import make_plant, plant_over
from zentrack.fusion.multitarget.network import NetworkTracker, TrackerSettings
from zentrack.fusion.scan import Scan
from zentrack.node.context import NodeContext
from zentrack.node.counters import COUNTERS_EVERY_STEPS
from zentrack.node.detections import SensorLink
from zentrack.node.diffusion.neighbour_clocks import NeighbourClocks
from zentrack.node.phases import TRACK_LIST_TRANSITIONS, TrackListPhase, checked_move
from zentrack.node.timing import COAST_MARGIN_S
from zentrack.node.track_lists.admission import TrackListAdmission
from zentrack.node.track_lists.windows import DetectionWindows
from zentrack.transport.codec import Message
from zentrack.transport.messages import Measurement, Start
from zentrack.transport.scan_messages import ForwardedScan
from zentrack.transport.track_messages import MAX_TRACKS, TrackList

log = logging.getLogger("zentrack.node")

#: the time a neighbour's list may take after its sender's clock says it is due: its step's time and its way (s)
LIST_DELAY_S = 0.1


def tracker_settings(cfg: NodeConfig) -> TrackerSettings:
    """The multi-target tracker a node's slice describes (ValueError for a single-target slice)."""
    if cfg.multitarget is None:
        raise ValueError(f"node {cfg.node}: its configuration is not a many-target one")
    return TrackerSettings(cfg.filter, make_plant(cfg.plant, cfg.ts, cfg.plant_params), cfg.measurement,
                           np.asarray(cfg.p0, dtype=float), cfg.ts, **cfg.multitarget)


def list_allowance_s(ts: float, deadline_frac: float) -> float:
    """How long after its own list a tracker of sensors of their own takes a neighbour's of the same time on its
    clock (s): its wait for the lists, from its list's publication to its fusion window's end (at least the
    deadline's part of a period, ``node/timing.py``), less :data:`LIST_DELAY_S` for the list's way and its
    sender's step. A neighbour whose clock is behind by less than that is waited for and its list predicted back;
    one further behind, its list of the step before predicted forward (``neighbour_clocks.py``, ``shift``)."""
    return max(deadline_frac * ts - LIST_DELAY_S, 0.0)


class TrackListPayload:
    """Node ``cfg.node``'s many-target steps (module docstring)."""

    def __init__(self, ctx: NodeContext, cfg: NodeConfig) -> None:
        self.ctx, self.neighbours = ctx, list(cfg.neighbours)
        # ids are (born step, node, serial): a node restarted within the step of its last ids must not issue them
        # again, so a realtime node's serials start at its start time in microseconds (they only grow); lockstep
        # starts at 0 (its ids are those of the in-process network, tests/test_multitarget_live.py)
        first_serial = 0 if cfg.mode == "lockstep" else int(time.time() * 1e6)
        #: sensors of their own (``windows.py``); None: the truth's scans on ``meas/<i>``
        self.windows = None if cfg.detections is None else DetectionWindows(
            ctx, [SensorLink(**link) for link in cfg.detections["sensors"]], cfg.measurement_dim)
        over = None if self.windows is None else (lambda dt: plant_over(cfg.plant, cfg.ts, dt, cfg.plant_params))
        self.network = NetworkTracker(cfg.node, tracker_settings(cfg), first_serial, over)
        self.exchange = self.network.settings.exchanges_scans  # bearing sensors: scans to and from the neighbours
        if self.exchange and self.windows is not None:  # (refused with the scenario: scenario_sensor_timing.py)
            raise ValueError(f"node {cfg.node}: bearing sensors exchange scans of each step; not with sensors of "
                             "their own")
        #: whose scans it takes: its neighbours of its own kind (a mixed network's point radars send none)
        self.scan_from = (list(self.neighbours) if cfg.scan_neighbours is None else list(cfg.scan_neighbours)) \
            if self.exchange else []
        self.measurement_dim = cfg.measurement_dim
        if cfg.sensor is None:
            raise ValueError(f"node {cfg.node}: a many-target node needs a sensor (relays track one target)")
        self.sensor_position = np.asarray(cfg.sensor.position, dtype=float)
        self.noise_cov = np.asarray(cfg.sensor.noise_cov, dtype=float)
        self.counters = {"meas_rx": 0, "lists_rx": 0, "late": 0, "coasted": 0, "misses": 0, "steps": 0,
                         "partial_fusions": 0, "takeovers": 0, "scans_rx": 0, "partial_scans": 0}
        #: sensors of their own: the tracker runs on its own clock, its neighbours' offsets estimated (or taken as
        #: synchronised, ``clock = "configured"``) and their lists predicted to its time (``admission.py``)
        self.clocks = None if self.windows is None or cfg.detections is None else NeighbourClocks(
            ctx.id, self.neighbours, cfg.ts, estimated=cfg.detections["clock"] == "estimated",
            allowance_s=list_allowance_s(cfg.ts, cfg.deadline_frac))
        self.intake = TrackListAdmission(ctx, self.neighbours, self.scan_from, self.measurement_dim, self.counters,
                                         self.clocks, None if self.clocks is None else self.network.predicted_over)
        self.phase = TrackListPhase.IDLE
        self.step = 0
        self._own: tuple[Measurement | None, float | None] | None = None  # (exchange) step k's own, until its step
        self._fused = 0  # the neighbours' lists the last fusion took
        #: the step a realtime node joined a run under way at: its list of that step is held back (module docstring)
        self._joined_at: int | None = None

    # ------------------------------------------------------------------ the payload interface
    def subscriptions(self) -> list[tuple[str, str]]:
        """Its measurements, its neighbours' lists (and, bearing sensors, their scans)."""
        keys, node = self.ctx.keys, self.ctx.id
        own = [(keys.meas(node), "meas")] if self.windows is None else self.windows.subscriptions()
        return [*own, *[(keys.tracks(j), "tracks") for j in self.neighbours],
                *[(keys.scan(j), "scan") for j in self.scan_from]]

    def publications(self) -> dict[str, tuple[str, bool]]:
        keys, node = self.ctx.keys, self.ctx.id
        return {"tracks": (keys.tracks(node), True), **({"scan": (keys.scan(node), True)} if self.exchange else {})}

    def flood_rate(self) -> float:
        """4x the most a sender sends on one key (a list per step; a sensor of its own, its scans at its rate), plus
        20."""
        per_s = 1.0 / (self.ctx.timing.ts or 0.1)
        if self.windows is not None:
            per_s = max(per_s, self.windows.fastest_hz())
        return 4.0 * per_s + 20.0

    def snapshot_parts(self) -> tuple[dict, dict]:
        extra: dict = {"tracks": len(self.network.tracker.tracks)}
        if self.windows is not None:
            extra["detections"] = self.windows.counts()
        return dict(self.counters), extra

    def detection_period_s(self) -> float | None:
        return None if self.windows is None else self.windows.intake.period_s

    def report_parts(self) -> dict:
        """Sensors of their own: each sensor's and each neighbour's clock offset to this tracker's as applied now
        (s; None before any sample)."""
        if self.windows is None or self.clocks is None:
            return {}
        return {"sensor_offsets_s": self.windows.offsets(), "neighbour_offsets_s": self.clocks.report()}

    def take_start(self, start: Start) -> None:
        pass  # the tracks start from the measurements, not from the start's x0

    def begin(self, fresh: bool, now: float) -> None:
        ctx = self.ctx
        self.step = 0 if fresh else max(0, ctx.timing.k_now(now))
        self._joined_at = None if fresh or not ctx.realtime or not self.neighbours else self.step
        self._enter(TrackListPhase.AWAIT_MEAS)
        log.info("node %d: %s at step %d, %d participants, %d neighbours", ctx.id,
                 "cold start" if fresh else "joined the run under way", self.step, len(ctx.participants or ()),
                 len(self.neighbours))

    def admit(self, msg: Message) -> None:
        if msg.tag == "det" and self.windows is not None:
            self.windows.admit(msg, self.step, self.phase is TrackListPhase.AWAIT_LISTS)
            return
        self.intake.admit(msg, self.step)

    def due(self, now: float) -> float:
        """When the current phase of the step stops waiting (realtime)."""
        timing, k = self.ctx.timing, self.step
        if self.phase is TrackListPhase.AWAIT_MEAS:
            return timing.deadline(k) - COAST_MARGIN_S if self.windows is None else self.windows.due(k)
        if self.phase is TrackListPhase.AWAIT_SCANS:
            return timing.scan_deadline(k, 1)
        return timing.fusion_window_end(k + 1)

    def advance(self, now: float) -> bool:
        steps = self.ctx.steps
        if steps is not None and self.step >= steps:
            return False
        before = (self.phase, self.step)
        if self.phase is TrackListPhase.AWAIT_MEAS:
            self._try_step()
        elif self.phase is TrackListPhase.AWAIT_SCANS:
            self._try_scans()
        elif self.phase is TrackListPhase.AWAIT_LISTS:
            self._try_fuse()
        return (self.phase, self.step) != before

    # ------------------------------------------------------------------ steps
    def _enter(self, phase: TrackListPhase) -> None:
        self.phase = checked_move(TRACK_LIST_TRANSITIONS, self.phase, phase)

    def _try_step(self) -> None:
        ctx = self.ctx
        now, k = ctx.clock(), self.step
        if ctx.realtime and ctx.timing.k_now(now) > k + 1:  # fell behind (stalled): go on at the current step
            self.counters["misses"] += ctx.timing.k_now(now) - k  # steps k .. k_now - 1 are skipped
            self.step = k = ctx.timing.k_now(now)
        if self.windows is not None:
            if now >= self.due(now):  # the window and the lag after it are over
                t0 = time.perf_counter()
                window = self.windows.step(self.network, k)
                self._publish(k, window.scans == 0, window.t_meas_pub, window.t_recv, (time.perf_counter() - t0) * 1e6)
            return
        got = self.intake.meas.pop(k, None)
        if got is None and not (ctx.realtime and now >= self.due(now)):
            return
        meas, t_recv = got if got is not None else (None, None)
        if not self.exchange:
            self._local_step(k, meas, t_recv, [])
            return
        returns = None if meas is None else meas.returns  # "no scan" goes out too: nobody need wait for it
        ctx.send("scan", ForwardedScan(k, k * self.network.settings.ts, ctx.id, ctx.id, returns,
                                       None if returns is None else self.sensor_position,
                                       None if returns is None else self.noise_cov, ctx.clock()).encode())
        self._own = (meas, t_recv)
        self._enter(TrackListPhase.AWAIT_SCANS)

    def _try_scans(self) -> None:
        """Bearing sensors: step k's own scan is out; step once the neighbours' are in (or their deadline)."""
        k = self.step
        complete = self._waited(self.intake.scans.get(k), self.scan_from)
        if complete is None:
            return
        held = self.intake.scans.take(k)
        self.counters["partial_scans"] += not complete
        assert self._own is not None
        (meas, t_recv), self._own = self._own, None
        others = [sc for j in self.scan_from if (sc := held.get(j)) is not None]  # the neighbours' order, as in-process
        self._local_step(k, meas, t_recv, others)

    def _local_step(self, k: int, meas: Measurement | None, t_recv: float | None, others: list[Scan]) -> None:
        """The local tracker's step k on the neighbours' scans ``others`` and the own measurement (None: none in
        time), then the track list of step k goes out."""
        ctx = self.ctx
        last = self.network.step
        if last is not None and k <= last:  # cannot happen: a step is taken once
            raise RuntimeError(f"node {ctx.id}: step {k} after {last}")
        scan = None
        if meas is not None and meas.returns is not None:
            scan = Scan(k, ctx.id, meas.returns, self.sensor_position, self.noise_cov)
        t0 = time.perf_counter()
        if self.exchange:  # the neighbours' scans, then the own
            self.network.local_step(k, others + ([scan] if scan is not None else []))
        else:
            self.network.local_step(k, scan)
        self._publish(k, scan is None, None if meas is None else meas.t_pub, t_recv, (time.perf_counter() - t0) * 1e6)

    def _publish(self, k: int, coasted: bool, t_meas_pub: float | None, t_recv: float | None,
                 update_us: float) -> None:
        """The track list of step k goes out (``t_meas_pub``, ``t_recv``: its last scan's publication and arrival,
        tracker clock), then the node waits for its neighbours'."""
        ctx = self.ctx
        self.counters["coasted"] += coasted
        t_pub = ctx.clock()
        miss = ctx.realtime and t_pub > ctx.timing.deadline(k)
        self.counters["misses"] += miss
        self.counters["steps"] += 1
        self.counters["takeovers"] = self.network.takeovers
        counters = ctx.snapshot(*self.snapshot_parts()) if self.counters["steps"] % COUNTERS_EVERY_STEPS == 1 else None
        tracks = TrackList.of(k, k * self.network.settings.ts, ctx.id, self.network.estimates(limit=MAX_TRACKS), t_pub,
                              t_meas_pub=t_meas_pub, t_recv=t_recv,
                              update_us=update_us, fused=self._fused, coasted=coasted, miss=miss,
                              counters=counters)
        if k == self._joined_at:  # one scan of its own and no neighbour's track yet: not the network's picture
            log.info("node %d: step %d: no list while it takes its neighbours' tracks over", ctx.id, k)
        else:
            ctx.send("tracks", tracks.encode())
        self._enter(TrackListPhase.AWAIT_LISTS)

    def _waited(self, held: Mapping[int, object], among: list[int] | None = None) -> bool | None:
        """Whether the wait for the neighbours' messages of the step (``among`` them: all) is over: True, every
        expected one is in; False, the phase's deadline passed without them (realtime); None, wait on."""
        expected = self.ctx.expected(self.neighbours)
        if among is not None:
            expected &= set(among)
        if expected <= set(held):
            return True
        now = self.ctx.clock()
        return False if self.ctx.realtime and now >= self.due(now) else None

    def _try_fuse(self) -> None:
        k = self.step
        held = self.intake.lists.get(k)
        complete = self._waited(held)
        if complete is None:
            return
        self.counters["partial_fusions"] += not complete
        self.network.fuse(held)
        self._fused = len(held)
        self.intake.used(k)
        self.step = k + 1
        self._enter(TrackListPhase.AWAIT_MEAS)
