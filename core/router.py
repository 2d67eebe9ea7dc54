"""``zentrack router``: a Zenoh router (``zenoh.open`` in router mode) for star and multi-host topologies."""
from __future__ import annotations

import argparse
import json
import logging

import zenoh

from .zsession import StopFlag, loopback_config, setup_logging

log = logging.getLogger("zentrack.router")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447; tcp/0.0.0.0:7447 for all interfaces)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="other routers to connect to")
    p.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file (flags override it)")


def run(args: argparse.Namespace) -> int:
    setup_logging()
    listen = args.listen or ["tcp/127.0.0.1:7447"]
    if args.zenoh_config:
        conf = zenoh.Config.from_file(args.zenoh_config)
        conf.insert_json5("mode", '"router"')
        conf.insert_json5("listen/endpoints", json.dumps(listen))
        if args.connect:
            conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    else:
        conf = loopback_config("router", listen=listen, connect=args.connect)
    stop = StopFlag()
    with zenoh.open(conf) as session:
        log.info("router %s listening on %s", session.zid(), args.listen or ["tcp/127.0.0.1:7447"])
        while not stop.event.wait(1.0):
            pass
    return 0
