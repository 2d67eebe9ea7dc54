"""When a tracker opens a new Zenoh session and when it stops (``node/link_watch.py``), on a hand-driven clock."""
from __future__ import annotations

from zentrack.node.link_watch import LinkWatch, Watch

RECONNECT_S, TRUTH_TIMEOUT = 2.0, 30.0


def test_a_peer_re_opens_after_the_truths_silence_with_a_doubling_back_off_and_stops_at_the_timeout():
    w = LinkWatch(RECONNECT_S, TRUTH_TIMEOUT)
    w.opened(0.0, client=False)
    assert w.decide(1.0, None, last_open=0.0) is Watch.WAIT
    assert w.decide(3.0, 1.9, last_open=0.0) is Watch.WAIT  # silent less than --reconnect-s
    assert w.decide(3.1, 2.1, last_open=0.0) is Watch.REOPEN
    w.opened(3.1, client=False)
    assert w.decide(5.2, 4.2, last_open=3.1) is Watch.WAIT  # the back-off doubled to 4 s
    assert w.decide(7.2, 6.2, last_open=3.1) is Watch.REOPEN
    assert w.decide(8.0, None, last_open=7.2) is Watch.WAIT and w.backoff == RECONNECT_S  # back: reset
    assert w.decide(40.0, 30.5, last_open=7.2) is Watch.STOP


def test_a_client_whose_router_is_down_waits_for_zenohs_re_dial_and_counts_silence_from_the_links_return():
    """A router restart: the truth silent from its death (t = 0) on; the client leaves the re-dial to Zenoh (a new
    session's open held the tracker's loop: 2-5 steps skipped at every router restart) and, once its link is
    back at t = 3, gives the truth --reconnect-s from then before it opens a new session."""
    w = LinkWatch(RECONNECT_S, TRUTH_TIMEOUT)
    w.opened(-10.0, client=True)
    for t in (0.5, 2.5, 2.9):
        assert w.decide(t, t, last_open=-10.0, router_up=False) is Watch.WAIT
    assert w.decide(3.0, 3.0, last_open=-10.0, router_up=True) is Watch.WAIT
    assert abs(w.since_link(4.9, 4.9) - 1.9) < 1e-9
    assert w.decide(4.9, 4.9, last_open=-10.0) is Watch.WAIT
    assert w.decide(5.1, 5.1, last_open=-10.0) is Watch.REOPEN  # the truth still silent 2 s after the link's return
    assert w.decide(31.0, 31.0, last_open=5.1, router_up=False) is Watch.STOP  # no router for good: still stops
