"""Echo process for the raw Zenoh round-trip measurement: republishes ``<prefix>/ping`` on ``<prefix>/pong``.

usage: python -m zentrack.bench.pong ENDPOINT PREFIX [peer|client]

``peer`` (default): a peer that connects to ENDPOINT (the ping side listens); ``client``: a client of the
router at ENDPOINT.
"""
from __future__ import annotations

import sys

import zenoh

from zentrack.common.procs import StopFlag
from zentrack.transport.zsession import loopback_config


def main() -> int:
    endpoint, prefix = sys.argv[1], sys.argv[2]
    mode = sys.argv[3] if len(sys.argv) > 3 else "peer"
    conf = loopback_config("peer", listen=["tcp/127.0.0.1:0"], connect=[endpoint]) if mode == "peer" else \
        loopback_config("client", connect=[endpoint])
    done = StopFlag()  # SIGTERM (or Ctrl-C) ends it
    with zenoh.open(conf) as session:
        pub = session.declare_publisher(f"{prefix}/pong", express=True, congestion_control=zenoh.CongestionControl.BLOCK)
        sub = session.declare_subscriber(f"{prefix}/ping", lambda s: pub.put(s.payload.to_bytes()))
        token = session.liveliness().declare_token(f"{prefix}/alive/pong")
        done.wait()
        token.undeclare()
        sub.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
