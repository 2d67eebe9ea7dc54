"""The inbox's flood guard on its own (no Zenoh): a stranger's garbage on a key cannot use up the token bucket
its genuine publisher needs, while a flood of well-formed messages is still limited."""
from __future__ import annotations

import numpy as np

from zentrack.transport.messages import Measurement
from zentrack.transport.zsession import Inbox


def _measurement(k: int) -> bytes:
    return Measurement(k, 0.1 * k, 0, np.array([0.1, 0.2]), None, 1.0).encode()


def test_garbage_takes_no_token_and_the_genuine_measurement_still_gets_in():
    inbox = Inbox(rate_per_key=40.0, burst=1.0)  # the bucket holds 40 messages, refilled at 40 per second
    rng = np.random.default_rng(1)
    admitted = []
    for n in range(2000):  # one second of a 2000 msg/s garbage flood on meas/0, a real measurement every 0.1 s
        now = n / 2000.0
        junk = rng.bytes(64)
        inbox.admit("meas", "zentrack/r/meas/0", len(junk), now, lambda junk=junk: junk)
        if n % 200 == 0:
            real = _measurement(n // 200)
            admitted.append(inbox.admit("meas", "zentrack/r/meas/0", len(real), now, lambda real=real: real))
    assert all(admitted) and len(admitted) == 10
    assert inbox.dropped.get("meas/undecodable", 0) >= 1900  # all but the first half-bucket's worth
    assert "meas/rate" not in inbox.dropped


def test_a_flood_of_well_formed_messages_is_still_limited_by_rate():
    inbox = Inbox(rate_per_key=40.0, burst=1.0)
    real = _measurement(3)
    taken = [inbox.admit("meas", "zentrack/r/meas/0", len(real), 0.0, lambda: real) for _ in range(100)]
    assert sum(taken) == 40 and inbox.dropped == {"meas/rate": 60}


def test_control_messages_and_big_ones_are_judged_as_before():
    inbox = Inbox(rate_per_key=10.0, burst=1.0, max_bytes=100)
    assert not inbox.admit("meas", "k", 101, 0.0, lambda: b"x" * 101)
    assert inbox.dropped == {"meas/size": 1}
    taken = [inbox.admit("start", "ctl", 10, 0.0, lambda: b"garbage!!!") for _ in range(12)]
    assert sum(taken) == 10  # control tags are rate-limited, never framed here (the schedule decodes them)


def test_framing_reads_the_header_only_and_refuses_what_unpack_refuses():
    import msgpack
    import pytest

    from zentrack.transport.codec import WireError, check_framing, unpack

    real = _measurement(5)
    check_framing(real)
    padded = msgpack.packb({**unpack(real), "pad": b"x" * 200_000})
    check_framing(padded)  # a big message frames by its header, as unpack frames it in full
    for bad in (b"", b"\xc1", msgpack.packb([1, 2]), msgpack.packb({"v": 99, "kind": "meas", "k": 1, "t": 0.1}),
                msgpack.packb({"pad": b"x", "v": 2}), msgpack.packb({**unpack(real), "k": -1}),
                msgpack.packb({**unpack(real), "t": float("nan")})):
        with pytest.raises(WireError) as framing:
            check_framing(bad)
        with pytest.raises(WireError) as full:
            unpack(bad)
        assert framing.value.reason == full.value.reason or framing.value.reason == "schema", (bad, framing.value)
