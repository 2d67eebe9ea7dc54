"""A many-target tracker's schedule (node/track_lists/payload.py) as a pure state machine: an injected clock, messages
encoded with the real codec and delivered by hand, three nodes of the mt-crossing ring (node 0 hears 1 and 7;
here 1 and 7 are played by hand)."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.fusion.track_to_track import TrackEstimate, TrackId
from zentrack.node.phases import TRACK_LIST_TRANSITIONS, TrackListPhase
from zentrack.node.schedule import NodeSchedule
from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Measurement, Start
from zentrack.transport.scan_messages import ForwardedScan
from zentrack.transport.track_messages import TrackList

T0, TS = 1000.0, 1.0
KEYS = Keys("t")


def setup_for(timing: str = "realtime", scenario: str = "mt-crossing"):
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    return resolve_setup(p.parse_args(["--scenario", scenario, "--timing", timing, "--steps", "20"]))


class Bench:
    """Node 0's schedule with a settable clock and a record of what it sent."""

    def __init__(self, timing: str = "realtime", scenario: str = "mt-crossing") -> None:
        self.setup = setup_for(timing, scenario)
        self.data = self.setup.multitarget_data
        self.now = T0 - 0.5
        self.sent: list[tuple[str, bytes]] = []
        self.node = NodeSchedule.track_lists(KEYS, self.setup.node_config(0), lambda: self.now,
                                        lambda ch, b: self.sent.append((ch, b)))
        self.node.handle(Message("alive", KEYS.alive("truth"), b"put", self.now))
        for j in (1, 7):
            self.node.handle(Message("alive", KEYS.alive(j), b"put", self.now))

    def at(self, t: float) -> None:
        self.now = t
        self.node.advance()

    def start(self) -> None:
        start = Start(T0, TS, 20, self.setup.mode, tuple(range(8)), 0.5, np.zeros(6))
        self.node.handle(Message("start", KEYS.start, start.encode(), self.now))
        self.node.advance()

    def measure(self, k: int) -> None:
        returns = self.data.scan(k, 0).returns
        payload = Measurement(k, k * TS, 0, returns, None, self.now).encode()
        self.node.handle(Message("meas", KEYS.meas(0), payload, self.now))

    def neighbour_list(self, j: int, k: int, tracks: list[TrackEstimate]) -> None:
        payload = TrackList.of(k, k * TS, j, tracks, self.now).encode()
        self.node.handle(Message("tracks", KEYS.tracks(j), payload, self.now))

    def lists(self) -> list[TrackList]:
        return [TrackList.decode(b, 0, 6) for ch, b in self.sent if ch == "tracks"]

    def neighbour_scan(self, j: int, k: int, origin: int | None = None, returns: np.ndarray | None = None) -> None:
        """Node j's scan of step k as it forwards it (bearing runs): its sensor's returns, pose and noise."""
        scan = self.data.scan(k, j)
        fwd = ForwardedScan(k, k * TS, j, j if origin is None else origin, scan.returns if returns is None else returns,
                            scan.pose, scan.noise_cov, self.now)
        self.node.handle(Message("scan", KEYS.scan(j), fwd.encode(), self.now))


def target_track(data, k: int, target: int, node: int, serial: int = 0, born: int = 0) -> TrackEstimate:
    """A confirmed track of ``target`` at step k as node ``node`` would publish it (on the truth, 5 m std)."""
    ids, states = data.truth_at(k)
    state = states[list(ids).index(target)]
    return TrackEstimate(TrackId(born, node, serial), state, np.diag([25.0] * 3 + [4.0] * 3), "confirmed", k)


def test_the_transition_table_is_a_cycle_after_the_start():
    assert TRACK_LIST_TRANSITIONS[TrackListPhase.IDLE] == {TrackListPhase.AWAIT_MEAS}
    assert TRACK_LIST_TRANSITIONS[TrackListPhase.AWAIT_MEAS] == {TrackListPhase.AWAIT_LISTS, TrackListPhase.AWAIT_SCANS}
    assert TRACK_LIST_TRANSITIONS[TrackListPhase.AWAIT_SCANS] == {TrackListPhase.AWAIT_LISTS}
    assert TRACK_LIST_TRANSITIONS[TrackListPhase.AWAIT_LISTS] == {TrackListPhase.AWAIT_MEAS}


