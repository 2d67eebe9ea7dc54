"""The many-target viewer (the core driving ``zentrack.viewer.multi_target``) fed real target sets and track lists, its
recording read back with Rerun's reader: the truth's targets and paths, each node's confirmed and tentative
tracks with their identity labels and trails, GOSPA per node as ``gospa`` scores the same sets, refused
messages counted and skipped; and its layout (``zentrack.viewer.multi_target_layout.multitarget_blueprint``)."""
from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
from test_viewer import column, read_rrd

from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.fusion.multitarget.metrics import gospa
from zentrack.fusion.track_to_track import TrackId
from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys
from zentrack.transport.messages import Stop
from zentrack.transport.track_messages import TargetSet, TrackEntry, TrackList
from zentrack.viewer.core import Viewer
from zentrack.viewer.multi_target import dim, multi_target, track_label
from zentrack.viewer.multi_target_layout import multitarget_blueprint, targets_region

STEPS = 6
KEYS = Keys("r1")


@pytest.fixture(scope="module")
def data():
    cfg = resize(load_scenario_config("mt-crossing", multitarget=True), None, STEPS)
    return cfg.multitarget_data(seed=0)


def truth_msg(data, k: int) -> Message:
    ids, states = data.truth_at(k)
    return Message("truth", KEYS.truth, TargetSet(k, k * data.ts, ids, states, 1.0).encode(), 1.0)


def track(born: int, node: int, serial: int, status: str, pos) -> TrackEntry:
    return TrackEntry(TrackId(born, node, serial), status, np.r_[np.asarray(pos, dtype=float), 0.0, 0.0, 0.0],
                      np.diag([25.0, 25.0, 25.0, 4.0, 4.0, 4.0]))


def tracks_msg(node: int, k: int, tracks, key_node: int | None = None) -> Message:
    payload = TrackList(k, float(k), node, tuple(tracks), 1.0).encode()
    return Message("tracks", KEYS.tracks(node if key_node is None else key_node), payload, 1.0)


def node0_tracks(data, k: int) -> list[TrackEntry]:
    """Node 0 at step k: a confirmed track 1 m east of each of the first three targets, one tentative track."""
    _, states = data.truth_at(k)
    confirmed = [track(0, 0, j, "confirmed", states[j, :3] + [1.0, 0.0, 0.0]) for j in range(3)]
    return [*confirmed, track(0, 0, 9, "tentative", [100.0 + k, 50.0, 200.0])]


def fed_viewer(data, path, recording_id: str) -> tuple[Viewer, rr.RecordingStream]:
    """A viewer recording to ``path``, fed STEPS steps of truth, node 0's lists every step, node 1's only at step 2
    and an empty list of node 1 at step 3; returns it and its recording stream (both still open)."""
    rec = rr.RecordingStream("zentrack-test", recording_id=recording_id)
    rec.set_sinks(rr.FileSink(str(path)))
    viewer = Viewer(None, KEYS, *multi_target(data, rec))
    for k in range(STEPS):
        viewer.handle(truth_msg(data, k))
        viewer.handle(tracks_msg(0, k, node0_tracks(data, k)))
    viewer.handle(tracks_msg(1, 2, [track(0, 1, 0, "confirmed", data.truth_at(2)[1][3, :3])]))
    viewer.handle(tracks_msg(1, 3, []))
    return viewer, rec


