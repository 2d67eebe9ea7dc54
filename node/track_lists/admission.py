"""What a many-target tracker takes in: its own measurements, its neighbours' track lists and (bearing sensors)
their scans, each decoded, checked against the steps it may carry now and held by step; a bad one raises
:class:`~zentrack.transport.codec.WireError` with its reason (the schedule counts it), a late one is counted.
The checks every tracker shares are in ``node/intake.py``.

Trackers on their own clocks (sensors of their own): a neighbour's list of its step k' is valid at ``k' ts`` after
t0 on *its* clock. As a single-target tracker does with round messages (``node/diffusion/neighbour_clocks.py``),
each list's publication time gives a sample of the sender's clock offset ``o``; the list is taken as the sender's
for this tracker's step ``k = k' - n`` (``n`` whole periods of the offset and the settle time:
:meth:`~zentrack.node.diffusion.neighbour_clocks.NeighbourClocks.own_step`) and every entry predicted by the
node's per-track filter from ``k' ts - o`` to ``k ts`` on this clock
(:meth:`~zentrack.fusion.multitarget.network.NetworkTracker.predicted_over`), before the window check and the
fusion see it. When the estimate of ``o`` moves by a period, the list of the sender's next step maps to a step
already held: it takes the held one's place.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

from zentrack.fusion.scan import Scan
from zentrack.fusion.track_to_track import TrackEstimate
from zentrack.node.context import NodeContext
from zentrack.node.diffusion.neighbour_clocks import VALIDITY_SLACK_S, NeighbourClocks
from zentrack.node.intake import StepSlots, own_measurement
from zentrack.transport.codec import Message, WireError
from zentrack.transport.messages import Measurement
from zentrack.transport.scan_messages import ForwardedScan
from zentrack.transport.track_messages import TrackList

#: the kinematic state of a many-target track: position and velocity in 3-D
TRACK_DIM = 6
#: neighbours' lists kept for steps this far ahead of the node (a faster neighbour's)
LISTS_AHEAD = 3

#: ``predict(entries, dt, step)``: a neighbour's entries predicted ``dt`` seconds, as entries of ``step``
PredictList = Callable[[Sequence[TrackEstimate], float, int], list[TrackEstimate]]


class TrackListAdmission:
    """Node ``ctx.id``'s intake (module docstring); ``scan_from``: whose scans it takes (bearing sensors)."""

    def __init__(self, ctx: NodeContext, neighbours: list[int], scan_from: list[int], measurement_dim: int,
                 counters: dict[str, int], clocks: NeighbourClocks | None = None,
                 predict: PredictList | None = None) -> None:
        self.ctx, self.neighbours, self.scan_from = ctx, neighbours, scan_from
        self.measurement_dim, self.counters = measurement_dim, counters
        #: sensors of their own: the neighbours' clocks and the prediction of a list to this clock (module
        #: docstring); None: every node on the run's clock
        self.clocks, self.predict = clocks, predict
        if (clocks is None) != (predict is None):
            raise ValueError("a node on its own clock needs both its neighbours' clocks and the list prediction")
        #: (step, sender) -> the sender's own step of the list held for it (its clock mapped to this one's)
        self.sender_step: dict[tuple[int, int], int] = {}
        self.meas: dict[int, tuple[Measurement, float]] = {}  #: own measurements by step (and receive time)
        self.lists: StepSlots[list[TrackEstimate]] = StepSlots("list")  #: step -> sender -> its tracks
        self.scans: StepSlots[Scan | None] = StepSlots("scan")  #: step -> sender -> its scan (None: it has none)

    def window(self, step: int) -> tuple[int, int]:
        """The steps a measurement or list may carry now: the node's current one (lockstep), or from one behind
        the node's schedule to a few ahead of the run's clock (realtime)."""
        if self.ctx.lockstep:
            return step, step + LISTS_AHEAD
        lo, hi = self.ctx.timing.meas_window(step, self.ctx.clock())
        return lo, hi + 1

    def admit(self, msg: Message, step: int) -> None:
        """A message of the node's current ``step``'s time: its measurement, a list or a scan."""
        if msg.tag == "meas":
            self.measurement(msg, step)
        elif msg.tag == "tracks":
            self.track_list(msg, step)
        elif msg.tag == "scan":
            self.scan(msg, step)

    def measurement(self, msg: Message, step: int) -> None:
        lo, hi = self.window(step)
        meas = own_measurement(msg, self.ctx.id, self.measurement_dim, lo, hi)
        if meas.k in self.meas:
            raise WireError("duplicate", f"a second measurement of step {meas.k}")
        self.meas[meas.k] = (meas, msg.t_recv)
        self.counters["meas_rx"] += 1

    def track_list(self, msg: Message, step: int) -> None:
        sender = self.ctx.keys.node_of(msg.key)
        if sender is None or sender not in self.neighbours:
            raise WireError("sender_mismatch", f"tracks on key {msg.key!r}")
        _, hi = self.window(step)
        tracks = TrackList.decode(msg.payload, sender, TRACK_DIM)
        k = tracks.k if self.clocks is None else self.own_step(tracks, sender, msg.t_recv)
        if k < step:  # its step is fused already
            self.counters["late"] += 1
            return
        if k > hi:
            raise WireError("future", f"a track list of step {k}, after {hi}")
        if self.clocks is None or self.predict is None:
            self.lists.put(k, sender, tracks.estimates())
        else:  # on this clock: predicted to this tracker's time of step k; a list remapped takes the held one's place
            held = self.sender_step.get((k, sender))
            if held is not None and held != tracks.k:
                self.lists.get(k).pop(sender, None)
            ts = self.ctx.timing.ts
            self.lists.put(k, sender, self.predict(tracks.estimates(), self.clocks.lead_to(sender, k * ts, tracks.t), k))
            self.sender_step[(k, sender)] = tracks.k
        self.counters["lists_rx"] += 1

    def own_step(self, tracks: TrackList, sender: int, t_recv: float) -> int:
        """The step of this tracker's schedule a neighbour's list belongs to (module docstring), after its clock
        sample is taken (whatever the step: the mapping needs it); WireError: it says it is valid at another time
        than its step's."""
        assert self.clocks is not None
        self.clocks.observe(sender, t_recv, tracks.t_pub, tracks.k)
        ts = self.ctx.timing.ts
        if abs(tracks.t - tracks.k * ts) > VALIDITY_SLACK_S:
            raise WireError("schema", f"node {sender}'s list of step {tracks.k} says it is valid at {tracks.t:.6g} s, "
                                      f"not at its step's time ({tracks.k * ts:.6g} s)")
        return self.clocks.own_step(sender, tracks.k)

    def scan(self, msg: Message, step: int) -> None:
        """A neighbour's scan of a step (bearing sensors): its own sensor's returns, pose and noise."""
        sender = self.ctx.keys.node_of(msg.key)
        if sender is None or sender not in self.scan_from:
            raise WireError("sender_mismatch", f"scan on key {msg.key!r}")
        _, hi = self.window(step)
        fwd = ForwardedScan.decode(msg.payload, sender, self.measurement_dim)
        fwd.check_origin(sender)
        if fwd.k < step or self.scans.late(fwd.k):
            self.counters["late"] += 1  # its step is taken already
            return
        if fwd.k > hi:
            raise WireError("future", f"a scan of step {fwd.k}, after {hi}")
        self.scans.put(fwd.k, sender, None if fwd.returns is None or fwd.pose is None or fwd.noise_cov is None
                       else Scan(fwd.k, sender, fwd.returns, fwd.pose, fwd.noise_cov))
        self.counters["scans_rx"] += 1

    def used(self, k: int) -> None:
        """Step k is fused: everything held for it and before goes."""
        for store in (self.lists, self.scans):
            store.take(k)
            store.drop_before(k + 1)
        for s in [s for s in self.meas if s <= k]:
            del self.meas[s]
        self.sender_step = {key: v for key, v in self.sender_step.items() if key[0] > k}
