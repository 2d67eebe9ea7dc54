"""The key-expression scheme every zentrack process uses (prefix ``zentrack/<run>``).

==========================  ===========================================================================
key                         what is published there
==========================  ===========================================================================
``<prefix>/truth``          true state per step, or the targets present (many targets); evaluators only: recorder, viewer
``<prefix>/meas/<i>``       node i's scan for step k (published by truth)
``<prefix>/prior/<i>``      node i's fusion message for step k+1, round l (named information pairs (P̄⁻¹, P̄⁻¹ψ))
``<prefix>/scan/<i>``       scans node i forwards to its neighbours (rules that fuse neighbours' measurements)
``<prefix>/est/<i>``        node i's posterior for step k with timings and message counters
``<prefix>/tracks/<i>``     node i's track list for step k (id, status, mean, covariance per track)
``<prefix>/alive/<i>``      liveliness token of node i (``alive/truth`` for the truth process)
``<prefix>/ctl/start``      run parameters (mode, Ts, steps) announced by truth
``<prefix>/ctl/stop``       end of run
==========================  ===========================================================================
"""
from __future__ import annotations

import re
from dataclasses import dataclass

_RUN_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def check_run_name(run: str) -> str:
    """A run name becomes part of every key: letters, digits, ``_ . -`` only, 1-64 characters."""
    if not _RUN_RE.match(run):
        raise ValueError(f"run name {run!r} must be 1-64 characters from A-Z a-z 0-9 _ . -")
    return run


@dataclass(frozen=True)
class Keys:
    """Key expressions of one run."""

    run: str = "default"
    root: str = "zentrack"

    def __post_init__(self) -> None:
        check_run_name(self.run)

    @property
    def prefix(self) -> str:
        return f"{self.root}/{self.run}"

    @property
    def truth(self) -> str:
        return f"{self.prefix}/truth"

    def meas(self, node: int | str) -> str:
        return f"{self.prefix}/meas/{node}"

    def prior(self, node: int | str) -> str:
        return f"{self.prefix}/prior/{node}"

    def scan(self, node: int | str) -> str:
        return f"{self.prefix}/scan/{node}"

    def est(self, node: int | str) -> str:
        return f"{self.prefix}/est/{node}"

    def tracks(self, node: int | str) -> str:
        return f"{self.prefix}/tracks/{node}"

    def alive(self, node: int | str) -> str:
        return f"{self.prefix}/alive/{node}"

    @property
    def start(self) -> str:
        return f"{self.prefix}/ctl/start"

    @property
    def stop(self) -> str:
        return f"{self.prefix}/ctl/stop"

    def last_segment(self, key: str) -> str:
        """The final ``/``-separated part of a key (a node id or ``truth``)."""
        return key.rsplit("/", 1)[-1]

    def node_of(self, key: str) -> int | None:
        """The node id a key ends with (``.../est/3`` -> 3), or None when its last part is not a node id: only
        ASCII digits count (``str.isdigit`` also takes ``²``, which ``int`` refuses), at most four of them."""
        return node_id(self.last_segment(key))

    def kind_of(self, key: str) -> str:
        """``meas``, ``prior``, ``est``, ``alive``, ``truth`` or ``ctl`` for a key of this run."""
        rest = key[len(self.prefix) + 1 :] if key.startswith(self.prefix + "/") else ""
        return rest.split("/", 1)[0]


def node_id(name: str) -> int | None:
    """``name`` as a node id if it is one (1 to 4 ASCII digits), else None."""
    return int(name) if 0 < len(name) <= 4 and name.isascii() and name.isdigit() else None