def test_a_step_publishes_its_list_then_fuses_once_every_live_neighbour_list_is_in():
    b = Bench()
    b.start()
    assert b.node.payload.phase is TrackListPhase.AWAIT_MEAS and b.node.payload.step == 0
    b.at(T0 + 0.01)
    b.measure(0)
    b.at(T0 + 0.02)
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS and [lst.k for lst in b.lists()] == [0]
    assert b.lists()[0].coasted is False and b.lists()[0].miss is False
    b.neighbour_list(1, 0, [])
    b.at(T0 + 0.03)
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS  # node 7's list is still out
    b.neighbour_list(7, 0, [])
    b.at(T0 + 0.04)
    assert b.node.payload.phase is TrackListPhase.AWAIT_MEAS and b.node.payload.step == 1
    assert b.node.payload.counters["partial_fusions"] == 0 and b.node.payload.counters["lists_rx"] == 2


def test_without_a_scan_the_node_coasts_at_the_deadline_and_fuses_what_came_at_the_window_end():
    b = Bench()
    b.start()
    b.at(T0 + 0.2)
    assert b.node.payload.phase is TrackListPhase.AWAIT_MEAS  # before the coast deadline: still waiting
    b.at(T0 + 0.5)  # past step 0's deadline less the coast margin
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS and b.lists()[0].coasted is True
    b.neighbour_list(1, 0, [])
    b.at(T0 + 0.9)
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS
    b.at(T0 + 1.0)  # the window ends just before step 1's sample: node 7's list is left out
    assert b.node.payload.step == 1 and b.node.payload.counters["partial_fusions"] == 1 and b.node.payload.counters["coasted"] == 1


def test_a_neighbours_target_is_taken_over_with_its_id_and_confirmed_at_the_next_step():
    b = Bench()
    b.start()
    b.at(T0 + 0.01)
    b.measure(0)
    b.at(T0 + 0.02)
    theirs = target_track(b.data, 0, 2, node=1, serial=5)
    b.neighbour_list(1, 0, [theirs])
    b.neighbour_list(7, 0, [])
    b.at(T0 + 0.03)
    assert b.node.payload.network.takeovers == 1
    b.at(T0 + 1.01)
    b.measure(1)
    b.at(T0 + 1.02)
    confirmed = [e for e in b.lists()[-1].tracks if e.status == "confirmed"]
    assert [e.id for e in confirmed] == [theirs.id]
    truth = dict(zip(*b.data.truth_at(1)))[2]
    assert np.linalg.norm(confirmed[0].mean[:3] - truth[:3]) < 30.0


@pytest.mark.parametrize("forge", ["nan", "duplicate_ids", "wrong_sender", "not_a_neighbour", "too_many", "bytes",
                                   "huge_cov", "tiny_cov"])
def test_a_hostile_list_is_refused_counted_and_changes_nothing(forge):
    b = Bench()
    b.start()
    b.at(T0 + 0.01)
    good = target_track(b.data, 0, 1, node=1)
    if forge == "bytes":
        payload, key = b"\x93\x01\x02", KEYS.tracks(1)
    elif forge == "not_a_neighbour":
        payload, key = TrackList.of(0, 0.0, 3, [good], b.now).encode(), KEYS.tracks(3)
    elif forge == "wrong_sender":  # node 7's key, node 1's list
        payload, key = TrackList.of(0, 0.0, 1, [good], b.now).encode(), KEYS.tracks(7)
    else:
        import msgpack

        doc = msgpack.unpackb(TrackList.of(0, 0.0, 1, [good], b.now).encode(), raw=False)
        if forge == "nan":
            doc["tracks"][0]["x"]["data"] = np.full(6, np.nan).tobytes()
        elif forge == "duplicate_ids":
            doc["tracks"] = doc["tracks"] * 2
        elif forge in ("huge_cov", "tiny_cov"):  # SPD, but the fusion's inverses overflow or lose every digit
            from zentrack.transport.codec import pack_symmetric

            doc["tracks"][0]["P"] = pack_symmetric((1e307 if forge == "huge_cov" else 1e-320) * np.eye(6))
        else:
            doc["tracks"] = doc["tracks"] * 300
        payload, key = msgpack.packb(doc, use_bin_type=True), KEYS.tracks(1)
    b.node.handle(Message("tracks", key, payload, b.now))
    assert sum(b.node.ctx.rejects.counts.values()) == 1
    assert b.node.payload.intake.lists.by_step == {} and b.node.payload.counters["lists_rx"] == 0
    b.neighbour_list(1, 0, [good])  # the honest list still counts
    assert b.node.payload.counters["lists_rx"] == 1


