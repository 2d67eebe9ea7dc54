"""Zenoh session plumbing shared by every process: configuration from flags, an inbox, clean shutdown.

Embedded default: a peer that listens on ``tcp/127.0.0.1:0`` with multicast scouting off; peers find each
other through the endpoints they ``--connect`` to and gossip (no router needed). ``--zenoh-mode client`` with
``--connect tcp/<router>:7447`` goes through a router; ``--zenoh-config FILE`` loads a full Zenoh config
(JSON5) that the flags then override.
"""
from __future__ import annotations

import argparse
import json
import logging
import queue
import re
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from zentrack.common.argtypes import int_in
from zentrack.common.deprecation import DeprecatedFlag
from zentrack.transport.codec import MAX_MESSAGE_BYTES, Message, WireError, check_framing
from zentrack.transport.keys import Keys, check_run_name
from zentrack.transport.secure import Identity, apply_access_control, apply_tls
from zentrack.transport.zruntime import ensure_runtime_threads

DEFAULT_LISTEN = "tcp/127.0.0.1:0"
#: what ``--zenoh-mode`` takes (every process command names it so; the run's timing is ``--timing``)
ZENOH_MODES = ("peer", "client", "router")
log = logging.getLogger("zentrack.zenoh")

# link protocols of the eclipse-zenoh wheel; the ones in _HOST_PORT take ``<host>:<port>`` addresses
PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "serial", "vsock")
_HOST_PORT = ("tcp", "udp", "tls", "quic", "ws")
_HOST = re.compile(r"^(\[[0-9A-Fa-f:.]+(%[\w.-]+)?\]|[A-Za-z0-9_.-]+)$")


def add_zenoh_arguments(p: argparse.ArgumentParser, lease_default: int | None = None) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("--run", default="default", type=run_name_type, help="run name: keys live under zentrack/<run>/")
    g.add_argument("--zenoh-mode", dest="zenoh_mode", choices=ZENOH_MODES, default="peer",
                   help="Zenoh mode (default peer; `--timing` is the run's timing)")
    g.add_argument("--mode", dest="zenoh_mode", choices=ZENOH_MODES, action=DeprecatedFlag, use="--zenoh-mode")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
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


def zenoh_message(exc: BaseException) -> str:
    """Zenoh's error text on one line, without the Rust source locations it appends."""
    text = str(exc)
    inner = re.search(r'msg: "(.*?)", location', text, re.S)
    if inner:
        text = inner.group(1)
    text = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", text)
    text = " ".join(text.split()).rstrip(". ")
    return text or type(exc).__name__


def check_endpoint(endpoint: object, what: str) -> str:
    """Check the syntax of a Zenoh endpoint ``<protocol>/<address>[?<metadata>][#<config>]`` before Zenoh
    sees it (Zenoh silently retries a connect endpoint it cannot parse); raise ValueError naming ``what``."""
    if not isinstance(endpoint, str) or "/" not in endpoint:
        raise ValueError(f"{what}: {endpoint!r} is not a Zenoh endpoint; expected <protocol>/<address>, "
                         f"e.g. tcp/127.0.0.1:7447")
    proto, address = endpoint.split("/", 1)
    address = re.split(r"[?#]", address, maxsplit=1)[0]
    if proto not in PROTOCOLS:
        raise ValueError(f"{what}: {endpoint!r}: unknown protocol {proto!r}; allowed: {', '.join(PROTOCOLS)}")
    if not address:
        raise ValueError(f"{what}: {endpoint!r}: the address after {proto}/ is missing")
    if proto in _HOST_PORT:
        host, sep, port = address.rpartition(":")
        if not sep or not _HOST.match(host) or not (port.isascii() and port.isdigit()) or not 0 <= int(port) <= 65535:
            raise ValueError(f"{what}: {endpoint!r}: expected {proto}/<host>:<port> with a port from 0 to 65535, "
                             f"e.g. {proto}/127.0.0.1:7447")
    return endpoint


def check_endpoints(endpoints: list, what: str) -> list:
    for e in endpoints:
        check_endpoint(e, what)
    return list(endpoints)


