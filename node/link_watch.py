"""When a tracker opens a new Zenoh session, and when it gives up on the truth: :class:`LinkWatch`, pure logic on
the run's clock. ``node/process.py`` owns the session, measures the truth's silence and asks at every watch.

- The truth silent for ``--reconnect-s``: a new session (every link, subscription and token anew: links gossip
  does not re-open by itself come back), tried again with a doubling back-off up to :data:`MAX_BACKOFF_S`; the
  back-off starts over once the truth is heard.
- Silent for ``--truth-timeout``: the tracker stops.

A client of a router re-opens as a peer does. Leaving the re-dial to Zenoh while its router link was down saved
the steps a blocked open skips at a router restart (refused at once, re-dialled every
:data:`~zentrack.transport.zconfig.CONNECT_RETRY` period), but behind a cut link Zenoh's pending dial waits for
its own failure: a cut host's trackers published again 12 steps after the heal instead of 2
(``tests/test_partition.py``). With the 0.1 s re-dial alone a router restart costs 0.5-2.1 steps from the router
listening (``tests/test_router_restart.py``).
"""
from __future__ import annotations

import math
from enum import Enum

#: the longest wait between two new sessions while the truth stays silent, s
MAX_BACKOFF_S = 8.0


class Watch(Enum):
    WAIT = "wait"
    REOPEN = "open a new session"
    STOP = "stop"


class LinkWatch:
    """A tracker's watch (module docstring): ``reconnect_s`` and ``truth_timeout`` are its flags."""

    def __init__(self, reconnect_s: float, truth_timeout: float = math.inf) -> None:
        self.reconnect_s, self.truth_timeout = reconnect_s, truth_timeout
        self.backoff = reconnect_s

    def decide(self, now: float, silence: float | None, last_open: float) -> Watch:
        """What to do at ``now``: the truth silent for ``silence`` s (None: it is there), the last session opened at
        ``last_open``."""
        if silence is not None and silence > self.truth_timeout:
            return Watch.STOP
        if silence is None:  # the truth is heard: the next silence starts the back-off over
            self.backoff = self.reconnect_s
            return Watch.WAIT
        if silence >= self.reconnect_s and now - last_open > self.backoff:
            self.backoff = min(2 * self.backoff, MAX_BACKOFF_S)
            return Watch.REOPEN
        return Watch.WAIT