@pytest.fixture
def recorded(tmp_path, data):
    """A viewer fed STEPS steps of truth, node 0's lists every step, node 1's only at step 2, an empty list of
    node 1 at step 3, and six messages it must refuse; returns (the viewer, the recording read back)."""
    path = tmp_path / "mt.rrd"
    viewer, rec = fed_viewer(data, path, "mt-test")
    bad = [Message("tracks", KEYS.tracks(1), b"\x93not a list", 1.0),  # undecodable
           tracks_msg(2, 1, node0_tracks(data, 1), key_node=3),  # node 2's list on node 3's key
           tracks_msg(2, STEPS, node0_tracks(data, 1)),  # a step beyond the run
           tracks_msg(9, 1, node0_tracks(data, 1)),  # not one of the run's nodes
           Message("truth", KEYS.truth, TargetSet(STEPS, 0.0, *data.truth_at(0), 1.0).encode(), 1.0),  # beyond the run
           Message("truth", KEYS.truth, TargetSet(1, 1.0, np.array([0, 1]), data.truth_at(1)[1][:1], 1.0).encode(),
                   1.0)]  # two ids, one state
    for msg in bad:
        viewer.handle(msg)
    viewer.handle(Message("stop", KEYS.stop, Stop(STEPS - 1).encode(), 1.0))
    viewer.canvas.buf.flush()
    viewer.close()
    rec.flush()
    rec.disconnect()
    return viewer, read_rrd(path)


def test_the_truth_is_drawn_as_labelled_targets_and_thin_paths(recorded, data):
    viewer, rec = recorded
    assert viewer.canvas.logged["truth"] == STEPS and viewer.stopped
    targets = rec["/world/truth/targets"]
    assert sorted(column(targets, "step")) == list(range(STEPS))
    ids, states = data.truth_at(STEPS - 1)
    steps, positions = column(targets, "step"), column(targets, "Points3D:positions")
    np.testing.assert_allclose(np.asarray(positions[steps.index(STEPS - 1)]), states[:, :3], rtol=1e-6)
    assert all(list(v) == [f"t{i}" for i in ids] for v in column(targets, "Points3D:labels"))
    paths = rec["/world/truth/paths"]
    assert sorted(column(paths, "step")) == list(range(1, STEPS)), "a segment per step after the first"
    strips = column(paths, "LineStrips3D:strips")
    assert all(len(s) == len(ids) for s in strips), "one segment per target and step"
    last = strips[column(paths, "step").index(STEPS - 1)]
    np.testing.assert_allclose(np.asarray(last[0]), [data.truth_at(STEPS - 2)[1][0, :3], states[0, :3]], rtol=1e-6)
    assert "/world/sensors" in rec and list(column(rec["/world/sensors"], "Points3D:labels")[0]) == \
        [f"s{i}" for i in range(data.nodes)]


def test_tracks_carry_their_identity_and_status_apart(recorded, data):
    _, rec = recorded
    confirmed, tentative = rec["/world/nodes/0/confirmed"], rec["/world/nodes/0/tentative"]
    assert sorted(column(confirmed, "step")) == list(range(STEPS))
    assert all(list(v) == ["0/0/0", "0/0/1", "0/0/2"] for v in column(confirmed, "Points3D:labels"))
    assert [list(v) for v in column(tentative, "Points3D:labels")] == [["0/0/9"]] * STEPS
    conf_r = {float(r) for v in column(confirmed, "Points3D:radii") for r in v}
    tent_r = {float(r) for v in column(tentative, "Points3D:radii") for r in v}
    assert max(conf_r) < min(tent_r) < 0, "both in UI points, the tentative ones smaller"
    conf_c = np.asarray(column(confirmed, "Points3D:colors")[0])
    tent_c = np.asarray(column(tentative, "Points3D:colors")[0])
    assert len(set(conf_c.tolist())) == 1 and len(set(tent_c.tolist())) == 1
    assert (tent_c >> 8 & 0xFFFFFF)[0] != (conf_c >> 8 & 0xFFFFFF)[0], "tentative tracks are dimmer"
    # node 1: one track at step 2, then an empty list at step 3 that clears it
    steps1, labels1 = column(rec["/world/nodes/1/confirmed"], "step"), column(rec["/world/nodes/1/confirmed"], "Points3D:labels")
    assert sorted(steps1) == [2, 3]
    assert list(labels1[steps1.index(2)]) == ["0/1/0"] and not labels1[steps1.index(3)]
    assert track_label(TrackId(12, 3, 5)) == "12/3/5" and dim([240, 40, 40]) != [240, 40, 40]


