"""``zentrack viewer``: subscribes to a run and streams it to Rerun (file, web viewer or native viewer).

Entities (timelines ``step`` and ``time`` = k·Ts):

- ``world/truth/position`` point, ``world/truth/path`` one segment per step;
- ``world/sensors`` (static), ``world/nodes/<i>/estimate`` point, ``.../trail`` one segment per step,
  ``.../ellipsoid`` the 3-σ position covariance ellipsoid (half sizes 3·sqrt(eig), principal axes),
  ``.../ray`` the current bearing line of sight (bearing scenarios) or ``.../measurement`` (point scenarios);
- with clutter (seed 001): ``world/nodes/<i>/clutter`` the clutter returns' rays (dimmed; the target's return,
  known from the replayed scenario, is ``.../ray``), ``.../particles`` a subsample of the node's particle cloud,
  ``metrics/beta_target/<i>`` the association probability the node gave the target's return, and
  ``world/fused/{estimate,ellipsoid}`` the paper's fusion centre (covariance-weighted, once every node's
  estimate of a step is in);
- ``metrics/<name>/<i>`` time series: position error, NEES (with its 95 % χ² band), trace of the position
  covariance, step latency, pairs fused;
- ``events``: liveliness joins and departures and newly rejected messages, as a text log.

- with moving sensors (seed 002 UAVs, seed 003 satellites): ``world/platforms/<i>/{position,trail}`` from the
  pose each scan carries, and ``world/graph`` the communication links between the current positions; when
  the sensors are far from the target (satellites hundreds of km up), markers and lines are drawn at a fixed
  size on screen (Rerun UI points) so the target's track and the satellites both stay visible, and
  ``world/fused/{estimate,ellipsoid}`` is the CI (uniform weights) of every node's estimate;
- with a multi-round fusion rule (seed 002 consensus): ``metrics/disagreement/<l>`` the spread of the nodes'
  position estimates after round l of each step (RMS distance to their mean, from the round messages
  ``prior/<i>``), which shrinks round after round.

- with an extended object (seed 004): the true and every node's estimated outline, the scan points, sensor
  and relay nodes in two styles, the graph, and ``metrics/gw/<i>`` (:mod:`zentrack.viewer.extent_view`).

Sinks: ``--save PATH.rrd`` (with ``write_footer=False`` so a crash or Ctrl-C still leaves a readable file up to
the last flush), ``--serve`` (a ``rerun --serve-web`` child bound to ``--bind``, 127.0.0.1 by default), and
``--spawn`` (native viewer; needs a display). Memory stays flat: chunks are flushed on a timer and the file
sink keeps no footer index.
"""
from __future__ import annotations

import argparse
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.common.procs import StopFlag, die_with_parent, freeze_heap, setup_logging
from zentrack.config.run_setup import resolve_setup
from zentrack.fusion.consistency import anees_band
from zentrack.fusion.feedforward import covariance_weighted_fusion
from zentrack.fusion.filters import FilterContext, make_node_filter
from zentrack.fusion.fusion_rules import ci_combine
from zentrack.fusion.rules import make_rule
from zentrack.transport.codec import MAX_ROUNDS, Message, WireError
from zentrack.transport.keys import node_id
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage, Stop, Truth
from zentrack.transport.zsession import Inbox, open_session, zenoh_config
from zentrack.viewer.extent_view import ExtentView
from zentrack.viewer.geometry import bearing_direction, covariance_ellipsoid
from zentrack.viewer.ports import check_ports_free

log = logging.getLogger("zentrack.viewer")

METRICS = ("position_error", "nees", "trace_p", "latency_ms", "pairs_fused")
#: clutter rays (dimmed) and the fusion centre's estimate (seed 001 scenarios)
CLUTTER_RGB = np.array([110, 110, 110], dtype=np.uint8)
FUSED_RGB = [255, 215, 0]
#: sensors further than this from the scene's origin (m) make the viewer draw markers at a fixed screen size
FAR_SENSORS_M = 50_000.0


