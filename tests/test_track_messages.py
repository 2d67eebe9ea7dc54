"""The track-list wire message (``zentrack.transport.track_messages``): exact round trips, its key, and hostile
lists (too many tracks, duplicate ids, NaN, non-SPD covariances, a wrong sender or version, every field
replaced by every hostile value) refused with a ``WireError`` whose reason and text name what is wrong."""
from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from test_messages_fuzz import HOSTILE, paths, replaced

from zentrack.fusion.track_to_track import TrackEstimate, TrackId
from zentrack.transport import codec
from zentrack.transport.codec import MAX_COORDINATE, REASONS, WireError
from zentrack.transport.keys import Keys
from zentrack.transport.messages import RoundMessage
from zentrack.transport.track_messages import MAX_TRACKS, TrackEntry, TrackList

N = 4
SENDER = 3


def spd(n: int, scale: float = 1.0) -> np.ndarray:
    a = np.arange(n * n, dtype=float).reshape(n, n) / (n * n)
    return scale * (a @ a.T + np.eye(n))


def entry(serial: int, born: int = 2, node: int = SENDER, status: str = "confirmed") -> TrackEntry:
    return TrackEntry(TrackId(born, node, serial), status, np.arange(N, dtype=float) * 10.0 + serial,
                      spd(N, 1.0 + serial))


LIST = TrackList(7, 0.7, SENDER, (entry(0), entry(1, born=5, node=8, status="tentative"), entry(2)), 1700000000.25)


def decode(payload: bytes, key_node: int = SENDER, n: int = N, lo: int | None = 0, hi: int | None = 10) -> TrackList:
    return TrackList.decode(payload, key_node, n, lo, hi)


def as_map(tl: TrackList = LIST) -> dict:
    return msgpack.unpackb(tl.encode(), raw=False)


def forged(msg: dict) -> bytes:
    return msgpack.packb(msg, use_bin_type=True)


def refused(payload: bytes, **kwargs) -> WireError:
    with pytest.raises(WireError) as info:
        decode(payload, **kwargs)
    assert info.value.reason in REASONS
    return info.value


# ------------------------------------------------------------------------------------------------ round trips

def test_a_list_round_trips_exactly():
    got = decode(LIST.encode())
    assert (got.k, got.t, got.sender, got.t_pub) == (LIST.k, LIST.t, LIST.sender, LIST.t_pub)
    assert len(got.tracks) == len(LIST.tracks)
    for a, b in zip(got.tracks, LIST.tracks):
        assert (a.id, a.status) == (b.id, b.status)
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.cov, b.cov)
    assert decode(LIST.encode()).encode() == LIST.encode()


def test_an_empty_list_and_a_full_one_round_trip():
    empty = TrackList(0, 0.0, SENDER, (), 1.0)
    assert decode(empty.encode()).tracks == ()
    full = TrackList(9, 0.9, SENDER, tuple(entry(i) for i in range(MAX_TRACKS)), 1.0)
    assert [e.id for e in decode(full.encode()).tracks] == [e.id for e in full.tracks]


def test_a_list_carries_the_trackers_estimates_and_gives_them_back():
    estimates = [TrackEstimate(TrackId(1, SENDER, i), np.full(N, float(i)), spd(N), "confirmed", 7) for i in range(3)]
    back = decode(TrackList.of(7, 0.7, SENDER, estimates, 2.0).encode()).estimates()
    assert [(e.id, e.status, e.step) for e in back] == [(e.id, e.status, 7) for e in estimates]
    for a, b in zip(back, estimates):
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.cov, b.cov)


def test_a_tracks_existence_travels_and_a_certain_one_costs_no_byte():
    """A PMBM node's existence goes as ``r`` and comes back exactly; an M-of-N track's (1) is not sent."""
    estimates = [TrackEstimate(TrackId(1, SENDER, i), np.full(N, float(i)), spd(N), "confirmed", 7, existence=e)
                 for i, e in enumerate((1.0, 0.75, 0.5000001))]
    sent = TrackList.of(7, 0.7, SENDER, estimates, 2.0)
    assert ["r" in track for track in as_map(sent)["tracks"]] == [False, True, True]
    assert [e.existence for e in decode(sent.encode()).estimates()] == [1.0, 0.75, 0.5000001]
    certain = TrackList.of(7, 0.7, SENDER, estimates[:1], 2.0).encode()
    assert len(certain) == len(TrackList.of(7, 0.7, SENDER, [TrackEstimate(estimates[0].id, estimates[0].mean,
                                                                       estimates[0].cov, "confirmed", 7)], 2.0).encode())


