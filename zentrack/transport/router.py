"""``zentrack router``: a Zenoh router (``zenoh.open`` in router mode) for star and multi-host topologies."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from zentrack.common.argtypes import int_in
from zentrack.common.procs import StopFlag, setup_logging
from zentrack.transport.secure import Identity, Takes, default_takes, parse_takes, takes_text
from zentrack.transport.zsession import (
    DEFAULT_ROUTER_LISTEN,
    ROUTER_LEASE_MS,
    build_config,
    describe_config,
    describe_source,
    open_zenoh,
    run_name_type,
)

log = logging.getLogger("zentrack.router")

DEFAULT_LISTEN = DEFAULT_ROUTER_LISTEN


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447 or the --zenoh-config file's; tcp/0.0.0.0:7447 for all interfaces)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="other routers to connect to")
    p.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file (flags override it)")
    p.add_argument("--lease-ms", type=int_in(100, 3_600_000, "milliseconds"), metavar="MS",
                   help=f"transport lease: how fast the others notice this router lost or its link cut (default: "
                        f"{ROUTER_LEASE_MS} with --connect and no --zenoh-config, else the file's or Zenoh's 10 s)")
    p.add_argument("--secure", metavar="CERTS_DIR",
                   help="secure mode: listen with mutual TLS only (tls/ endpoints) and enforce the access control of "
                        "run --run with --nodes trackers (and --sensors); certificates from `zentrack certs`")
    p.add_argument("--run", type=run_name_type, help="secure mode: the run whose keys the access control covers")
    p.add_argument("--nodes", type=int_in(1, 1000, "nodes"), help="secure mode: number of trackers (node-0 ..)")
    p.add_argument("--sensors", type=int_in(0, 1000, "sensors"), default=0,
                   help="secure mode: sensors of their own (sensor-0 ..; [sensor_timing]), each publishing only its "
                        "det/<s> (default 0)")
    p.add_argument("--takes", metavar="SPEC",
                   help="secure mode: which sensors each tracker may read, one group per tracker, '/' between them, "
                        "','-separated ids (e.g. 0,1/1/2; default: tracker i reads sensor i)")


def access_flags(run: str, nodes: int | str, sensors: int | str = 0, takes: Takes | None = None) -> list[str]:
    """The flags that give a secure router its access control: run ``run``, ``nodes`` trackers (a number, or a
    variable a deployment expands), ``sensors`` sensors of their own, and ``--takes`` when the trackers take
    other sensors than :func:`~zentrack.transport.secure.default_takes`'."""
    out = ["--run", run, "--nodes", str(nodes)]
    if sensors:
        out += ["--sensors", str(sensors)]
        if takes is not None and takes != default_takes(len(takes), int(sensors)):
            out += ["--takes", takes_text(takes)]
    return out


def run(args: argparse.Namespace) -> int:
    setup_logging()
    secure = access = None
    if args.secure:
        if not args.run or not args.nodes:
            raise ValueError("--secure: the router needs --run and --nodes for its access control")
        if args.takes is not None and not args.sensors:
            raise ValueError("--takes goes with --sensors (the sensors of their own the trackers take)")
        takes = None if args.takes is None else parse_takes(args.takes, args.nodes, args.sensors)
        secure, access = Identity(Path(args.secure), "router"), (args.run, args.nodes, args.sensors, takes)
    elif args.run or args.nodes or args.sensors or args.takes is not None:
        raise ValueError("--run, --nodes, --sensors and --takes go with --secure (the access control)")
    listen = args.listen or ([DEFAULT_LISTEN.replace("tcp/", "tls/")] if secure else [])
    lease = args.lease_ms if args.lease_ms is not None else (
        ROUTER_LEASE_MS if args.connect and not args.zenoh_config else None)  # else the file's, or Zenoh's
    conf = build_config("router", listen, args.connect, file=args.zenoh_config, lease_ms=lease, secure=secure,
                        access=access)
    stop = StopFlag()
    with open_zenoh(conf, describe_source(args.zenoh_config, args.listen, args.connect)) as session:
        log.info("router %s: %s", session.zid(), describe_config(conf))
        while not stop.wait(1.0):
            pass
    return 0
