"""The one way every zentrack process builds its Zenoh config (:func:`build_config`), and what goes with it:
endpoint syntax checks, zentrack's safe defaults, a config file's checks, connect retries, the congestion
control of data publishers, and one-line descriptions of a config and of Zenoh's errors.

Embedded default: a peer that listens on ``tcp/127.0.0.1:0`` with multicast scouting off; peers find each
other through the endpoints they ``--connect`` to and gossip (no router needed). ``--zenoh-mode client`` with
``--connect tcp/<router>:7447`` goes through a router; ``--zenoh-config FILE`` loads a full Zenoh config
(JSON5) that the flags then override. The flags themselves, and opening a session, are
:mod:`zentrack.transport.zsession`.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import zenoh

from zentrack.transport.secure import Identity, Takes, apply_access_control, apply_tls

DEFAULT_LISTEN = "tcp/127.0.0.1:0"
DEFAULT_ROUTER_LISTEN = "tcp/127.0.0.1:7447"

# link protocols of the eclipse-zenoh wheel; the ones in _HOST_PORT take ``<host>:<port>`` addresses
PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "serial", "vsock")
_HOST_PORT = ("tcp", "udp", "tls", "quic", "ws")
_HOST = re.compile(r"^(\[[0-9A-Fa-f:.]+(%[\w.-]+)?\]|[A-Za-z0-9_.-]+)$")


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


#: the Zenoh lease (ms) of a router that dials another host's (``zentrack router --connect``; ``--lease-ms``):
#: the others close their link to it after this long without a word from it. With Zenoh's 10 s a cut
#: router-to-router link stays half-open through a 10 s partition and its TCP connection resumes only at its
#: next retransmission: the far host's trackers heard the truth again 27 steps after the heal, 10-14 with 1 s
#: (tests/test_partition.py). The hub router (no ``--connect``) keeps Zenoh's lease.
ROUTER_LEASE_MS = 1000


def endpoint_list(given: list[str]) -> list[str]:
    """``--connect`` endpoints, each given alone or several comma-separated in one (``ZENTRACK_CONNECT``, a
    swarm tracker's own host's router then the hub): in order, a client takes the first that answers."""
    return [e.strip() for entry in given for e in str(entry).split(",") if e.strip()]


def build_config(mode: str = "peer", listen: list | None = None, connect: list | None = None, file: str | None = None,
                 lease_ms: int | None = None, connect_timeout_ms: int = 30000, secure: Identity | None = None,
                 access: tuple[str, int] | tuple[str, int, int, Takes | None] | None = None) -> zenoh.Config:
    """The one way every zentrack process builds its Zenoh config, in three layers:

    1. zentrack's :func:`safe_defaults` (loopback listen, multicast scouting off, the drop wait);
    2. the config file ``file``, if any, merged over them: a key the file sets wins; a key it leaves at
       Zenoh's own default (listen on every interface, multicast on) keeps zentrack's safe value;
    3. the flags: ``mode``, ``listen`` and ``connect`` endpoints (replacing the file's), ``lease_ms``.

    Secure mode (``secure``, :mod:`~zentrack.transport.secure`) comes last and cannot be loosened by the file:
    mutual TLS only, no scouting; a router enforces ``access`` = (run, nodes) or (run, nodes, sensors, takes)
    (:func:`~zentrack.transport.secure.access_control`); everyone else is a client that
    only connects (``tls/`` endpoints) and listens nowhere, so no peer-to-peer link bypasses the router.
    """
    connect = endpoint_list(connect or [])
    check_endpoints(listen or [], "--listen")
    check_endpoints(connect, "--connect")
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
        retry_quickly(conf)
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


def loopback_config(mode: str = "peer", listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Config:
    """:func:`build_config` without a file: zentrack's safe defaults and explicit endpoints."""
    return build_config(mode, listen, connect)


#: how every process (a client, a peer, a router) re-tries a lost ``--connect`` endpoint: every 0.1 s. A client's
#: wait for its restarted router is this period: at Zenoh's default (1 s doubling to 4 s), and then at 0.25 s
#: growing to 1 s, the recorder and the truth re-linked on a 1 s grid, and every tracker published again 10-12
#: steps of 0.1 s after a router restart; at 0.1 s, 3-4 (``zentrack bench router-restart``, docs/soak.md, where
#: a cap of 0.2 s cost half a step more). A router re-linking with another host's after a partition waited as long
#: (10 steps lost to the wait alone at 1 s). A refused attempt costs one SYN; an unreachable endpoint's attempt
#: waits for its own failure before the next.
CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 100, "period_increase_factor": 1.0}


def retry_quickly(conf: zenoh.Config, retry: dict | None = None) -> None:
    """Set how a lost ``--connect`` endpoint is re-tried: ``retry`` (default :data:`CONNECT_RETRY`)."""
    conf.insert_json5("connect/retry", json.dumps(retry or CONNECT_RETRY))