def test_the_tracks_key_belongs_to_the_run_and_names_its_node():
    keys = Keys("r1")
    assert keys.tracks(5) == "zentrack/r1/tracks/5"
    assert keys.node_of(keys.tracks(5)) == 5 and keys.kind_of(keys.tracks(5)) == "tracks"
    assert "tracks" in codec.KINDS


# ------------------------------------------------------------------------------------------------ hostile lists

def test_too_many_tracks_are_refused_and_never_sent():
    msg = as_map()
    msg["tracks"] = msg["tracks"] + [dict(msg["tracks"][0], id=[2, SENDER, 100 + i]) for i in range(MAX_TRACKS)]
    err = refused(forged(msg))
    assert err.reason == "schema" and f"> {MAX_TRACKS}" in str(err)
    with pytest.raises(ValueError, match="MAX_TRACKS"):
        TrackList(7, 0.7, SENDER, tuple(entry(i) for i in range(MAX_TRACKS + 1)), 1.0).encode()


def test_duplicate_ids_are_refused_and_never_sent():
    msg = as_map()
    msg["tracks"][2]["id"] = list(msg["tracks"][0]["id"])
    err = refused(forged(msg))
    assert err.reason == "schema" and "twice" in str(err)
    with pytest.raises(ValueError, match="duplicate"):
        TrackList(7, 0.7, SENDER, (entry(0), entry(0)), 1.0).encode()


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_mean_or_covariance_is_refused_naming_the_track(value):
    for field_name in ("x", "P"):
        msg = as_map()
        data = np.frombuffer(msg["tracks"][1]["P" if field_name == "P" else "x"]["data"], dtype="<f8").copy()
        data[1] = value
        msg["tracks"][1][field_name]["data"] = data.tobytes()
        err = refused(forged(msg))
        assert err.reason == "nonfinite" and f"track 5/8/1 {field_name}" in str(err)


def test_the_first_of_several_bad_tracks_is_named_and_each_value_is_the_one_sent():
    """A list's means and covariances are checked all at once (``codec.unpack_vectors``, ``unpack_symmetrics``):
    with tracks 1 and 2 both bad, track 1 is named, under the reason of its first bad field; a good list decodes
    to the very values sent, each track's own arrays, writable."""
    for field_name, value, reason in (("x", math.nan, "nonfinite"), ("x", 2 * MAX_COORDINATE, "range"),
                                      ("P", math.inf, "nonfinite")):
        msg = as_map()
        for t in (2, 1):
            data = np.frombuffer(msg["tracks"][t][field_name]["data"], dtype="<f8").copy()
            data[-1] = value
            msg["tracks"][t][field_name]["data"] = data.tobytes()
        err = refused(forged(msg))
        assert err.reason == reason and f"track 5/8/1 {field_name}" in str(err), (field_name, str(err))
    got = decode(LIST.encode())
    for sent, back in zip(LIST.tracks, got.tracks):
        assert np.array_equal(sent.mean, back.mean) and np.array_equal(sent.cov, back.cov)
        assert back.mean.flags.writeable and back.cov.flags.writeable
    got.tracks[0].mean[0] = -1.0  # (one track's arrays are its own)
    assert got.tracks[1].mean[0] == LIST.tracks[1].mean[0]


def test_a_covariance_that_is_not_positive_definite_or_not_symmetric_is_refused():
    msg = as_map()
    msg["tracks"][0]["P"] = codec.pack_symmetric(np.diag([1.0, 1.0, -1.0, 1.0]))
    err = refused(forged(msg))
    assert err.reason == "not_pd" and "track 2/3/0 P" in str(err)
    full = spd(N)
    full[0, 1] += 0.5
    msg["tracks"][0]["P"] = codec.pack_array(full)  # a full matrix is accepted only if symmetric
    assert refused(forged(msg)).reason == "asymmetric"
    msg["tracks"][0]["P"] = codec.pack_array(spd(N))
    assert len(decode(forged(msg)).tracks) == 3


