"""What a many-target tracker takes in (mixed into :class:`~zentrack.node.multitarget.MultiTargetSchedule`, which
owns every attribute): its own measurements, its neighbours' track lists and (bearing sensors) their scans, each
decoded, checked against the steps it may carry now and kept by step; a bad one raises :class:`WireError` with its
reason (the schedule counts it), a late one is counted.
"""
from __future__ import annotations

from collections.abc import Callable

from zentrack.fusion.multitarget.network import NetworkTracker
from zentrack.fusion.scan import Scan
from zentrack.fusion.track_to_track import TrackEstimate
from zentrack.node.timing import StepTiming
from zentrack.transport.codec import Message, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Measurement
from zentrack.transport.scan_messages import ForwardedScan
from zentrack.transport.track_messages import TrackList

#: the kinematic state of a many-target track: position and velocity in 3-D
TRACK_DIM = 6
#: neighbours' lists kept for steps this far ahead of the node (a faster neighbour's)
LISTS_AHEAD = 3


class MtAdmission:
    """The message side of :class:`~zentrack.node.multitarget.MultiTargetSchedule`."""

    id: int
    mode: str
    step: int
    neighbours: list[int]
    exchange: bool
    scan_from: list[int]
    measurement_dim: int
    keys: Keys
    clock: Callable[[], float]
    timing: StepTiming
    network: NetworkTracker
    counters: dict[str, int]
    scans: dict[int, tuple[Measurement, float]]
    lists: dict[int, dict[int, list[TrackEstimate]]]
    nb_scans: dict[int, dict[int, Scan | None]]

    def _window(self) -> tuple[int, int]:
        """The steps a measurement or list may carry now: the node's current one (lockstep), or from one behind
        the node's schedule to a few ahead of the run's clock (realtime)."""
        if self.mode == "lockstep":
            return self.step, self.step + LISTS_AHEAD
        lo, hi = self.timing.meas_window(self.step, self.clock())
        return lo, hi + 1

    def _on_meas(self, msg: Message) -> None:
        lo, hi = self._window()
        meas = (msg.decoded if isinstance(msg.decoded, Measurement)
                else Measurement.decode(msg.payload, self.id, self.measurement_dim))
        if not lo <= meas.k <= hi:
            raise WireError("stale", f"measurement of step {meas.k} outside {lo}..{hi}")
        if meas.k in self.scans:
            raise WireError("duplicate", f"a second measurement of step {meas.k}")
        self.scans[meas.k] = (meas, msg.t_recv)
        self.counters["meas_rx"] += 1

    def _on_list(self, msg: Message) -> None:
        sender = self.keys.node_of(msg.key)
        if sender is None or sender not in self.neighbours:
            raise WireError("sender_mismatch", f"tracks on key {msg.key!r}")
        _, hi = self._window()
        tracks = TrackList.decode(msg.payload, sender, TRACK_DIM)
        if tracks.k < self.step:  # its step is fused already
            self.counters["late"] += 1
            return
        if tracks.k > hi:
            raise WireError("stale", f"a track list of step {tracks.k}, after {hi}")
        held = self.lists.setdefault(tracks.k, {})
        if sender in held:
            raise WireError("duplicate", f"a second list of node {sender} for step {tracks.k}")
        held[sender] = tracks.estimates()
        self.counters["lists_rx"] += 1

    def _on_scan(self, msg: Message) -> None:
        """A neighbour's scan of a step (bearing sensors): its own sensor's returns, pose and noise."""
        sender = self.keys.node_of(msg.key)
        if not self.exchange or sender is None or sender not in self.scan_from:
            raise WireError("sender_mismatch", f"scan on key {msg.key!r}")
        _, hi = self._window()
        fwd = ForwardedScan.decode(msg.payload, sender, self.measurement_dim)
        if fwd.origin != sender:
            raise WireError("sender_mismatch", f"scan from node {sender} claims origin {fwd.origin}")
        taken = self.network.step
        if fwd.k < self.step or (taken is not None and fwd.k <= taken):
            self.counters["late"] += 1  # its step is taken already
            return
        if fwd.k > hi:
            raise WireError("stale", f"a scan of step {fwd.k}, after {hi}")
        held = self.nb_scans.setdefault(fwd.k, {})
        if sender in held:
            raise WireError("duplicate", f"a second scan of node {sender} for step {fwd.k}")
        held[sender] = (None if fwd.returns is None or fwd.pose is None or fwd.noise_cov is None
                        else Scan(fwd.k, sender, fwd.returns, fwd.pose, fwd.noise_cov))
        self.counters["scans_rx"] += 1
