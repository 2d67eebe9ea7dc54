"""Command-line options of ``zentrack viewer`` (kept apart so the CLI does not import Rerun to build its parser)."""
from __future__ import annotations

import argparse

from zentrack.common.argtypes import float_in, int_in
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.transport.zsession import add_zenoh_arguments

from .ports import GRPC_PORT, WEB_PORT, port_number


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
                   help="--serve: keep serving this many seconds after ctl/stop (default 0)")
    p.add_argument("--nice", type=int_in(0, 19, "nice"), default=10, help="lower the viewer's CPU priority by this much so trackers "
                   "keep their deadlines on a loaded machine (default 10; 0 to keep it)")
    add_zenoh_arguments(p)


def run_viewer(args: argparse.Namespace) -> int:
    """``zentrack viewer``: imports the viewer process (and Rerun) only when a viewer runs."""
    from zentrack.viewer import process as viewer_process

    return viewer_process.run(args)