def _config_endpoints(conf: zenoh.Config, key: str) -> list:
    """The endpoints under ``key`` of a config (a list, or a map from mode to list)."""
    try:
        value = json.loads(conf.get_json(key))
    except Exception:  # noqa: BLE001 - a key the config does not have
        return []
    if isinstance(value, dict):
        return [e for v in value.values() if isinstance(v, list) for e in v]
    return value if isinstance(value, list) else []


def load_config_file(path: str) -> zenoh.Config:
    """Read a Zenoh JSON5 config; any problem (missing, unreadable, bad syntax, bad endpoint) is a ValueError
    naming the file."""
    try:
        conf = zenoh.Config.from_file(path)
    except Exception as exc:  # zenoh raises ZError with the parser's message
        raise ValueError(f"{path}: not a valid Zenoh config ({zenoh_message(exc)})") from None
    for key in ("listen/endpoints", "connect/endpoints"):
        check_endpoints(_config_endpoints(conf, key), f"{path}: {key.replace('/', '.')}")
    return conf


def describe_source(zenoh_config_file: str | None = None, listen: list | None = None,
                    connect: list | None = None) -> str:
    """What set up a Zenoh config, for error messages: the config file and the endpoint flags."""
    parts = [f"--zenoh-config {zenoh_config_file}"] if zenoh_config_file else []
    parts += [f"--listen {e}" for e in listen or []] + [f"--connect {e}" for e in connect or []]
    return ", ".join(parts) or "the default Zenoh config"


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


def open_zenoh(conf: zenoh.Config, what: str) -> zenoh.Session:
    """``zenoh.open(conf)``, with Zenoh's errors at open time (a listener it cannot bind, TLS without a key, an
    unknown protocol, ...) turned into ValueError("<what>: cannot open a Zenoh session (<zenoh's message>)")."""
    ensure_runtime_threads()
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ValueError(f"{what}: cannot open a Zenoh session ({zenoh_message(exc)})") from None
    log.info("zenoh session %s: %s", session.zid(), describe_config(conf))
    return session


def session_from_args(args: argparse.Namespace, role: str | None = None) -> zenoh.Session:
    """Open a Zenoh session from the flags of :func:`add_zenoh_arguments`: bad flags or config files, and
    Zenoh's errors at open time, are a ValueError naming the flag or file (the caller closes the session)."""
    return open_zenoh(zenoh_config(args, role), describe_source(args.zenoh_config, args.listen, args.connect))


#: how long (µs) a ``CongestionControl.DROP`` put may wait for a free batch before Zenoh drops the message.
#: Zenoh's default, 1 ms, loses messages on a busy 2-core host whenever the link's tx task is not scheduled
#: within 1 ms of a burst (every tracker publishes its round message at the same instant): a consensus round
#: then waits for a message that never comes. 20 ms rides out such a scheduling gap; a genuinely blocked
#: link still drops, and a lost peer's link closes at its lease.
WAIT_BEFORE_DROP_US = 20_000


def data_congestion(timing_mode: str) -> zenoh.CongestionControl:
    """The congestion control of a process's publishers in a run of ``timing_mode``.

    Realtime: ``DROP``. A ``BLOCK`` message that meets a full queue holds up everything behind it for up to
    ``block/wait_before_close`` (Zenoh's default 5 s) -- in the publisher, and in every router that forwards
    it, whose receive task for that publisher stops too: one cut or slow link towards one host (router to
    router) then starved every subscriber of the same publisher on the other hosts (measured: a 10 s cut
    between two hosts' routers made the trackers on the truth's own host coast 49 steps). A dropped message
    costs one step of one receiver, which the schedule already rides out by coasting. Lockstep: ``BLOCK``;
    every step waits for every message anyway, and none may be lost."""
    return zenoh.CongestionControl.BLOCK if timing_mode == "lockstep" else zenoh.CongestionControl.DROP


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


