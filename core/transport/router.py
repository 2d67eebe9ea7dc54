"""``zentrack router``: a Zenoh router (``zenoh.open`` in router mode) for star and multi-host topologies."""
from __future__ import annotations

import argparse
import json
import logging

import zenoh

from zentrack.common.procs import StopFlag, setup_logging
from zentrack.transport.zsession import check_endpoints, describe_source, load_config_file, loopback_config, open_zenoh

log = logging.getLogger("zentrack.router")

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def _file_sets_listen(conf: zenoh.Config) -> bool:
    """Whether a config file chose its own listen endpoints (the router keeps them unless --listen is given)."""
    return conf.get_json("listen/endpoints") != zenoh.Config().get_json("listen/endpoints")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447 or the --zenoh-config file's; tcp/0.0.0.0:7447 for all interfaces)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="other routers to connect to")
    p.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file (flags override it)")


def run(args: argparse.Namespace) -> int:
    setup_logging()
    listen = check_endpoints(args.listen or [DEFAULT_LISTEN], "--listen")
    flags = list(args.listen) or [f"{DEFAULT_LISTEN} (default)"]
    check_endpoints(args.connect, "--connect")
    if args.zenoh_config:
        conf = load_config_file(args.zenoh_config)
        conf.insert_json5("mode", '"router"')
        if args.listen or not _file_sets_listen(conf):
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        else:
            listen, flags = json.loads(conf.get_json("listen/endpoints")), []
        if args.connect:
            conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    else:
        conf = loopback_config("router", listen=listen, connect=args.connect)
    stop = StopFlag()
    with open_zenoh(conf, describe_source(args.zenoh_config, flags, args.connect)) as session:
        log.info("router %s listening on %s", session.zid(), listen)
        while not stop.event.wait(1.0):
            pass
    return 0
