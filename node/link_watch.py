"""When a tracker opens a new Zenoh session, and when it gives up on the truth: :class:`LinkWatch`, pure logic on
the run's clock. ``node/process.py`` owns the session, measures the truth's silence and asks at every watch.

- The truth silent for ``--reconnect-s``: a new session (every link, subscription and token anew: links gossip
  does not re-open by itself come back), tried again with a doubling back-off up to :data:`MAX_BACKOFF_S`.
- Silent for ``--truth-timeout``: the tracker stops.
- A client whose router link is down (a router restart, a cut link) waits: Zenoh re-dials its router by itself
  every :data:`~zentrack.transport.zconfig.CONNECT_RETRY` period and re-declares the session's subscriptions
  and token on the new link, and a new session would only start that over while its open held the tracker's
  loop (a blocked open cost the tracker 2-5 steps skipped at every router restart, ``zentrack bench
  router-restart``). Once the link is back, the silence counts from then: the truth's own client needs its
  re-dial too.
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
        self.client = False  # a client of a router (``--zenoh-mode client``, secure mode): Zenoh re-dials its router
        #: a client's: when its router link was last seen back (None: down, or a peer)
        self.router_back: float | None = None

    def opened(self, now: float, client: bool) -> None:
        """A new session opened at ``now``; ``client``: a client of a router (a client's silence counts from now)."""
        self.client = client
        self.router_back = now if client else None

    def since_link(self, now: float, gone: float) -> float:
        """How much of the truth's silence ``gone`` a new session could help with: a client's counts from the
        moment its router link came back, a peer's all of it."""
        return gone if self.router_back is None else min(gone, now - self.router_back)

    def decide(self, now: float, silence: float | None, last_open: float, router_up: bool = True) -> Watch:
        """What to do at ``now``: the truth silent for ``silence`` s (None: it is there), the last session opened at
        ``last_open``, and, for a client, whether its router link is up."""
        if silence is not None and silence > self.truth_timeout:
            return Watch.STOP
        if self.client:
            if not router_up:
                self.router_back = None
                return Watch.WAIT
            if self.router_back is None:
                self.router_back = now
        if silence is None or self.since_link(now, silence) < self.reconnect_s:
            self.backoff = self.reconnect_s
            return Watch.WAIT
        if now - last_open > self.backoff:
            self.backoff = min(2 * self.backoff, MAX_BACKOFF_S)
            return Watch.REOPEN
        return Watch.WAIT
