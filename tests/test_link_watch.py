"""When a tracker opens a new Zenoh session and when it stops (``node/link_watch.py``), on a hand-driven clock."""
from __future__ import annotations

from zentrack.node.link_watch import LinkWatch, Watch

RECONNECT_S, TRUTH_TIMEOUT = 2.0, 30.0


def test_a_tracker_re_opens_after_the_truths_silence_with_a_doubling_back_off_and_stops_at_the_timeout():
    w = LinkWatch(RECONNECT_S, TRUTH_TIMEOUT)
    assert w.decide(1.0, None, last_open=0.0) is Watch.WAIT
    assert w.decide(3.0, 1.9, last_open=0.0) is Watch.WAIT  # silent less than --reconnect-s
    assert w.decide(3.1, 2.1, last_open=0.0) is Watch.REOPEN
    assert w.decide(5.2, 4.2, last_open=3.1) is Watch.WAIT  # the back-off doubled to 4 s
    assert w.decide(7.2, 6.2, last_open=3.1) is Watch.REOPEN
    assert w.decide(8.0, None, last_open=7.2) is Watch.WAIT and w.backoff == RECONNECT_S  # back: reset
    assert w.decide(40.0, 30.5, last_open=7.2) is Watch.STOP


def test_a_long_silence_opens_sessions_ever_further_apart():
    """Host 1 cut off from the truth's host for 20 s (tests/test_partition.py): new sessions 2, 4, 8 and 8 s apart
    (and the watch's tick), not one every --reconnect-s."""
    w = LinkWatch(RECONNECT_S, TRUTH_TIMEOUT)
    opens, t = [0.0], 0.0
    while t < 24.0:
        t = round(t + 0.1, 1)
        if w.decide(t, t, last_open=opens[-1]) is Watch.REOPEN:
            opens.append(t)
    assert [round(b - a, 1) for a, b in zip(opens, opens[1:])] == [2.1, 4.1, 8.1, 8.1]
    assert w.decide(24.1, None, last_open=opens[-1]) is Watch.WAIT and w.backoff == RECONNECT_S
