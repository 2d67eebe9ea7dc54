"""The recorder: one core for every kind of run, holding a payload part for the kind of message it scores.

The core (:class:`Recorder`) joins the run like any observer: it subscribes to the part's channel on every node
(``est/*`` or ``tracks/*``), declares ``alive/recorder``, and drains what arrives. Each message is refused and
counted (``bad_messages``; the first few logged) when its key names no node of the run or the part cannot decode
it; otherwise the core keeps what every message says about its step, per (step, node): the latency (measurement
published -> message published), the wall-clock times, the local update's duration and the part's per-step
flags (coasted, deadline missed, ...), and banks the node's counters over its restarts (:mod:`.counters`). It
estimates each node's clock against its own as a tracker estimates its neighbours' (``t_pub`` on the node's clock
against the arrival on the recorder's, :class:`~zentrack.node.clock_offset.OffsetEstimator`), so that a part can
judge a tracker on its own clock at its estimates' time of validity (sensors of their own). The
part keeps the rest (the posteriors, or the track lists) and makes its kind's figures of ``summary.json`` with
the core's shared ones (:meth:`Recorder.node_entry`, :meth:`Recorder.latency_ms`, :func:`refused_counts`).

The parts: :class:`~zentrack.cluster.recording.estimates.Estimates` (one target, every node's posterior) and
:class:`~zentrack.cluster.recording.track_lists.TrackLists` (many targets, every node's track list).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np
import zenoh

from zentrack.cluster.recording.counters import CounterBank
from zentrack.common.atomic import replace_atomically
from zentrack.common.outages import runs_of
from zentrack.node.clock_offset import OffsetEstimator
from zentrack.transport.codec import Message, WireError
from zentrack.transport.zsession import Inbox

log = logging.getLogger("zentrack.recorder")

#: the largest offset of a node's clock to the recorder's that the recorder estimates (s)
CLOCK_TOLERANCE_S = 60.0


class Refusal(NamedTuple):
    """How a part's refused messages are told: the log line (``%s``: why), how many are logged, and the detail
    of a key that names no node of the run (``{}``: the key)."""

    note: str
    logged: int
    off_key: str


class StepMessage(Protocol):
    """What the core reads of every recorded message about its step (an estimate, a track list)."""

    @property
    def k(self) -> int: ...

    @property
    def t_pub(self) -> float: ...

    @property
    def t_meas_pub(self) -> float | None: ...

    @property
    def t_recv(self) -> float | None: ...

    @property
    def update_us(self) -> float | None: ...

    @property
    def counters(self) -> dict[str, Any] | None: ...


class Payload(Protocol):
    """A recorder's payload part: the message kind it decodes, what it keeps of it, its figures."""

    #: the per-node channel it records (:data:`~zentrack.transport.keys.CHANNELS`): ``est``, ``tracks``
    channel: str
    #: the per-step flags its messages carry (each a bool attribute of the message), kept by the core
    flag_names: tuple[str, ...]
    refusal: Refusal
    #: the run recorded: its ``steps``, ``nodes`` and ``ts`` (a scenario, or a many-target run's data)
    scn: Any

    def decode(self, payload: bytes, node: int) -> StepMessage:
        """The message node ``node`` published, checked against the run (WireError: refused)."""
        ...

    def keep(self, msg: Any, node: int, clock_offset: float = 0.0) -> None:
        """Keep what the part scores of a decoded message; ``clock_offset``: the node's clock less the recorder's
        as estimated when it came (s)."""
        ...

    def have(self) -> np.ndarray:
        """(steps, nodes): whether each node's message of each step was recorded."""
        ...

    def step_errors(self) -> np.ndarray:
        """(steps, nodes): each node's error at each step (NaN: nothing recorded)."""
        ...

    def nan_free(self) -> bool:
        """Whether everything recorded is finite."""
        ...

    def summary(self, rec: Recorder, reports: dict[int, dict], steps_run: int | None) -> dict:
        """The run's figures (:meth:`Recorder.summary`)."""
        ...

    def arrays(self, rec: Recorder) -> dict[str, np.ndarray]:
        """What :meth:`Recorder.save_estimates` writes, by name."""
        ...