#: zentrack's safe defaults: what a process uses for every key that neither a flag nor its config file sets
def safe_defaults(mode: str) -> dict[str, str]:
    out = {
        "scouting/multicast/enabled": "false",  # no multicast: peers meet only through the endpoints given
        "transport/link/tx/queue/congestion_control/drop/wait_before_drop": str(WAIT_BEFORE_DROP_US),
        # zentrack never publishes through shared memory; with it on, every flood of large messages left a
        # receiver ~20 MB bigger for good (measured: 50,000 x 66 KB, RSS 41 -> 62 MB; off: 41 -> 42 MB)
        "transport/shared_memory/enabled": "false",
    }
    if mode in ("peer", "router"):  # listen on loopback only, never on every interface by accident
        out["listen/endpoints"] = json.dumps([DEFAULT_LISTEN if mode == "peer" else DEFAULT_ROUTER_LISTEN])
    return out


DEFAULT_ROUTER_LISTEN = "tcp/127.0.0.1:7447"

#: the Zenoh lease (ms) of a router that dials another host's (``zentrack router --connect``; ``--lease-ms``):
#: the others close their link to it after this long without a word from it. With Zenoh's 10 s a cut
#: router-to-router link stays half-open through a 10 s partition and its TCP connection resumes only at its
#: next retransmission: the far host's trackers heard the truth again 27 steps after the heal, 10-14 with 1 s
#: (tests/test_partition.py). The hub router (no ``--connect``) keeps Zenoh's lease.
ROUTER_LEASE_MS = 1000


def build_config(mode: str = "peer", listen: list | None = None, connect: list | None = None, file: str | None = None,
                 lease_ms: int | None = None, connect_timeout_ms: int = 30000, secure: Identity | None = None,
                 access: tuple[str, int] | None = None) -> zenoh.Config:
    """The one way every zentrack process builds its Zenoh config, in three layers:

    1. zentrack's :func:`safe_defaults` (loopback listen, multicast scouting off, the drop wait);
    2. the config file ``file``, if any, merged over them: a key the file sets wins; a key it leaves at
       Zenoh's own default (listen on every interface, multicast on) keeps zentrack's safe value;
    3. the flags: ``mode``, ``listen`` and ``connect`` endpoints (replacing the file's), ``lease_ms``.

    Secure mode (``secure``, :mod:`~zentrack.transport.secure`) comes last and cannot be loosened by the file:
    mutual TLS only, no scouting; a router enforces ``access`` = (run, nodes); everyone else is a client that
    only connects (``tls/`` endpoints) and listens nowhere, so no peer-to-peer link bypasses the router.
    """
    check_endpoints(listen or [], "--listen")
    check_endpoints(connect or [], "--connect")
    if secure is not None:
        mode = "router" if mode == "router" else "client"
        for e in (listen or []) + (connect or []):
            if not e.startswith("tls/"):
                raise ValueError(f"--secure: endpoint {e!r} is not tls/<host>:<port>")
        if mode == "client" and listen:
            raise ValueError("--secure: a client listens nowhere (it connects to the router); drop --listen")
        if mode == "router" and access is None:
            raise ValueError("--secure: the router needs the run name and the number of trackers for its access control")
    conf = load_config_file(file) if file else zenoh.Config()
    stock = zenoh.Config()
    for key, value in safe_defaults(mode).items():
        if conf.get_json(key) == stock.get_json(key):  # not set by the file
            conf.insert_json5(key, value)
    conf.insert_json5("mode", json.dumps(mode))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        # keep trying while the router or hub is still starting (compose starts services in any order)
        conf.insert_json5("connect/timeout_ms", str(int(connect_timeout_ms)))
        conf.insert_json5("connect/exit_on_failure", "false")
        retry_quickly(conf, ROUTER_CONNECT_RETRY if mode == "router" else CONNECT_RETRY)
    if lease_ms is not None:
        conf.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    if secure is not None:
        apply_tls(conf, secure, listen=mode == "router")
        if mode == "client":
            conf.insert_json5("listen/endpoints", "[]")
        if access is not None:
            apply_access_control(conf, *access)
    return conf


