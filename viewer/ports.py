"""The viewer's ports: their defaults, the flag type and the check that nothing holds them (standard library only:
the viewer's options, the viewer process and the orchestrator use it)."""
from __future__ import annotations

import argparse
import errno
import socket
from collections.abc import Iterable, Mapping

WEB_PORT, GRPC_PORT = 9090, 9876
PORT_FLAGS = {WEB_PORT: "--web-port", GRPC_PORT: "--grpc-port"}


def port_number(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port from 1 to 65535, got {value}")
    return value


def port_in_use(port: int, host: str = "127.0.0.1") -> bool:
    """Whether a listening socket holds ``host:port`` (or the wildcard address on that port). Uses
    SO_REUSEADDR like the Rerun server does, so connections lingering in TIME_WAIT do not count."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return True
            raise
    return False


def check_ports_free(ports: Iterable[int] | Mapping[int, str | None] = (WEB_PORT, GRPC_PORT), host: str = "127.0.0.1") -> None:
    """Raise ValueError naming the first of ``ports`` that a listening socket already holds on ``host``.

    ``ports`` is a list of port numbers (the viewer's defaults are named after their flags, ``--web-port`` and
    ``--grpc-port``) or a map from port to the flag that chose it. ``zentrack viewer --serve`` and
    ``zentrack run --viewer-serve`` call it before starting anything, so a stale Rerun server is never
    streamed into silently."""
    named = dict(ports) if isinstance(ports, Mapping) else {p: PORT_FLAGS.get(p) for p in ports}
    for port, flag in named.items():
        label = f"port {port} ({flag})" if flag else f"port {port}"
        try:
            busy = port_in_use(port, host)
        except OSError as exc:
            raise ValueError(f"{label} on {host}: cannot be bound ({exc.strerror or exc})") from None
        if busy:
            raise ValueError(f"{label} on {host} is already in use (a Rerun server left running? see "
                             f"`ss -ltnp 'sport = :{port}'`); stop it" + (f" or choose another {flag}" if flag else ""))