def test_a_second_list_for_one_step_is_refused_and_a_late_one_counted():
    b = Bench()
    b.start()
    b.neighbour_list(1, 0, [])
    b.neighbour_list(1, 0, [])
    assert b.node.ctx.rejects.counts == {"duplicate": 1}
    b.at(T0 + 0.5)
    b.neighbour_list(7, 0, [])
    b.at(T0 + 0.6)
    assert b.node.payload.step == 1
    b.neighbour_list(7, 0, [])  # step 0 is fused: late, not refused
    assert b.node.payload.counters["late"] == 1


def test_a_node_that_joins_a_run_under_way_starts_at_the_current_step_with_no_track():
    b = Bench()
    b.now = T0 + 7.3
    b.start()
    assert b.node.payload.step == 7 and b.node.payload.phase is TrackListPhase.AWAIT_MEAS and b.node.payload.network.tracker.tracks == []


def test_a_node_that_joins_under_way_holds_back_its_first_list_and_publishes_its_neighbours_targets_next():
    """Its first list would hold one scan and claim every other target gone; it fuses the neighbours' lists of
    that step first, and its next list holds their targets (a fresh start publishes at step 0: tests above)."""
    b = Bench()
    b.now = T0 + 7.3
    b.start()
    b.at(T0 + 7.31)
    b.measure(7)
    b.at(T0 + 7.32)
    assert b.lists() == [] and b.node.payload.phase is TrackListPhase.AWAIT_LISTS
    theirs = [target_track(b.data, 7, t, node=1, serial=t) for t in b.data.truth_at(7)[0]]
    b.neighbour_list(1, 7, theirs)
    b.neighbour_list(7, 7, [])
    b.at(T0 + 7.33)
    b.at(T0 + 8.01)
    b.measure(8)
    b.at(T0 + 8.02)
    (first,) = b.lists()
    assert first.k == 8 and {e.id for e in first.tracks if e.status == "confirmed"} == {e.id for e in theirs}


def test_a_stalled_node_goes_on_at_the_current_step_and_counts_the_steps_it_missed():
    b = Bench()
    b.start()
    b.at(T0 + 0.01)
    b.measure(0)
    b.at(T0 + 0.02)
    b.neighbour_list(1, 0, [])
    b.neighbour_list(7, 0, [])
    b.at(T0 + 0.03)
    b.at(T0 + 4.2)  # stalled through steps 1..3
    assert b.node.payload.step == 4 and b.node.payload.counters["misses"] == 3


def test_lockstep_waits_for_its_scan_and_every_participating_neighbour_without_deadlines():
    b = Bench("lockstep")
    b.start()
    b.at(T0 + 100.0)
    assert b.node.payload.phase is TrackListPhase.AWAIT_MEAS and not b.sent  # no deadline: it waits
    b.measure(0)
    b.at(T0 + 100.0)
    b.neighbour_list(1, 0, [])
    b.at(T0 + 200.0)
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS
    b.neighbour_list(7, 0, [])
    b.at(T0 + 200.0)
    assert b.node.payload.step == 1 and b.node.payload.counters["partial_fusions"] == 0


def test_hundreds_of_forged_targets_fill_at_most_the_trackers_room_and_the_next_list_still_goes_out():
    b = Bench()
    b.start()
    b.at(T0 + 0.01)
    b.measure(0)
    b.at(T0 + 0.02)
    far = [TrackEstimate(TrackId(0, 1, s), np.array([1e5 + 1e3 * s, 0, 0, 0, 0, 0.0]), np.eye(6), "confirmed", 0)
           for s in range(256)]
    b.neighbour_list(1, 0, far)
    b.neighbour_list(7, 0, far[:200])
    b.at(T0 + 0.03)
    b.at(T0 + 1.01)
    b.measure(1)
    b.at(T0 + 1.02)
    assert 0 < b.node.payload.network.takeovers <= b.node.payload.network.settings.max_tracks
    assert b.lists()[-1].k == 1 and len(b.lists()[-1].tracks) <= 256  # it published