def describe_config(conf: zenoh.Config) -> str:
    """The settings that decide who can reach a process: mode, listen and connect endpoints, scouting."""
    def get(key: str):
        try:
            return json.loads(conf.get_json(key))
        except Exception:  # noqa: BLE001 - a key this Zenoh version does not have
            return None

    mode = get("mode") or "peer"
    listen = get("listen/endpoints")
    if isinstance(listen, dict):
        listen = listen.get(mode, [])
    multicast = get("scouting/multicast/enabled")
    gossip = get("scouting/gossip/enabled")
    tls = get("transport/link/tls") or {}
    cert = tls.get("connect_certificate") or tls.get("listen_certificate")
    acl = get("access_control") or {}
    secure = (f", mutual TLS as {Path(cert).stem}" if cert and tls.get("enable_mtls") else "") + (
        f", access control on ({len(acl.get('policies', []))} roles)" if acl.get("enabled") else "")
    return (f"mode {mode}, listen {listen or []}, connect {get('connect/endpoints') or []}, multicast scouting "
            f"{'on' if multicast in (None, True) else 'off'}, gossip {'on' if gossip in (None, True) else 'off'}"
            + secure)


def direct(callback: Callable) -> zenoh.handlers.Callback:
    """A callback Zenoh runs on its own receiving thread. zenoh-python's default (``indirect=True``) runs each
    subscription's callback on a Python thread of its own, fed through a channel: one more thread wake-up per
    message on the way to the main loop, per subscription a thread. The inbox's callbacks only copy bytes and
    enqueue, so they are safe to run directly."""
    return zenoh.handlers.Callback(callback, indirect=False)


