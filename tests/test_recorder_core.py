"""The recorder core with each payload part, fed by hand (no Zenoh): the part's channel is subscribed, a message
on a key of no node or that does not decode is refused and counted (the first few logged in the part's words),
the step's times and flags are the core's, and a node's counters are banked over its restarts whichever kind of
message carried them."""
from __future__ import annotations

import argparse
import logging

import numpy as np
import pytest

from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.cluster.recording.track_lists import TrackLists
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.fusion.track_to_track import TrackEstimate, TrackId
from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys
from zentrack.transport.messages import EstimateMessage
from zentrack.transport.track_messages import TrackList

T0 = 1000.0


class _FakeSession:
    """What the recorder declares on a Zenoh session, without Zenoh; remembers the keys."""

    def __init__(self) -> None:
        self.keys: list[str] = []

    def declare_subscriber(self, key, handler):
        self.keys.append(key)
        return self

    def liveliness(self):
        return self

    def declare_token(self, key):
        self.keys.append(key)
        return self

    def undeclare(self):
        pass


@pytest.fixture(scope="module")
def mt_data():
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    return resolve_setup(p.parse_args(["--scenario", "mt-crossing", "--steps", "20"])).multitarget_data


def _estimate(keys: Keys, scn, i: int, k: int, **about) -> Message:
    x = scn.truth[0][k] + 1.0
    msg = EstimateMessage(k, 0.1 * k, i, x, np.eye(x.size), T0 + 0.1 * k + 0.02, **about)
    return Message("est", keys.est(i), msg.encode(), T0)


def _track_list(keys: Keys, data, i: int, k: int, **about) -> Message:
    ids, states = data.truth_at(k)
    tracks = [TrackEstimate(TrackId(0, i, int(t)), states[j], np.eye(6), "confirmed", k) for j, t in enumerate(ids)]
    return Message("tracks", keys.tracks(i), TrackList.of(k, 0.1 * k, i, tracks, T0 + 0.1 * k + 0.02, **about).encode(), T0)


def test_both_parts_share_the_core_session_refusals_times_and_counters(exp2_small, mt_data, caplog):
    keys = Keys("t")
    cases = [(Estimates(exp2_small), _estimate, exp2_small, "recorder: dropped an estimate"),
             (TrackLists(mt_data), _track_list, mt_data, "recorder: refused a track list")]
    for part, message, data, note in cases:
        session = _FakeSession()
        rec = Recorder(session, keys, part)  # type: ignore[arg-type]
        assert session.keys == [keys.of(part.channel, "*"), keys.alive("recorder")]
        assert rec.steps_reached() == 0
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="zentrack.recorder"):
            for bad in (Message(part.channel, keys.of(part.channel, 99), b"x", T0),
                        Message(part.channel, keys.of(part.channel, 0), b"\xc1 not msgpack", T0),
                        Message(part.channel, keys.of(part.channel, 0), b"\xc1", T0),
                        Message(part.channel, keys.of(part.channel, 0), b"\xc1", T0)):
                rec._record(bad)
        assert rec.bad_messages == 4
        assert [r.getMessage().split(" (")[0] for r in caplog.records] == [note] * part.refusal.logged
        rec._record(message(keys, data, 1, 3, t_meas_pub=T0 + 0.3, update_us=80.0, coasted=True,
                            counters={"steps": 4, "incarnation": 1}))
        assert rec.steps_reached() == 4 and rec.have()[3, 1] and rec.have().sum() == 1
        assert rec.latency[3, 1] == pytest.approx(0.02) and rec.update_us[3, 1] == 80.0
        assert rec.flags["coasted"][3, 1] and not rec.flags["miss"][3, 1]
        assert rec.times["t_pub"][3, 1] == pytest.approx(T0 + 0.32)
        # a new incarnation: the first one's counts are banked once
        rec._record(message(keys, data, 1, 6, counters={"steps": 1, "incarnation": 2}))
        rec._record(message(keys, data, 1, 7))
        assert rec.counters.restarts[1] == 1 and rec.counters.total[1] == {"steps": 4}
        assert rec.counters.last[1] == {"steps": 1, "incarnation": 2} and rec.counters.received_since[1] == 1
        summary = rec.summary()
        node = summary["nodes"][1]
        assert node["steps_estimated"] == 3 and node["gaps"][0] == [0, 2]
        assert node["latency_ms"]["count"] == 1 and node["latency_ms"]["p50"] == pytest.approx(20.0)
        rec.close()
