"""Zenoh session plumbing shared by every process: configuration from flags, an inbox, clean shutdown.

Embedded default: a peer that listens on ``tcp/127.0.0.1:0`` with multicast scouting off; peers find each
other through the endpoints they ``--connect`` to and gossip (no router needed). ``--mode client`` with
``--connect tcp/<router>:7447`` goes through a router; ``--zenoh-config FILE`` loads a full Zenoh config
(JSON5) that the flags then override.
"""
from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import zenoh

from .keys import Keys, check_run_name

DEFAULT_LISTEN = "tcp/127.0.0.1:0"


def add_zenoh_arguments(p: argparse.ArgumentParser, lease_default: int | None = None) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("--run", default="default", type=_run_name, help="run name: keys live under zentrack/<run>/")
    g.add_argument("--mode", dest="zenoh_mode", choices=("peer", "client", "router"), default="peer",
                   help="Zenoh mode (default peer)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; peers default to {DEFAULT_LISTEN})")
    g.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file (flags override it)")
    g.add_argument("--lease-ms", type=int, default=lease_default, metavar="MS",
                   help="transport lease: how fast others notice this process hang or lose its link")


def _run_name(text: str) -> str:
    try:
        return check_run_name(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """Build the Zenoh config from the flags of :func:`add_zenoh_arguments`."""
    if args.zenoh_config:
        try:
            conf = zenoh.Config.from_file(args.zenoh_config)
        except Exception as exc:  # zenoh raises ZError with the parser's message
            raise ValueError(f"{args.zenoh_config}: not a valid Zenoh config ({exc})") from None
    else:
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("mode", json.dumps(args.zenoh_mode))
    listen = list(args.listen)
    if not listen and args.zenoh_mode == "peer" and not args.zenoh_config:
        listen = [DEFAULT_LISTEN]
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if args.connect:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect))
        # keep trying while the router or hub is still starting (compose starts services in any order)
        conf.insert_json5("connect/timeout_ms", str(int(getattr(args, "connect_timeout_ms", 30000))))
        conf.insert_json5("connect/exit_on_failure", "false")
    if args.lease_ms is not None:
        if args.lease_ms < 100:
            raise ValueError(f"--lease-ms must be at least 100, got {args.lease_ms}")
        conf.insert_json5("transport/link/tx/lease", str(int(args.lease_ms)))
    return conf


@dataclass
class Message:
    """One item of an :class:`Inbox`: what arrived, on which key, when."""

    tag: str
    key: str
    payload: bytes
    t_recv: float


class Inbox:
    """All subscriptions of a process feed one queue; Zenoh callbacks only copy bytes and enqueue."""

    def __init__(self) -> None:
        self.queue: queue.Queue[Message] = queue.Queue()

    def callback(self, tag: str) -> Callable[[zenoh.Sample], None]:
        put = self.queue.put

        def on_sample(sample: zenoh.Sample) -> None:
            put(Message(tag, str(sample.key_expr), sample.payload.to_bytes(), time.time()))

        return on_sample

    def liveliness_callback(self, tag: str = "alive") -> Callable[[zenoh.Sample], None]:
        put = self.queue.put

        def on_token(sample: zenoh.Sample) -> None:
            kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
            put(Message(tag, str(sample.key_expr), kind.encode(), time.time()))

        return on_token

    def get(self, timeout: float) -> Message | None:
        try:
            return self.queue.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None


class StopFlag:
    """Set by SIGTERM/SIGINT so the main loop can close the session and exit cleanly."""

    def __init__(self) -> None:
        self.event = threading.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self.event.set())

    def __bool__(self) -> bool:
        return self.event.is_set()


def loopback_config(mode: str = "peer", listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Config:
    """A Zenoh config with multicast scouting off and explicit endpoints (what every zentrack process uses)."""
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("mode", json.dumps(mode))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    return conf


def setup_logging() -> None:
    """One log format for every process (stderr; the orchestrator sends it to <out>/logs/<name>.log)."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s", stream=sys.stderr)


def undeclare_all(*entities) -> None:
    """Undeclare subscribers, publishers and liveliness tokens (lists are flattened)."""
    for e in entities:
        for item in e if isinstance(e, (list, tuple)) else [e]:
            item.undeclare()


def processes_of_runs(runs: list[str], exclude: str | None = None) -> list[str]:
    """Command lines (first 200 characters) of processes started with ``--run <name>`` for one of ``runs``
    (this process and any whose command line contains ``exclude`` are left out)."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            cmd = open(f"/proc/{pid}/cmdline", "rb").read().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if any(f"--run {r} " in cmd + " " for r in runs) and not (exclude and exclude in cmd):
            found.append(cmd[:200])
    return found


def freeze_heap() -> None:
    """Move everything allocated so far (imported modules, scenario arrays) out of the garbage collector's
    reach, so a full collection in a long-running process takes microseconds, not tens of milliseconds."""
    gc.collect()
    gc.freeze()


@contextmanager
def open_session(args: argparse.Namespace) -> Iterator[tuple[zenoh.Session, Keys]]:
    """Open (and always close) a Zenoh session for the run named by ``args.run``."""
    session = zenoh.open(zenoh_config(args))
    try:
        yield session, Keys(args.run)
    finally:
        session.close()
