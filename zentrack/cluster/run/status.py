"""``zentrack status`` and ``zentrack health``: who is alive in a run, from Zenoh liveliness tokens.

``status`` lists every live token of the run (``alive/*``: trackers by id, ``truth``, ``recorder``, ``viewer``).
``health`` exits 0 when the token ``alive/<name>`` is present and 1 otherwise; it is what a container's
HEALTHCHECK runs, so its defaults come from the environment (``ZENTRACK_RUN``, ``ZENTRACK_NAME``,
``ZENTRACK_CONNECT``, ``ZENTRACK_ZENOH_MODE`` (``ZENTRACK_MODE`` for one more release), ``ZENTRACK_SECURE``, ``ZENTRACK_ZENOH_CONFIG``) when the flags are not given. ``health --router`` checks a router
instead: a client session to ``--connect`` reaches it (a router holds no token of any run).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time

from zentrack.common.argtypes import float_in
from zentrack.transport.keys import Keys, node_id
from zentrack.transport.zsession import add_zenoh_arguments, session_from_args

timeout_s = float_in(0.01, 3600.0, "timeout")  # seconds to wait for the cluster


def wait_connected(session, timeout: float, settle: float = 0.25) -> None:
    """Give a fresh session up to ``timeout`` to reach its peers: a peer learns the others by gossip after
    its first connection, and only peers it is connected to answer, so wait until the set stops growing."""
    end = time.time() + timeout
    seen, stable_since = -1, time.time()
    while time.time() < end:
        count = len(list(session.info.peers_zid())) + len(list(session.info.routers_zid()))
        if count != seen:
            seen, stable_since = count, time.time()
        elif count > 0 and time.time() - stable_since >= settle:
            return
        time.sleep(0.02)


def live_tokens(session, keys: Keys, timeout: float) -> list[str]:
    """Names of the live tokens of the run (node ids as strings, ``truth``, ...), sorted."""
    wait_connected(session, timeout)
    names = set()
    for reply in session.liveliness().get(keys.alive("*"), timeout=timeout):
        if reply.ok is not None:
            names.add(keys.last_segment(str(reply.ok.key_expr)))
    return sorted(names, key=lambda n: (node_id(n) is None, node_id(n) or 0, n))


def add_status_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--timeout", type=timeout_s, default=2.0, help="seconds to wait for the cluster, up to 3600 (default 2)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    add_zenoh_arguments(p)
    p.set_defaults(listen=[], connect_timeout_ms=2000)


def probe(args: argparse.Namespace) -> list[str]:
    """The live token names of ``args.run``. The session is closed with a bound: closing waits on every peer,
    and a frozen one (SIGSTOP, a cut link) would hold a probe for its whole lease; the answer is known by then,
    so after ``CLOSE_WAIT_S`` the probe leaves the close to the exit (see :func:`finish`)."""
    session = session_from_args(args, "monitor")
    try:
        return live_tokens(session, Keys(args.run), args.timeout)
    finally:
        closer = threading.Thread(target=session.close, daemon=True)
        closer.start()
        closer.join(CLOSE_WAIT_S)
        if closer.is_alive():
            _pending_close.append(closer)


CLOSE_WAIT_S = 1.0
_pending_close: list[threading.Thread] = []


def finish(code: int) -> int:
    """Return ``code``, or exit at once with it when a session close is still blocked on a frozen peer."""
    if _pending_close:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def status(args: argparse.Namespace) -> int:
    names = probe(args)
    keys = Keys(args.run)
    nodes = [i for i in map(node_id, names) if i is not None]
    others = [n for n in names if node_id(n) is None]
    if args.json:
        print(json.dumps({"run": keys.run, "nodes": nodes, "processes": others}))
    else:
        print(f"run {keys.run}: {len(nodes)} tracker(s) alive {nodes}; other processes {others}")
    return finish(0)


def add_health_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--name", default=os.environ.get("ZENTRACK_NAME"), help="token to check (node id, truth, ...)")
    p.add_argument("--router", action="store_true",
                   help="check instead that a Zenoh router answers at --connect (the router service's HEALTHCHECK)")
    p.add_argument("--timeout", type=timeout_s, default=2.0, help="seconds to wait, up to 3600 (default 2)")
    add_zenoh_arguments(p)
    env_connect = os.environ.get("ZENTRACK_CONNECT")
    p.set_defaults(run=os.environ.get("ZENTRACK_RUN", "default"), connect=[env_connect] if env_connect else [],
                   zenoh_mode=os.environ.get("ZENTRACK_ZENOH_MODE") or os.environ.get("ZENTRACK_MODE") or "peer",
                   listen=[], connect_timeout_ms=2000,
                   secure=os.environ.get("ZENTRACK_SECURE") or None,
                   zenoh_config=os.environ.get("ZENTRACK_ZENOH_CONFIG") or None)


def router_answers(args: argparse.Namespace) -> bool:
    """Whether a client session to ``--connect`` reaches a Zenoh router within ``--timeout``."""
    try:
        session = session_from_args(args, "monitor")
    except ValueError:
        return False  # nothing listens there (yet)
    try:
        end = time.time() + args.timeout
        while time.time() < end:
            if list(session.info.routers_zid()):
                return True
            time.sleep(0.02)
        return False
    finally:
        session.close()


def health(args: argparse.Namespace) -> int:
    if args.router:
        if args.zenoh_mode != "client" or not args.connect:
            raise ValueError("health --router: give the router's endpoint with --connect and --zenoh-mode client "
                             "(or ZENTRACK_CONNECT and ZENTRACK_ZENOH_MODE=client)")
        ok = router_answers(args)
        print(f"router at {', '.join(args.connect)}: {'healthy' if ok else 'no answer'}", file=sys.stderr)
        return 0 if ok else 1
    if not args.name:
        raise ValueError("health: give --name (or set ZENTRACK_NAME)")
    alive = args.name in probe(args)
    print(f"{args.name}: {'healthy' if alive else 'no liveliness token'} (run {args.run})", file=sys.stderr)
    return finish(0 if alive else 1)