def test_each_track_has_a_trail_from_its_previous_position(recorded, data):
    _, rec = recorded
    trails = rec["/world/nodes/0/trails"]
    steps, strips = column(trails, "step"), column(trails, "LineStrips3D:strips")
    k = STEPS - 1
    row = strips[steps.index(k)]
    assert len(row) == 4, "three confirmed tracks and the tentative one were in the list before"
    before, now = node0_tracks(data, k - 1), node0_tracks(data, k)
    for strip, a, b in zip(row, before, now):
        np.testing.assert_allclose(np.asarray(strip), [a.mean[:3], b.mean[:3]], rtol=1e-6)
    assert not strips[steps.index(0)], "no trail at the first step"
    radii = column(trails, "LineStrips3D:radii")[steps.index(k)]
    assert radii[0] < radii[3] < 0, "the tentative track's trail is thinner"


def test_gospa_per_node_is_gospa_of_the_confirmed_tracks_against_the_truth(recorded, data):
    _, rec = recorded
    for k_col, v_col, part in ((column(rec["/metrics/gospa/0"], "step"), column(rec["/metrics/gospa/0"], "Scalars:scalars"), "total"),
                               *((column(rec[f"/metrics/gospa_{p}/0"], "step"), column(rec[f"/metrics/gospa_{p}/0"], "Scalars:scalars"), p)
                                 for p in ("localisation", "missed", "false"))):
        assert sorted(k_col) == list(range(STEPS))
        for k, v in zip(k_col, v_col):
            confirmed = np.array([e.mean[:3] for e in node0_tracks(data, k) if e.status == "confirmed"])
            expected = getattr(gospa(confirmed, data.truth_at(k)[1][:, :3], 50.0), part)
            assert np.ravel(v)[0] == pytest.approx(expected, rel=1e-6), (part, k)
    # three of four targets held, 1 m off: sqrt(3 * 1 + 50^2 / 2) m
    assert np.ravel(column(rec["/metrics/gospa/0"], "Scalars:scalars")[0])[0] == pytest.approx(np.sqrt(3 + 1250.0))
    counts = [np.ravel(v)[0] for v in column(rec["/metrics/confirmed/0"], "Scalars:scalars")]
    assert counts == [3.0] * STEPS
    targets = [np.ravel(v)[0] for v in column(rec["/metrics/confirmed/targets"], "Scalars:scalars")]
    assert targets == [float(len(data.truth_at(k)[0])) for k in range(STEPS)]


def test_refused_messages_are_counted_and_skipped(recorded):
    viewer, rec = recorded
    assert viewer.canvas.logged["bad"] == 6
    assert viewer.canvas.logged["tracks"] == STEPS + 2 and viewer.canvas.logged["truth"] == STEPS
    assert "/world/nodes/2/confirmed" not in rec and "/world/nodes/3/confirmed" not in rec
    assert "/world/nodes/9/confirmed" not in rec
    assert max(column(rec["/world/nodes/0/confirmed"], "step")) < STEPS
    assert sorted(column(rec["/world/truth/targets"], "step")) == list(range(STEPS)), "one target set per step"


def test_the_layout_frames_the_targets_region(data):
    (cx, cy, cz), half = targets_region(data.truth)
    pos = data.truth[..., :3][data.alive]
    assert np.all(np.abs(pos[:, 0] - cx) <= half + 1e-9) and np.all(np.abs(pos[:, 1] - cy) <= half + 1e-9)
    assert half < 0.5 * np.max(np.linalg.norm(data.sensors[:, :2], axis=1)), "framed on the targets, not the sensors"
    empty = np.full((3, 2, 6), np.nan)
    assert targets_region(empty) == ((0.0, 0.0, 0.0), 100.0)
    assert isinstance(multitarget_blueprint(data.nodes, ((cx, cy, cz), half), 4), rr.blueprint.Blueprint)