def node_color(i: int, n: int) -> list[int]:
    h = (i / max(n, 1)) % 1.0
    r, g, b = (np.clip(np.abs((h * 6 + off) % 6 - 3) - 1, 0, 1) for off in (0, 4, 2))
    return [int(200 * r + 40), int(200 * g + 40), int(200 * b + 40)]


def blueprint(nodes: int, clutter: bool = False, rounds: bool = False, extent: bool = False) -> rrb.Blueprint:
    history = rrb.VisibleTimeRanges([rrb.VisibleTimeRange("step", start=rrb.TimeRangeBoundary.infinite(),
                                                          end=rrb.TimeRangeBoundary.cursor_relative())])
    trails: dict[rr.encodings.EntityPathLike, rrb.VisibleTimeRanges] = {
        "world/truth/path": history, **{f"world/nodes/{i}/trail": history for i in range(nodes)},
        **{f"world/platforms/{i}/trail": history for i in range(nodes)}}
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="3-D: truth, estimates, 3σ ellipsoids, bearings", overrides=trails),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="metrics/position_error", name="position error (m)"),
                rrb.TimeSeriesView(origin="metrics/nees", name="NEES (grey: 95% band)"),
                rrb.TimeSeriesView(origin="metrics/trace_p", name="trace of position covariance (m²)"),
                rrb.TimeSeriesView(origin="metrics/latency_ms", name="step latency (ms)"),
                rrb.TimeSeriesView(origin="metrics/pairs_fused", name="pairs fused"),
                *([rrb.TimeSeriesView(origin="metrics/beta_target", name="β of the target's return")] if clutter else []),
                *([rrb.TimeSeriesView(origin="metrics/disagreement", name="disagreement per round (m)")]
                  if rounds else []),
                *([rrb.TimeSeriesView(origin="metrics/gw", name="Gaussian Wasserstein distance (m)")] if extent else []),
                rrb.TextLogView(origin="events", name="events"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class ColumnBuffer:
    """Rows per entity, sent with one ``send_columns`` call per entity every flush (far cheaper than one
    ``log`` call per row). A crash loses at most the rows since the last flush."""

    KINDS = {
        "scalar": lambda rows: rr.Scalars.columns(scalars=[r[0] for r in rows]),
        "point": lambda rows: rr.Points3D.columns(positions=[r[0] for r in rows], colors=[r[1] for r in rows],
                                                  radii=[r[2] for r in rows]),
        "segment": lambda rows: rr.LineStrips3D.columns(strips=[r[0] for r in rows], colors=[r[1] for r in rows],
                                                        radii=[r[2] for r in rows]),
        "cloud": lambda rows: rr.Points3D.columns(
            positions=np.concatenate([r[0] for r in rows]), colors=np.concatenate([r[1] for r in rows]),
            radii=np.concatenate([r[2] for r in rows])).partition([len(r[0]) for r in rows]),
        "segments": lambda rows: rr.LineStrips3D.columns(
            strips=[s for r in rows for s in r[0]], colors=np.concatenate([r[1] for r in rows]),
            radii=np.concatenate([r[2] for r in rows])).partition([len(r[0]) for r in rows]),
        "ellipsoid": lambda rows: rr.Ellipsoids3D.columns(
            centers=[r[0] for r in rows], half_sizes=[r[1] for r in rows], quaternions=[r[2] for r in rows],
            colors=[r[3] for r in rows], fill_mode=[rr.components.FillMode.MajorWireframe] * len(rows)),
    }

    def __init__(self, rec: rr.RecordingStream, ts: float) -> None:
        self.rec, self.ts = rec, ts
        self.rows: dict[tuple[str, str], list] = {}

    def add(self, entity: str, kind: str, step: int, *values) -> None:
        self.rows.setdefault((entity, kind), []).append((step, values))

    def flush(self) -> None:
        for (entity, kind), rows in self.rows.items():
            steps = np.array([r[0] for r in rows])
            self.rec.send_columns(
                entity,
                indexes=[rr.TimeColumn("step", sequence=steps), rr.TimeColumn("time", duration=steps * self.ts)],
                columns=self.KINDS[kind]([r[1] for r in rows]),
            )
        self.rows.clear()


class Viewer:
    def __init__(self, session, keys, setup, rec: rr.RecordingStream, flush_s: float = 1.0) -> None:
        self.keys, self.rec, self.flush_s = keys, rec, flush_s
        self.scn = setup.scenario
        self.ts = self.scn.ts
        self.m = self.scn.nodes
        self.inbox = Inbox(rate_per_key=1e9, max_queued=100_000)  # every round of every node, faster in lockstep
        self.truth: dict[int, np.ndarray] = {}
        self.last_est: dict[int, np.ndarray] = {}
        self.pending: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        self.last_truth: np.ndarray | None = None
        self.rejected: dict[int, dict] = {}
        self.fusion_inputs: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        self.logged = {"est": 0, "truth": 0, "meas": 0, "bad": 0}
        self.stopped = False
        self.current_step = 0
        self.colors = [node_color(i, self.m) for i in range(self.m)]
        n_dim = self.scn.truth.shape[-1]
        self.band = anees_band(n_dim, 1)
        self.moving = self.scn.sensor_track is not None
        track = self.scn.sensor_track if self.moving else self.scn.sensors[None]
        self.far = bool(np.max(np.linalg.norm(track, axis=-1)) > FAR_SENSORS_M)
        self.poses: dict[int, np.ndarray] = {}  # the latest pose of each moving sensor
        self.edges = [(i, int(j)) for i in range(self.m) for j in np.flatnonzero(self.scn.adjacency[i]) if j > i]
        info = round_message_dims(setup)  # None: one round per step, no disagreement to draw
        self.round_dims: dict[str, int] | None = None if info is None else info[0]
        self.rounds: int | None = None if info is None else info[1]
        self.round_x: dict[tuple[int, int], dict[int, np.ndarray]] = {}
        self.subs = [
            session.declare_subscriber(keys.truth, self.inbox.callback("truth")),
            session.declare_subscriber(keys.est("*"), self.inbox.callback("est")),
            session.declare_subscriber(keys.meas("*"), self.inbox.callback("meas")),
            session.declare_subscriber(keys.stop, self.inbox.callback("stop")),
            session.liveliness().declare_subscriber(keys.alive("*"), self.inbox.liveliness_callback(), history=True),
        ]
        if self.round_dims is not None:
            self.subs.append(session.declare_subscriber(keys.prior("*"), self.inbox.callback("prior")))
        self.token = session.liveliness().declare_token(keys.alive("viewer"))
        self.buf = ColumnBuffer(rec, self.ts)
        self.extent = ExtentView(self.scn, self.buf, self.colors) if self.scn.plant == "eot" else None
        #: the state components drawn as a position (an extended object's centre is 2-D, on the surface)
        self.pos_dims = 2 if self.extent is not None else min(3, n_dim)
        self._log_static()

    def _log_static(self) -> None:
        rec, scn = self.rec, self.scn
        if self.extent is not None:
            self.extent.log_static(rec)
        elif scn.truth.shape[-1] >= 3 and scn.sensor_track is None:
            rec.log("world/sensors", rr.Points3D(scn.sensors, colors=self.colors, radii=4.0,
                                                 labels=[f"sensor {i}" for i in range(self.m)]), static=True)
        for i in range(self.m):
            for name in METRICS:
                rec.log(f"metrics/{name}/{i}", rr.SeriesLines(colors=[self.colors[i]], names=[f"node {i}"]), static=True)
        if scn.has_scans and self.extent is None:
            for i in range(self.m):
                rec.log(f"metrics/beta_target/{i}", rr.SeriesLines(colors=[self.colors[i]], names=[f"node {i}"]),
                        static=True)
        for rnd in range(1, (self.rounds or 0) + 1):
            shade = int(60 + 180 * rnd / max(self.rounds or 1, 1))
            rec.log(f"metrics/disagreement/{rnd}", rr.SeriesLines(colors=[[shade, shade, 255]], names=[f"round {rnd}"]),
                    static=True)
        for side in ("lo", "hi"):
            rec.log(f"metrics/nees/band_{side}", rr.SeriesLines(colors=[[128, 128, 128]], names=[f"95% {side}"]), static=True)

    def r(self, radius: float) -> float:
        """A marker's radius: scene units, or (far sensors) a fixed size on screen (negative: UI points)."""
        return -float(np.clip(radius, 1.0, 6.0)) if self.far else radius

    def _time(self, k: int) -> None:
        self.current_step = max(self.current_step, k)
        self.rec.set_time("step", sequence=k)
        self.rec.set_time("time", duration=k * self.ts)

    def run(self, stop: StopFlag, duration: float | None, stop_grace: float = 1.0) -> None:
        """Log until ctl/stop (then ``stop_grace`` seconds more for stragglers), a signal, or ``duration``."""
        end = None if duration is None else time.time() + duration
        next_flush = time.time() + self.flush_s
        while not stop and (end is None or time.time() < end):
            msg = self.inbox.get(0.2)
            while msg is not None:
                was_stopped = self.stopped
                self.handle(msg)
                if self.stopped and not was_stopped:
                    end = time.time() + stop_grace if end is None else min(end, time.time() + stop_grace)
                msg = self.inbox.get(0.0) if time.time() < next_flush else None
            if time.time() >= next_flush:
                self.buf.flush()
                next_flush = time.time() + self.flush_s
        self.buf.flush()

    def handle(self, msg: Message) -> None:
        try:
            last = self.scn.steps - 1  # a step beyond the run would stretch the timeline (or break Rerun's)
            if msg.tag == "truth":
                truth = Truth.decode(msg.payload)
                self._check_state(truth.k, truth.x)
                self._on_truth(truth)
            elif msg.tag == "est":
                i = self.keys.node_of(msg.key)
                if i is not None and i < self.m:
                    est = EstimateMessage.decode(msg.payload, i)
                    self._check_state(est.k, est.x)
                    self._on_est(i, est)
            elif msg.tag == "meas":
                i = self.keys.node_of(msg.key)
                if i is not None and i < self.m:
                    self._on_meas(i, Measurement.decode(msg.payload, i, self.scn.measurements.shape[-1], 0, last))
            elif msg.tag == "prior":
                i = self.keys.node_of(msg.key)
                if i is not None and i < self.m and self.round_dims is not None:  # the last is for step `steps`
                    self._on_round(i, RoundMessage.decode(msg.payload, i, self.round_dims, 0, last + 1, MAX_ROUNDS))
            elif msg.tag == "alive":
                who = self.keys.last_segment(msg.key)
                joined = msg.payload == b"put"
                self._time(self.current_step)
                self.rec.log("events", rr.TextLog(f"{'node ' if node_id(who) is not None else ''}{who} {'joined' if joined else 'left'}",
                                                  level="INFO" if joined else "WARN"))
            elif msg.tag == "stop":
                Stop.decode(msg.payload)  # the truth's (anything else on ctl/stop is counted and ignored)
                self.stopped = True
        except WireError as err:
            self.logged["bad"] += 1
            if self.logged["bad"] <= 3:
                log.warning("viewer: dropped a %s message (%s)", msg.tag, err)

    def _check_state(self, k: int, x: np.ndarray) -> None:
        """A true state or estimate is drawn and scored against the scenario's: one of its steps, its dimension."""
        if k >= self.scn.steps:
            raise WireError("future", f"step {k} beyond the run's {self.scn.steps}")
        if x.shape[0] != self.scn.truth.shape[-1]:
            raise WireError("shape", f"x: dimension {x.shape[0]}, the scenario's is {self.scn.truth.shape[-1]}")

    def _on_truth(self, t: Truth) -> None:
        k, x = t.k, t.x
        self.truth[k] = x
        self.truth.pop(k - 50, None)
        self.current_step = max(self.current_step, k)
        p = self._pos(x)
        white = [255, 255, 255]
        self.buf.add("world/truth/position", "point", k, p, white, self.r(5.0))
        if self.last_truth is not None:
            self.buf.add("world/truth/path", "segment", k, [self.last_truth, p], white, self.r(1.0))
        self.last_truth = p
        if self.extent is not None:
            self.extent.truth(k, x)
        for i, (xe, ce) in self.pending.pop(k, {}).items():
            self._log_errors(i, k, xe, ce, x)
        for old in [j for j in self.pending if j < k - 50]:
            del self.pending[old]
        if self.moving and len(self.poses) >= 2:
            links = [[self.poses[i], self.poses[j]] for i, j in self.edges if i in self.poses and j in self.poses]
            if links:
                self.buf.add("world/graph", "segments", k, links, np.tile([90, 90, 140], (len(links), 1)),
                             np.full(len(links), 0.4))
        self.buf.add("metrics/nees/band_lo", "scalar", k, self.band[0])
        self.buf.add("metrics/nees/band_hi", "scalar", k, self.band[1])
        self.logged["truth"] += 1

    def _log_errors(self, i: int, k: int, x: np.ndarray, cov: np.ndarray, truth: np.ndarray) -> None:
        err = x - truth
        d = self.pos_dims
        self.buf.add(f"metrics/position_error/{i}", "scalar", k, float(np.linalg.norm(err[:d])))
        self.buf.add(f"metrics/nees/{i}", "scalar", k, float(err @ np.linalg.solve(cov, err)))
        if self.extent is not None:
            self.extent.score(i, k, x, truth)

    def _pos(self, x: np.ndarray) -> np.ndarray:
        return x[:3] if self.pos_dims == 3 else np.array([x[0], x[1], 0.0])

    def _on_est(self, i: int, e: EstimateMessage) -> None:
        k, x, cov = e.k, e.x, e.P
        self.current_step = max(self.current_step, k)
        base = f"world/nodes/{i}"
        p = self._pos(x)
        color = self.colors[i]
        self.buf.add(f"{base}/estimate", "point", k, p, color, self.r(3.0))
        if i in self.last_est:
            self.buf.add(f"{base}/trail", "segment", k, [self.last_est[i], p], color, self.r(0.5))
        self.last_est[i] = p
        if self.extent is not None:
            self.extent.estimate(i, k, x)
        d = self.pos_dims
        c3 = np.eye(3) * 1e-9
        c3[:d, :d] = cov[:d, :d]
        half, quat = covariance_ellipsoid(c3)
        self.buf.add(f"{base}/ellipsoid", "ellipsoid", k, p, half, quat, color)
        truth = self.truth.get(k)
        if truth is not None:
            self._log_errors(i, k, x, cov, truth)
        else:  # the estimate overtook the truth message: score it when the truth arrives
            self.pending.setdefault(k, {})[i] = (x, cov)
        self.buf.add(f"metrics/trace_p/{i}", "scalar", k, float(np.trace(cov[:d, :d])))
        if e.t_meas_pub is not None:
            self.buf.add(f"metrics/latency_ms/{i}", "scalar", k, (e.t_pub - e.t_meas_pub) * 1e3)
        self.buf.add(f"metrics/pairs_fused/{i}", "scalar", k, float(e.fused))
        clutter = self.scn.has_scans and self.extent is None
        if clutter:
            self._on_diagnostics(i, k, e)
        if clutter or (self.far and self.m > 1):
            self._fuse_centre(k, i, x, cov)
        if e.counters is None:  # counters ride on every tenth estimate only
            self.logged["est"] += 1
            return
        rejected = e.counters.get("rejected") or {}
        before = self.rejected.get(i, {})
        new = {r: n - before.get(r, 0) for r, n in rejected.items() if n > before.get(r, 0)}
        if new:
            self._time(k)
            self.rec.log("events", rr.TextLog(f"node {i} rejected " + ", ".join(f"{n} {r}" for r, n in sorted(new.items())),
                                              level="WARN"))
        self.rejected[i] = dict(rejected)
        self.logged["est"] += 1

    def _on_meas(self, i: int, m: Measurement) -> None:
        """Draw a scan: a ray per bearing return, a point per Cartesian return (none for an empty scan). In
        clutter, the target's return (known from the replayed scenario) is drawn in the node's colour and the
        clutter rays dimmed under ``.../clutter``."""
        if m.returns is None or len(m.returns) == 0:
            return
        k = m.k
        if self.extent is not None:
            self.extent.scan(i, k, m.returns)
            self.logged["meas"] += 1
            return
        base = f"world/nodes/{i}"
        s = self.scn.sensors[i] if m.pose is None else m.pose
        if self.moving:
            if i in self.poses:
                self.buf.add(f"world/platforms/{i}/trail", "segment", k, [self.poses[i], s], self.colors[i],
                             self.r(1.0))
            self.buf.add(f"world/platforms/{i}/position", "point", k, s, self.colors[i], self.r(40.0))
            self.poses[i] = s
        target = self._target_index(k, i)
        z = m.returns[0 if target is None else target]  # point-target scans have one return
        if self.scn.measurement == "bearing":
            ref = self.last_est.get(i)
            length = float(np.linalg.norm(ref - s)) * 1.2 if ref is not None else 1000.0
            if target is None or target >= 0:
                self.buf.add(f"{base}/ray", "segment", k, [s, s + length * bearing_direction(*z)], self.colors[i],
                             self.r(0.3))
            if self.scn.has_scans:
                clutter = [r for j, r in enumerate(m.returns) if j != target]
                strips = [[s, s + length * bearing_direction(*r)] for r in clutter]
                self.buf.add(f"{base}/clutter", "segments", k, strips, np.tile(CLUTTER_RGB, (len(strips), 1)),
                             np.full(len(strips), 0.15))
        elif self.scn.measurement == "point":
            self.buf.add(f"{base}/measurement", "point", k, z, self.colors[i], 1.5)
        self.logged["meas"] += 1

    def _target_index(self, k: int, i: int) -> int | None:
        """Where the target's return sits in node i's scan of step k (-1: missed); None without clutter."""
        if self.scn.scan_target is None or not 0 <= k < self.scn.steps:
            return None
        return int(self.scn.scan_target[0, k, i])

    def _on_diagnostics(self, i: int, k: int, e: EstimateMessage) -> None:
        """A particle filter's cloud (subsample) and the association probability of the target's return."""
        if e.samples is not None and len(e.samples):
            pts = np.stack([self._pos(x) for x in e.samples])
            faint = np.tile(np.asarray(self.colors[i]) // 2 + 60, (len(pts), 1))
            self.buf.add(f"world/nodes/{i}/particles", "cloud", k, pts, faint, np.full(len(pts), 0.8))
        target = self._target_index(k, i)
        beta = e.beta
        if beta is not None and target is not None:
            value = float(beta[target]) if 0 <= target < len(beta) else 0.0
            self.buf.add(f"metrics/beta_target/{i}", "scalar", k, value)

    def _on_round(self, i: int, p: RoundMessage) -> None:
        """A node's round message: once every node's message of (step, round) is in, their disagreement."""
        if p.warm:
            return
        block = p.blocks.get("state", p.blocks.get("prior"))  # consensus on measurements: the prior
        if block is None:
            return
        y_mat, y_vec = block
        key = (p.k, p.round)
        got = self.round_x.setdefault(key, {})
        got[i] = self._pos(np.linalg.solve(y_mat, y_vec))
        for old in [kr for kr in self.round_x if kr[0] < p.k - 10]:
            del self.round_x[old]
        if len(got) == self.m:
            pts = np.stack(list(got.values()))
            spread = float(np.sqrt(np.mean(np.sum((pts - pts.mean(axis=0)) ** 2, axis=-1))))
            self.buf.add(f"metrics/disagreement/{p.round}", "scalar", p.k, spread)
            del self.round_x[key]

    def _fuse_centre(self, k: int, i: int, x: np.ndarray, cov: np.ndarray) -> None:
        """A fusion centre drawn as ``world/fused`` once every node's estimate of step k is in: the paper's
        covariance-weighted combination (seed 001), or CI with uniform weights (satellites: their estimates
        are correlated through the diffusion, so only CI is consistent)."""
        got = self.fusion_inputs.setdefault(k, {})
        got[i] = (x, cov)
        for old in [j for j in self.fusion_inputs if j < k - 20]:
            del self.fusion_inputs[old]
        if len(got) < self.m:
            return
        del self.fusion_inputs[k]
        order = sorted(got)
        means, covs = np.stack([got[j][0] for j in order]), np.stack([got[j][1] for j in order])
        if self.scn.has_scans:
            fused = covariance_weighted_fusion(means, covs)
        else:
            infos = np.linalg.inv(covs)
            fused = ci_combine(infos, np.einsum("mij,mj->mi", infos, means), np.full(len(order), 1.0 / len(order)))
        p = self._pos(fused.mean)
        d = min(3, fused.mean.shape[0])
        c3 = np.eye(3) * 1e-9
        c3[:d, :d] = fused.cov[:d, :d]
        half, quat = covariance_ellipsoid(c3)
        self.buf.add("world/fused/estimate", "point", k, p, FUSED_RGB, self.r(4.0))
        self.buf.add("world/fused/ellipsoid", "ellipsoid", k, p, half, quat, FUSED_RGB)

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.token.undeclare()


def round_message_dims(setup) -> tuple[dict[str, int], int] | None:
    """The blocks of the run's round messages (what ``prior/<i>`` carries) and the rounds per step, when the
    rule has more than one round; None otherwise."""
    params = setup.run_parameters()
    rule = make_rule(params.fusion, params.fusion_params)
    if rule.rounds(0) < 2:
        return None
    scn = setup.scenario
    node = make_node_filter(params.filter, FilterContext.from_scenario(scn, np.random.default_rng(0)), params.filter_params)
    probe = node.initial(scn.x0_estimate[0], np.random.default_rng(0))
    dims = rule.message_dims({name: int(p.vector.shape[-1]) for name, p in node.blocks(probe).items()})
    return dims, int(rule.rounds(0))


def rerun_binary() -> str:
    """The real ``rerun`` executable shipped by rerun-sdk (``rerun_cli/rerun``), not the ``rerun`` console
    script, which is a Python wrapper that runs the binary as a child: stopping the wrapper would leave the
    server running and holding its ports."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).with_name("rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    return shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))


def start_web_server(args: argparse.Namespace) -> subprocess.Popen:
    """A ``rerun --serve-web`` child: gRPC server + web viewer bound to ``--bind``, in its own process group
    (:func:`stop_web_server` stops the whole group) and sent SIGTERM by the kernel if this process dies."""
    return subprocess.Popen([rerun_binary(), "--serve-web", "--bind", args.bind, "--port", str(args.grpc_port),
                             "--web-viewer-port", str(args.web_port), "--server-memory-limit", "512MiB"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, preexec_fn=die_with_parent)


def wait_listening(server: subprocess.Popen, host: str, ports: list[int], timeout: float = 15.0,
                   stop: StopFlag | None = None) -> None:
    """Poll until the server accepts connections on every port (or ``stop`` is set); ValueError if it exits or
    takes too long."""
    host = "127.0.0.1" if host in ("0.0.0.0", "") else ("::1" if host == "::" else host)
    end = time.monotonic() + timeout
    pending = list(ports)
    while pending and not stop:
        if server.poll() is not None:
            raise ValueError(f"the Rerun web server (rerun --serve-web) exited with status {server.returncode} "
                             f"before listening on {host}:{pending[0]}")
        try:
            with socket.create_connection((host, pending[0]), timeout=0.5):
                pending.pop(0)
            continue
        except OSError:
            pass
        if time.monotonic() > end:
            raise ValueError(f"the Rerun web server is not listening on {host}:{pending[0]} after {timeout:.0f} s")
        time.sleep(0.05)


def stop_web_server(server: subprocess.Popen, grace: float = 5.0) -> None:
    """SIGTERM the server's whole process group, SIGKILL it after ``grace`` seconds, and reap the server."""
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(server.pid, sig)
        except ProcessLookupError:
            pass
        try:
            server.wait(timeout=wait)
            break
        except subprocess.TimeoutExpired:
            continue
    try:  # anything else the server started in its group
        os.killpg(server.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def run(args: argparse.Namespace) -> int:
    setup_logging()
    if not (args.save or args.serve or args.spawn):
        raise ValueError("choose at least one sink: --save PATH.rrd, --serve or --spawn")
    if args.save and not args.save.endswith(".rrd"):
        raise ValueError(f"--save: {args.save} must end in .rrd")
    if not args.flush_s > 0:
        raise ValueError(f"--flush-s must be positive, got {args.flush_s}")
    setup = resolve_setup(args)
    zenoh_config(args, "viewer")  # every flag and file is checked before anything starts
    if args.serve:
        if args.web_port == args.grpc_port:
            raise ValueError(f"--web-port and --grpc-port must differ, both are {args.web_port}")
        check_ports_free({args.web_port: "--web-port", args.grpc_port: "--grpc-port"}, args.bind)
    if args.nice > 0:
        os.nice(args.nice)
    stop = StopFlag()  # SIGTERM from here on ends the loops below and runs every finally
    server = None
    try:
        if args.serve:
            server = start_web_server(args)
            wait_listening(server, args.bind, [args.grpc_port, args.web_port], stop=stop)
        with open_session(args, "viewer") as (session, keys):
            if not stop:
                serve(args, setup, session, keys, stop)
    finally:
        if server is not None:
            stop_web_server(server)
    return 0


def serve(args: argparse.Namespace, setup, session, keys, stop: StopFlag) -> None:
    """Set up the Rerun sinks and log the run until it stops."""
    batcher = rr.ChunkBatcherConfig(flush_tick=args.flush_s, flush_num_bytes=4 * 1024 * 1024, flush_num_rows=2**20)
    rec = rr.RecordingStream("zentrack", recording_id=f"zentrack-{args.run}", batcher_config=batcher)
    sinks: list[rr.GrpcSink | rr.FileSink] = []
    if args.spawn:
        rec.spawn(connect=False)
        sinks.append(rr.GrpcSink())
    if args.save:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(args.save, write_footer=False))
    if args.serve:
        sinks.append(rr.GrpcSink(f"rerun+http://{args.bind}:{args.grpc_port}/proxy"))
        log.info("web viewer: http://%s:%d/?url=rerun%%2Bhttp://%s:%d/proxy", args.bind, args.web_port, args.bind, args.grpc_port)
    try:
        extended = setup.scenario.plant == "eot"
        layout = blueprint(setup.scenario.nodes, clutter=setup.scenario.has_scans and not extended,
                           rounds=round_message_dims(setup) is not None, extent=extended)
        rec.set_sinks(*sinks, default_blueprint=layout)
        rec.send_blueprint(layout)
        viewer = Viewer(session, keys, setup, rec, args.flush_s)
        freeze_heap()
        log.info("viewer: run %s, %d nodes, sinks %s", keys.run, setup.scenario.nodes,
                 [s for s, on in (("file", args.save), ("web", args.serve), ("spawn", args.spawn)) if on])
        try:
            viewer.run(stop, None)
            if args.serve and args.linger > 0:
                viewer.run(stop, args.linger)
        finally:
            viewer.close()
            log.info("viewer: logged %s", viewer.logged)
    finally:
        rec.flush()
        rec.disconnect()
