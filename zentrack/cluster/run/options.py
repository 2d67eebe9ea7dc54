"""``zentrack run``'s topology and per-tracker prefix options, checked against the run."""
from __future__ import annotations

import argparse
import shlex
import shutil

TOPOLOGIES = ("auto", "peers", "router")
#: ``--topology auto`` meshes up to this many trackers as peers and uses a router above: in a full mesh every
#: tracker pays per link (keep-alives, lease checks), and on a 2-core host 24 peers missed 28 deadlines in
#: 30 s where 24 clients of a router missed none and cost 4.0 instead of 5.9 ms of CPU per step
#: (``zentrack bench scale --sizes 16,24 --duration 30 [--router]``)
PEER_MESH_LIMIT = 12


def uses_router(topology: str, router_flag: bool, nodes: int) -> bool:
    """Whether ``zentrack run`` starts a router for ``nodes`` trackers (ValueError for contradictory flags)."""
    if router_flag and topology == "peers":
        raise ValueError("--router contradicts --topology peers; choose one")
    return router_flag or topology == "router" or (topology == "auto" and nodes > PEER_MESH_LIMIT)


def node_prefix_arg(text: str) -> tuple[int, list[str]]:
    """``--node-prefix I=COMMAND``: tracker ``I`` and the command (split like a shell) its process runs under."""
    index, sep, command = text.partition("=")
    words = shlex.split(command) if sep else []
    if not index.strip().isdigit() or not words:
        raise argparse.ArgumentTypeError(f"expected I=COMMAND (e.g. 1='faketime -f +0.3s'), got {text!r}")
    return int(index), words


def node_prefixes(prefixes: dict[int, list[str]], nodes: int) -> dict[int, list[str]]:
    """``--node-prefix`` checked against the run: ValueError for a tracker it does not have or a command not found."""
    for i, words in prefixes.items():
        if i >= nodes:
            raise ValueError(f"--node-prefix {i}=...: the run has trackers 0..{nodes - 1}")
        if shutil.which(words[0]) is None:
            raise ValueError(f"--node-prefix {i}={shlex.join(words)}: no command {words[0]!r} on PATH")
    return prefixes


#: what ``zentrack run --nodes 1`` warns
LONE_TRACKER = "--nodes 1: one tracker has no neighbours, so nothing is fused (a network needs --nodes 2 or more)"