class Inbox:
    """All subscriptions of a process feed one queue; Zenoh callbacks only copy bytes and enqueue (run directly
    on Zenoh's receiving thread, see :func:`direct`).

    Flood guard, applied in the Zenoh callback before a payload is even copied: a message over
    ``max_bytes`` is dropped (``size``); each key has a token bucket (``rate_per_key`` messages per second,
    bursts of ``burst`` s worth) and a message beyond it is dropped (``rate``); data messages (every tag but
    the control ones) beyond ``max_queued`` waiting in the queue are dropped (``queue``). Drops are counted in
    ``dropped`` (``"<tag>/<reason>"`` -> count), which a caller may share across inboxes.

    Decode, then limit: once a key's bucket is down to half (and until it is empty: then nothing takes a
    token anyway, and nothing is looked at), a data message takes a token only if it frames
    as one of zentrack's (:func:`~zentrack.transport.codec.check_framing`: msgpack, version, kind, step); anything
    else is dropped under the framing's reason (``undecodable``, ``version``, ...) without a token. So a
    stranger's garbage flood on a key cannot use up the bucket its genuine publisher needs (the truth's
    measurements on ``meas/<i>``); a flood of well-formed messages still can in insecure mode (``--secure``
    lets only the truth publish there)."""

    CONTROL_TAGS = ("start", "stop", "alive")

    def __init__(self, rate_per_key: float = 200.0, burst: float = 2.0, max_bytes: int = MAX_MESSAGE_BYTES,
                 max_queued: int = 2000, dropped: dict[str, int] | None = None) -> None:
        # SimpleQueue: put and a timed get are one C call each (Queue's are a dozen Python calls and a Condition)
        self.queue: queue.SimpleQueue[Message] = queue.SimpleQueue()
        self.rate_per_key, self.burst, self.max_bytes, self.max_queued = rate_per_key, burst, max_bytes, max_queued
        self.dropped: dict[str, int] = dropped if dropped is not None else {}
        self._buckets: dict[str, list[float]] = {}  # key -> [tokens, last refill]
        self._queued = 0  # data messages waiting (control ones are not bounded here: rate-limited per key)
        self._lock = threading.Lock()

    def set_rate(self, rate_per_key: float) -> None:
        """Messages per second per key before the guard drops (e.g. once the run's period is known)."""
        with self._lock:
            self.rate_per_key = float(rate_per_key)

    def admit(self, tag: str, key: str, size: int, now: float, payload: Callable[[], bytes] | None = None) -> bool:
        """Whether a message of ``size`` bytes on ``key`` may be queued; counts it under its reason if not.
        ``payload`` gives its bytes, framed (class docstring) once the key's bucket is down to half."""
        reason = None
        with self._lock:
            if size > self.max_bytes:
                reason = "size"
            else:
                cap = self.rate_per_key * self.burst
                tokens, last = self._buckets.get(key, (cap, now))
                tokens = min(cap, tokens + (now - last) * self.rate_per_key)
                if payload is not None and 1.0 <= tokens < 0.5 * cap and tag not in self.CONTROL_TAGS:
                    try:
                        check_framing(payload())
                    except WireError as err:  # not one of ours: no token for it
                        name = f"{tag}/{err.reason}"
                        self.dropped[name] = self.dropped.get(name, 0) + 1
                        return False
                if tokens < 1.0:
                    reason = "rate"
                elif tag not in self.CONTROL_TAGS and self._queued >= self.max_queued:
                    reason = "queue"
                else:
                    tokens -= 1.0
                    if tag not in self.CONTROL_TAGS:
                        self._queued += 1
                if len(self._buckets) < 10_000 or key in self._buckets:  # keys are few; a flood of new ones is not kept
                    self._buckets[key] = [tokens, now]
            if reason is not None:
                name = f"{tag}/{reason}"
                self.dropped[name] = self.dropped.get(name, 0) + 1
        return reason is None

    def callback(self, tag: str) -> zenoh.handlers.Callback:
        put, admit = self.queue.put, self.admit

        def on_sample(sample: zenoh.Sample) -> None:
            now, payload = time.time(), sample.payload  # (each ``sample.payload`` is a new Python object)
            key = str(sample.key_expr)
            if admit(tag, key, len(payload), now, payload.to_bytes):  # (bytes copied if looked at)
                put(Message(tag, key, payload.to_bytes(), now))

        return direct(on_sample)

    def liveliness_callback(self, tag: str = "alive") -> zenoh.handlers.Callback:
        put = self.queue.put

        def on_token(sample: zenoh.Sample) -> None:
            kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
            put(Message(tag, str(sample.key_expr), kind.encode(), time.time()))

        return direct(on_token)

    def reply_callback(self, tag: str) -> zenoh.handlers.Callback:
        """For ``session.get``: each good reply becomes a message like a sample on its key."""
        put = self.queue.put

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                put(Message(tag, str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.time()))

        return direct(on_reply)

    def get(self, timeout: float) -> Message | None:
        try:
            msg = self.queue.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None
        if msg.tag not in self.CONTROL_TAGS:
            with self._lock:
                self._queued -= 1
        return msg


def loopback_config(mode: str = "peer", listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Config:
    """:func:`build_config` without a file: zentrack's safe defaults and explicit endpoints."""
    return build_config(mode, listen, connect)


#: how a process re-tries a lost ``--connect`` endpoint (a restarted router): every 0.25 s at first, then at
#: most every 1 s, instead of Zenoh's default 1 s doubling to 4 s (which leaves a cluster deaf for up to 4 s
#: after its router is back)
CONNECT_RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 1.5}


#: how a router re-tries a lost ``--connect`` endpoint (another host's router, after a partition): every 0.1 s
#: at first, at most every 0.2 s. After a cut heals a host's trackers hear the truth again only once their
#: router has re-linked with the truth's: at :data:`CONNECT_RETRY`'s 1 s, up to 10 steps of a 0.1 s run were
#: lost to the wait alone. One router dials one or two endpoints; a refused attempt costs one SYN.
ROUTER_CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 200, "period_increase_factor": 1.5}


def retry_quickly(conf: zenoh.Config, retry: dict | None = None) -> None:
    """Set how a lost ``--connect`` endpoint is re-tried: ``retry`` (default :data:`CONNECT_RETRY`)."""
    conf.insert_json5("connect/retry", json.dumps(retry or CONNECT_RETRY))


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
