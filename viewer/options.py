"""Command-line options of ``zentrack viewer`` (kept apart so the CLI does not import Rerun to build its parser)."""
from __future__ import annotations

import argparse

from zentrack.runcfg import add_scenario_arguments
from zentrack.zsession import add_zenoh_arguments


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_arguments(p)
    sinks = p.add_argument_group("sinks (at least one)")
    sinks.add_argument("--save", metavar="PATH.rrd", help="write the recording to this file")
    sinks.add_argument("--serve", action="store_true", help="serve a web viewer (and gRPC) on --bind")
    sinks.add_argument("--spawn", action="store_true", help="open the native Rerun viewer (needs a display)")
    p.add_argument("--bind", default="127.0.0.1", help="address --serve binds to (default 127.0.0.1)")
    p.add_argument("--web-port", type=int, default=9090, help="web viewer port (default 9090)")
    p.add_argument("--grpc-port", type=int, default=9876, help="gRPC port of --serve (default 9876)")
    p.add_argument("--flush-s", type=float, default=1.0, help="seconds between flushes to the sinks (default 1)")
    p.add_argument("--linger", type=float, default=0.0, help="--serve: keep serving this long after ctl/stop")
    p.add_argument("--nice", type=int, default=10, help="lower the viewer's CPU priority by this much so trackers "
                   "keep their deadlines on a loaded machine (default 10; 0 to keep it)")
    add_zenoh_arguments(p)
