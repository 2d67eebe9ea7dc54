"""A free TCP port on loopback, for a router, a Zenoh endpoint or a web server that a run, a bench or a test
starts (the operating system picks it; free when asked, so bind it soon)."""
from __future__ import annotations

import socket


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
