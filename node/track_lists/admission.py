"""What a many-target tracker takes in: its own measurements, its neighbours' track lists and (bearing sensors)
their scans, each decoded, checked against the steps it may carry now and held by step; a bad one raises
:class:`~zentrack.transport.codec.WireError` with its reason (the schedule counts it), a late one is counted.
The checks every tracker shares are in ``node/intake.py``.
"""
from __future__ import annotations

from zentrack.fusion.scan import Scan
from zentrack.fusion.track_to_track import TrackEstimate
from zentrack.node.context import NodeContext
from zentrack.node.intake import StepSlots, own_measurement
from zentrack.transport.codec import Message, WireError
from zentrack.transport.messages import Measurement
from zentrack.transport.scan_messages import ForwardedScan
from zentrack.transport.track_messages import TrackList

#: the kinematic state of a many-target track: position and velocity in 3-D
TRACK_DIM = 6
#: neighbours' lists kept for steps this far ahead of the node (a faster neighbour's)
LISTS_AHEAD = 3


class TrackListAdmission:
    """Node ``ctx.id``'s intake (module docstring); ``scan_from``: whose scans it takes (bearing sensors)."""

    def __init__(self, ctx: NodeContext, neighbours: list[int], scan_from: list[int], measurement_dim: int,
                 counters: dict[str, int]) -> None:
        self.ctx, self.neighbours, self.scan_from = ctx, neighbours, scan_from
        self.measurement_dim, self.counters = measurement_dim, counters
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
        if tracks.k < step:  # its step is fused already
            self.counters["late"] += 1
            return
        if tracks.k > hi:
            raise WireError("future", f"a track list of step {tracks.k}, after {hi}")
        self.lists.put(tracks.k, sender, tracks.estimates())
        self.counters["lists_rx"] += 1

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
