"""Zenoh session plumbing shared by every process: the Zenoh flags, their config, opening a session (or
retrying until a router is up), clean shutdown.

The configuration itself is built in :mod:`zentrack.transport.zconfig` and the inbox is
:mod:`zentrack.transport.inbox`; their names are re-exported here, where the processes import them.
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from zentrack.common.argtypes import int_in
from zentrack.common.deprecation import DeprecatedFlag
from zentrack.transport.inbox import Inbox, direct
from zentrack.transport.keys import Keys, check_run_name
from zentrack.transport.secure import Identity
from zentrack.transport.zconfig import (
    CONNECT_RETRY,
    DEFAULT_LISTEN,
    DEFAULT_ROUTER_LISTEN,
    PROTOCOLS,
    ROUTER_LEASE_MS,
    WAIT_BEFORE_DROP_US,
    build_config,
    check_endpoint,
    check_endpoints,
    data_congestion,
    describe_config,
    describe_source,
    load_config_file,
    loopback_config,
    retry_quickly,
    safe_defaults,
    zenoh_message,
)
from zentrack.transport.zruntime import ensure_runtime_threads

__all__ = [
    "ZENOH_MODES", "add_zenoh_arguments", "run_name_type", "zenoh_config", "open_retrying", "open_zenoh",
    "session_from_args", "open_session", "undeclare_all",
    # re-exported from zentrack.transport.inbox and zentrack.transport.zconfig
    "Inbox", "direct", "CONNECT_RETRY", "DEFAULT_LISTEN", "DEFAULT_ROUTER_LISTEN", "PROTOCOLS",
    "ROUTER_LEASE_MS", "WAIT_BEFORE_DROP_US", "build_config", "check_endpoint",
    "check_endpoints", "data_congestion", "describe_config", "describe_source", "load_config_file",
    "loopback_config", "retry_quickly", "safe_defaults", "zenoh_message",
]

#: what ``--zenoh-mode`` takes (every process command names it so; the run's timing is ``--timing``)
ZENOH_MODES = ("peer", "client", "router")
log = logging.getLogger("zentrack.zenoh")


def add_zenoh_arguments(p: argparse.ArgumentParser, lease_default: int | None = None) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("--run", default="default", type=run_name_type, help="run name: keys live under zentrack/<run>/")
    g.add_argument("--zenoh-mode", dest="zenoh_mode", choices=ZENOH_MODES, default="peer",
                   help="Zenoh mode (default peer; `--timing` is the run's timing)")
    g.add_argument("--mode", dest="zenoh_mode", choices=ZENOH_MODES, action=DeprecatedFlag, use="--zenoh-mode")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable, or comma-separated; a "
                        "client takes the first that answers)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; peers default to {DEFAULT_LISTEN})")
    g.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file (flags override it)")
    g.add_argument("--lease-ms", type=int_in(100, 600_000, "lease_ms"), default=lease_default, metavar="MS",
                   help="transport lease, 100 to 600000 ms: how fast others notice this process hang or lose its link")
    g.add_argument("--secure", metavar="CERTS_DIR",
                   help="secure mode: mutual TLS with this process's certificate from CERTS_DIR (`zentrack certs`), "
                        "as a client of a router that enforces access control (--connect tls/<router>:<port>)")


def run_name_type(text: str) -> str:
    try:
        return check_run_name(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def open_retrying(conf: zenoh.Config, timeout: float) -> zenoh.Session:
    """``zenoh.open(conf)``, tried again every 0.2 s while it fails (a router that is not listening yet) until
    ``timeout`` seconds have passed; then Zenoh's error is raised."""
    ensure_runtime_threads()
    end = time.time() + timeout
    while True:
        try:
            return zenoh.open(conf)
        except Exception:  # noqa: BLE001 - zenoh raises a plain exception while the router is not up yet
            if time.time() > end:
                raise
            time.sleep(0.2)


def fall_back(conf: zenoh.Config) -> bool:
    """A client whose first ``--connect`` endpoint did not answer within the connect timeout (Zenoh's client
    keeps retrying the first endpoint until then and never tries the next): drop that endpoint from ``conf`` and
    say whether any is left to try (a swarm tracker: its own host's router, then the hub)."""
    endpoints = json.loads(conf.get_json("connect/endpoints"))
    if json.loads(conf.get_json("mode")) != "client" or not isinstance(endpoints, list) or len(endpoints) < 2:
        return False
    log.warning("zenoh: no router answered at %s; trying %s", endpoints[0], ", ".join(endpoints[1:]))
    conf.insert_json5("connect/endpoints", json.dumps(endpoints[1:]))
    return True


def open_zenoh(conf: zenoh.Config, what: str) -> zenoh.Session:
    """``zenoh.open(conf)``, with Zenoh's errors at open time (a listener it cannot bind, TLS without a key, an
    unknown protocol, ...) turned into ValueError("<what>: cannot open a Zenoh session (<zenoh's message>)")."""
    ensure_runtime_threads()
    while True:
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError as exc:
            if not fall_back(conf):
                raise ValueError(f"{what}: cannot open a Zenoh session ({zenoh_message(exc)})") from None
    log.info("zenoh session %s: %s", session.zid(), describe_config(conf))
    if json.loads(conf.get_json("mode")) == "client":  # which router it took (the first of --connect that answered)
        log.info("zenoh client %s: client of router %s", session.zid(),
                 ", ".join(str(z) for z in session.info.routers_zid()) or "none yet")
    return session


def session_from_args(args: argparse.Namespace, role: str | None = None) -> zenoh.Session:
    """Open a Zenoh session from the flags of :func:`add_zenoh_arguments`: bad flags or config files, and
    Zenoh's errors at open time, are a ValueError naming the flag or file (the caller closes the session)."""
    return open_zenoh(zenoh_config(args, role), describe_source(args.zenoh_config, args.listen, args.connect))


def zenoh_config(args: argparse.Namespace, role: str | None = None) -> zenoh.Config:
    """Build the Zenoh config from the flags of :func:`add_zenoh_arguments` (see :func:`build_config`); ``role``
    names this process's certificate in secure mode (``truth``, ``node-<i>``, ``viewer``, ...)."""
    if args.lease_ms is not None and args.lease_ms < 100:
        raise ValueError(f"--lease-ms must be at least 100, got {args.lease_ms}")
    secure = None
    if getattr(args, "secure", None):
        if role is None:
            raise ValueError("--secure: this command has no secure-mode role")
        secure = Identity(Path(args.secure), role)
    return build_config(args.zenoh_mode, args.listen, args.connect, file=args.zenoh_config, lease_ms=args.lease_ms,
                        connect_timeout_ms=int(getattr(args, "connect_timeout_ms", 30000)), secure=secure)


def undeclare_all(*entities) -> None:
    """Undeclare subscribers, publishers and liveliness tokens (lists are flattened)."""
    for e in entities:
        for item in e if isinstance(e, (list, tuple)) else [e]:
            item.undeclare()


@contextmanager
def open_session(args: argparse.Namespace, role: str | None = None) -> Iterator[tuple[zenoh.Session, Keys]]:
    """Open (and always close) a Zenoh session for the run named by ``args.run``; a config Zenoh refuses at open
    time is a ValueError naming the config file or flags at fault."""
    session = session_from_args(args, role)
    try:
        yield session, Keys(args.run)
    finally:
        session.close()
