"""Echo process for the raw Zenoh round-trip measurement: republishes ``<prefix>/ping`` on ``<prefix>/pong``.

usage: python -m zentrack.bench.pong ENDPOINT PREFIX
"""
from __future__ import annotations

import json
import signal
import sys
import threading

import zenoh


def main() -> int:
    endpoint, prefix = sys.argv[1], sys.argv[2]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
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