def test_a_wrong_sender_version_kind_or_step_is_refused():
    assert refused(LIST.encode(), key_node=SENDER + 1).reason == "sender_mismatch"
    msg = as_map()
    msg["v"] = 1
    assert refused(forged(msg)).reason == "version"
    prior = RoundMessage(7, 0.7, SENDER, 1, {"state": (spd(N), np.zeros(N))}, 1.0).encode()
    assert refused(prior).reason == "kind"
    assert refused(LIST.encode(), lo=8).reason == "stale"
    assert refused(LIST.encode(), hi=6).reason == "future"


@pytest.mark.parametrize(("path", "value", "reason", "named"), [
    (("tracks", 0, "id"), [2, SENDER], "schema", "not [born, node, serial]"),
    (("tracks", 0, "id"), [8, SENDER, 0], "schema", "after the list's step 7"),
    (("tracks", 0, "id"), [2, 1000, 0], "schema", "track id node"),
    (("tracks", 0, "id"), [2, SENDER, -1], "schema", "track id serial"),
    (("tracks", 0, "id"), [2, True, 0], "schema", "track id node"),
    (("tracks", 0, "status"), "deleted", "schema", "status 'deleted'"),
    (("tracks", 0, "x"), codec.pack_array(np.zeros(N + 1)), "shape", "track 2/3/0 x"),
    (("tracks", 0, "x"), codec.pack_array(np.full(N, 2 * MAX_COORDINATE)), "range", "track 2/3/0 x"),
    (("tracks", 0, "P"), codec.pack_symmetric(spd(N + 1)), "shape", "track 2/3/0 P"),
    (("tracks", 0), [1, 2], "schema", "a map per track"),
    (("tracks", 0, "r"), 0.0, "schema", "track 2/3/0: existence r"),
    (("tracks", 0, "r"), 1.5, "schema", "track 2/3/0: existence r"),
    (("tracks", 0, "r"), float("nan"), "schema", "track 2/3/0: existence r"),
    (("tracks", 0, "r"), "0.5", "schema", "track 2/3/0: existence r"),
    (("tracks",), {"a": 1}, "schema", "'tracks'"),
])
def test_a_bad_field_is_refused_with_a_reason_naming_it(path, value, reason, named):
    err = refused(replaced(as_map(), path, value))
    assert err.reason == reason and named in str(err)


def test_the_wrong_state_dimension_is_refused():
    assert refused(LIST.encode(), n=N + 2).reason == "shape"


def well_typed(tl: TrackList) -> bool:
    return (type(tl.k) is int and type(tl.sender) is int and math.isfinite(tl.t) and math.isfinite(tl.t_pub)
            and type(tl.tracks) is tuple and len(tl.tracks) <= MAX_TRACKS
            and len({e.id for e in tl.tracks}) == len(tl.tracks)
            and all(type(e.id) is TrackId and all(type(v) is int and v >= 0 for v in (e.id.born, e.id.node,
                                                                                      e.id.serial))
                    and e.id.born <= tl.k and e.status in ("tentative", "confirmed")
                    and e.mean.shape == (N,) and np.isfinite(e.mean).all()
                    and e.cov.shape == (N, N) and np.array_equal(e.cov, e.cov.T)
                    and np.linalg.eigvalsh(e.cov)[0] > 0 for e in tl.tracks))


def test_every_field_replaced_by_every_hostile_value_gives_a_wire_error_or_a_well_typed_list():
    msg = as_map()
    outcomes = {"ok": 0, "refused": 0}
    for path in paths(msg):
        for payload in [replaced(msg, path, v) for v in HOSTILE] + [replaced(msg, path, None, remove=True)]:
            try:
                got = decode(payload)
            except WireError as err:
                assert err.reason in REASONS
                outcomes["refused"] += 1
                continue
            assert well_typed(got), path
            outcomes["ok"] += 1
    assert outcomes["refused"] > 0.8 * (outcomes["ok"] + outcomes["refused"])