class Recorder:
    """Records a run's messages of one kind and judges them (module docstring); ``part`` keeps the payload."""

    def __init__(self, session: zenoh.Session, keys, part: Payload) -> None:
        self.keys, self.part = keys, part
        k, m = part.scn.steps, part.scn.nodes
        self.inbox = Inbox(rate_per_key=1e9, max_queued=1_000_000)  # the recorder must not drop what it scores
        #: (steps, nodes) seconds from the measurement's publication to the message's (NaN where unknown)
        self.latency = np.full((k, m), np.nan)
        #: (steps, nodes) how long the node's local update of the step took (us), NaN where unknown
        self.update_us = np.full((k, m), np.nan)
        #: wall-clock times (s) of each step: truth published the measurement, the node received it, the node
        #: published its message (NaN where unknown): where a late step lost its time
        self.times = {name: np.full((k, m), np.nan) for name in ("t_meas_pub", "t_recv", "t_pub")}
        #: (steps, nodes) per-step flags of the part's messages (``Payload.flag_names``)
        self.flags = {name: np.zeros((k, m), dtype=bool) for name in part.flag_names}
        self.counters = CounterBank(m)
        #: each node's clock against the recorder's, estimated from its messages (``t_pub`` on its clock against
        #: their arrival on the recorder's: ``node/clock_offset.py``, 0 within its dead band)
        self.clocks = [OffsetEstimator(tolerance=CLOCK_TOLERANCE_S) for _ in range(m)]
        #: messages refused: on a key of no node of the run, or not decodable as the part's kind
        self.bad_messages = 0
        self.sub = session.declare_subscriber(keys.of(part.channel, "*"), self.inbox.callback(part.channel))
        self.token = session.liveliness().declare_token(keys.alive("recorder"))

    @property
    def scn(self) -> Any:
        """The run recorded (its steps, nodes, ts; the part's scenario or many-target data)."""
        return self.part.scn

    def drain(self, timeout: float = 0.0) -> int:
        """Process queued messages (waiting up to ``timeout`` for the first); returns how many."""
        return self.inbox.drain(self._record, timeout)

    def _record(self, msg: Message) -> None:
        part = self.part
        node = self.keys.node_of(msg.key)
        try:
            if node is None or node >= self.scn.nodes:
                raise WireError("sender_mismatch", part.refusal.off_key.format(msg.key))
            got = part.decode(msg.payload, node)
        except WireError as err:
            self.bad_messages += 1
            if self.bad_messages <= part.refusal.logged:
                log.warning(part.refusal.note, err)
            return
        k = got.k
        if got.t_meas_pub is not None:
            self.latency[k, node] = got.t_pub - got.t_meas_pub
        for name, value in (("t_meas_pub", got.t_meas_pub), ("t_recv", got.t_recv), ("t_pub", got.t_pub)):
            if value is not None:
                self.times[name][k, node] = value
        for name, flag in self.flags.items():
            flag[k, node] = getattr(got, name)
        self.update_us[k, node] = np.nan if got.update_us is None else got.update_us  # the last message's
        clock = self.clocks[node]
        clock.add(msg.t_recv, got.t_pub, key=k)
        part.keep(got, node, 0.0 - clock.offset)
        self.counters.bank(node, got.counters)

    def node_clock(self, node: int) -> float | None:
        """Node ``node``'s clock less the recorder's as last estimated (s; None before any message)."""
        clock = self.clocks[node]
        return None if clock.estimate is None else round(0.0 - clock.offset, 6)

    def close(self) -> None:
        self.sub.undeclare()
        self.token.undeclare()

    # ------------------------------------------------------------------ steps recorded
    def have(self) -> np.ndarray:
        """(steps, nodes): whether each node's message of each step was recorded."""
        return self.part.have()

    def steps_reached(self) -> int:
        """How many steps the run got through: one past the last step any node published a message for
        (0 before the first)."""
        reached = np.flatnonzero(self.have().any(axis=1))
        return int(reached[-1]) + 1 if reached.size else 0

    def step_errors(self) -> np.ndarray:
        """(steps, nodes) error of every node at every step (NaN: nothing recorded); the part's measure."""
        return self.part.step_errors()

    def nan_free(self) -> bool:
        """Whether everything recorded is finite."""
        return self.part.nan_free()

    def save_estimates(self, path: Path) -> None:
        """Write what the part recorded to ``path`` (``estimates.npz``, ``tracks.npz``) atomically: a full disk
        leaves no truncated file behind."""
        arrays = self.part.arrays(self)

        def write(tmp: Path) -> None:
            np.savez(tmp, **arrays)  # type: ignore[arg-type]  # numpy stub: **kwds vs allow_pickle: bool

        replace_atomically(path, write, suffix=".tmp.npz")

    # ------------------------------------------------------------------ summary
    def summary(self, reports: dict[int, dict] | None = None, steps_run: int | None = None) -> dict:
        """Per-node and network figures (the part's). ``reports``: each node's final ``node-<i>.json`` (its own
        counters at exit). ``steps_run``: an interrupted run's steps (:meth:`steps_reached`): the figures cover
        those, not the steps never reached."""
        return self.part.summary(self, reports or {}, steps_run)

    def steps_covered(self, steps_run: int | None, least: int = 0) -> int:
        """The steps a summary covers: all the run's, or ``steps_run`` of them (at least ``least``)."""
        return self.scn.steps if steps_run is None else max(least, min(steps_run, self.scn.steps))

    @staticmethod
    def node_entry(node: int, recorded: np.ndarray, without: str) -> dict:
        """A node's summary entry as it starts in every kind: the steps it has a message for (``recorded``, one
        bool per step covered), those it has none for (named ``without``) and those as gaps (runs of steps)."""
        return {"node": node, "steps_estimated": int(recorded.sum()), without: int((~recorded).sum()),
                "gaps": runs_of(~recorded)}

    def latency_ms(self, steps: int, node: int | None = None) -> dict:
        """:func:`percentiles` of the latency (ms) over the first ``steps`` steps: of node ``node``, or of all."""
        lat = self.latency[:steps] if node is None else self.latency[:steps, node]
        return percentiles(lat[np.isfinite(lat)] * 1e3)


def refused_counts(nodes: list[dict]) -> dict[str, int]:
    """What the nodes refused, summed per kind: each rejection reason (``early``, ``conflict``, ``undecodable``,
    ...), each flood-guard drop (``dropped <tag>/<reason>``) and the round messages left out in conflicts
    (``conflicts``); the gate's refusals are reported apart (``gated``: honest outliers too)."""
    out: dict[str, int] = {}
    for n in nodes:
        m = n["messages"]
        for name, count in [*m["rejected"].items(), *((f"dropped {k}", v) for k, v in m["dropped"].items()),
                            ("conflicts", m["conflicts"])]:
            if count:
                out[name] = out.get(name, 0) + int(count)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def percentiles(x: np.ndarray) -> dict:
    """The count, median, 90th and 99th percentile and maximum of ``x`` (the count only when empty)."""
    if x.size == 0:
        return {"count": 0}
    p50, p90, p99 = np.percentile(x, [50, 90, 99])
    return {"count": int(x.size), "p50": float(p50), "p90": float(p90), "p99": float(p99), "max": float(x.max())}