# ------------------------------------------------------------------ bearing sensors: scans exchanged
def test_a_bearing_node_sends_its_scan_and_steps_on_its_neighbours_scans_then_its_own():
    b = Bench(scenario="mt-bearing")
    assert b.node.publications()["scan"] == (KEYS.scan(0), True) and "scan" not in Bench().node.publications()
    assert (KEYS.scan(1), "scan") in b.node.subscriptions() and (KEYS.scan(7), "scan") in b.node.subscriptions()
    b.start()
    b.measure(0)
    b.at(T0 + 0.01)
    assert b.node.payload.phase is TrackListPhase.AWAIT_SCANS and not b.lists()  # its scan went out, its step waits
    (sent,) = [ForwardedScan.decode(p, 0, 2) for ch, p in b.sent if ch == "scan"]
    np.testing.assert_array_equal(sent.returns, b.data.scan(0, 0).returns)
    b.neighbour_scan(1, 0)
    b.at(T0 + 0.02)
    assert b.node.payload.phase is TrackListPhase.AWAIT_SCANS  # node 7's is still to come, and its deadline is not reached
    b.neighbour_scan(7, 0)
    b.at(T0 + 0.03)
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS and len(b.lists()) == 1
    assert b.node.payload.counters["scans_rx"] == 2 and b.node.payload.counters["partial_scans"] == 0
    # the same step as a tracker stepping on [1, 7, own] in-process: the same tracks
    from zentrack.fusion.multitarget.network import NetworkTracker
    ref = NetworkTracker(0, b.node.payload.network.settings)
    ref.local_step(0, [b.data.scan(0, 1), b.data.scan(0, 7), b.data.scan(0, 0)])
    mine = b.node.payload.network.tracker.tracks
    assert len(mine) == len(ref.tracker.tracks) > 0  # triangulated from the three rays
    np.testing.assert_allclose([t.mean for t in mine], [t.mean for t in ref.tracker.tracks], atol=1e-9)


def test_a_bearing_node_steps_at_the_scan_deadline_without_a_silent_neighbour():
    b = Bench(scenario="mt-bearing")
    b.start()
    b.measure(0)
    b.neighbour_scan(1, 0)
    b.at(T0 + 0.01)
    assert b.node.payload.phase is TrackListPhase.AWAIT_SCANS
    b.at(b.node.ctx.timing.scan_deadline(0, 1) + 1e-3)
    assert b.node.payload.phase is TrackListPhase.AWAIT_LISTS and b.node.payload.counters["partial_scans"] == 1


@pytest.mark.parametrize("forge", ["origin", "shape", "stranger", "duplicate", "nan"])
def test_a_hostile_scan_is_refused_counted_and_never_reaches_the_tracker(forge):
    b = Bench(scenario="mt-bearing")
    b.start()
    b.measure(0)
    if forge == "origin":  # node 1 forwarding node 3's scan as its own
        b.neighbour_scan(1, 0, origin=3)
    elif forge == "shape":  # point returns where bearings are due
        b.neighbour_scan(1, 0, returns=np.zeros((2, 3)))
    elif forge == "nan":
        b.neighbour_scan(1, 0, returns=np.array([[0.1, np.nan]]))
    elif forge == "stranger":  # a node that is no neighbour of node 0
        fwd = ForwardedScan(0, 0.0, 4, 4, b.data.scan(0, 4).returns, b.data.scan(0, 4).pose,
                            b.data.scan(0, 4).noise_cov, b.now)
        b.node.handle(Message("scan", KEYS.scan(4), fwd.encode(), b.now))
    else:
        b.neighbour_scan(1, 0)
        b.neighbour_scan(1, 0, returns=np.zeros((1, 2)))
    assert sum(b.node.ctx.rejects.counts.values()) == 1, b.node.ctx.rejects.counts
    held = b.node.payload.intake.scans.get(0)
    assert (set(held) == {1}) if forge == "duplicate" else not held
