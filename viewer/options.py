"""Command-line options of ``zentrack viewer`` (kept apart so the CLI does not import Rerun to build its parser)."""
from __future__ import annotations

import argparse
import errno
import socket
from collections.abc import Iterable, Mapping

from zentrack.common.argtypes import float_in, int_in
from zentrack.config.run_setup import add_scenario_arguments
from zentrack.transport.zsession import add_zenoh_arguments

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


def check_ports_free(ports: Iterable[int] | Mapping[int, str] = (WEB_PORT, GRPC_PORT), host: str = "127.0.0.1") -> None:
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
                             f"`ss -ltnp 'sport = :{port}'`); stop it or choose another {flag or 'port'}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_arguments(p)
    sinks = p.add_argument_group("sinks (at least one)")
    sinks.add_argument("--save", metavar="PATH.rrd", help="write the recording to this file")
    sinks.add_argument("--serve", action="store_true", help="serve a web viewer (and gRPC) on --bind")
    sinks.add_argument("--spawn", action="store_true", help="open the native Rerun viewer (needs a display)")
    p.add_argument("--bind", default="127.0.0.1", help="address --serve binds to (default 127.0.0.1)")
    p.add_argument("--web-port", type=port_number, default=WEB_PORT, help=f"web viewer port (default {WEB_PORT})")
    p.add_argument("--grpc-port", type=port_number, default=GRPC_PORT, help=f"gRPC port of --serve (default {GRPC_PORT})")
    p.add_argument("--flush-s", type=float_in(0.01, 60.0, "flush_s"), default=1.0,
                   help="seconds between flushes to the sinks, 0.01 to 60 (default 1)")
    p.add_argument("--linger", type=float_in(0.0, 86400.0, "linger"), default=0.0,
                   help="--serve: keep serving this many seconds after ctl/stop")
    p.add_argument("--nice", type=int_in(0, 19, "nice"), default=10, help="lower the viewer's CPU priority by this much so trackers "
                   "keep their deadlines on a loaded machine (default 10; 0 to keep it)")
    add_zenoh_arguments(p)


def run_viewer(args: argparse.Namespace) -> int:
    """``zentrack viewer``: imports the viewer process (and Rerun) only when a viewer runs."""
    from zentrack.viewer import process as viewer_process

    return viewer_process.run(args)
