"""``zentrack router``: a Zenoh router (``zenoh.open`` in router mode) for star and multi-host topologies."""
from __future__ import annotations

import argparse
import logging

from zentrack.common.procs import StopFlag, setup_logging
from zentrack.transport.zsession import (
    DEFAULT_ROUTER_LISTEN,
    build_config,
    describe_config,
    describe_source,
    open_zenoh,
)

log = logging.getLogger("zentrack.router")

DEFAULT_LISTEN = DEFAULT_ROUTER_LISTEN


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447 or the --zenoh-config file's; tcp/0.0.0.0:7447 for all interfaces)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="other routers to connect to")
    p.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file (flags override it)")


def run(args: argparse.Namespace) -> int:
    setup_logging()
    conf = build_config("router", args.listen, args.connect, file=args.zenoh_config)
    stop = StopFlag()
    with open_zenoh(conf, describe_source(args.zenoh_config, args.listen, args.connect)) as session:
        log.info("router %s: %s", session.zid(), describe_config(conf))
        while not stop.event.wait(1.0):
            pass
    return 0
