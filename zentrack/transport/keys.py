"""The key-expression scheme every zentrack process uses (prefix ``zentrack/<run>``).

==========================  ===========================================================================
key                         what is published there
==========================  ===========================================================================
``<prefix>/truth``          true state per step, or the targets present (many targets); evaluators only: recorder, viewer
``<prefix>/meas/<i>``       node i's scan for step k (published by truth)
``<prefix>/prior/<i>``      node i's fusion message for step k+1, round l (named information pairs (P̄⁻¹, P̄⁻¹ψ))
``<prefix>/scan/<i>``       scans node i forwards to its neighbours (rules that fuse neighbours' measurements)
``<prefix>/est/<i>``        node i's posterior for step k with timings and message counters
``<prefix>/det/<i>``        sensor i's detections (its own clock and sequence numbers; sensors of their own)
``<prefix>/tracks/<i>``     node i's track list for step k (id, status, mean, covariance per track)
``<prefix>/alive/<i>``      liveliness token of node i (``alive/truth`` for the truth process, ``alive/sensor-<s>``
                            for sensor s's: a name, never taken for a node id)
``<prefix>/ctl/start``      run parameters (mode, Ts, steps) announced by truth
``<prefix>/ctl/stop``       end of run
==========================  ===========================================================================
"""
from __future__ import annotations

import re
from dataclasses import dataclass

#: the roles that read a channel besides the evaluators (recorder and viewer read everything): ``truth``,
#: ``node`` (every node's key), ``own node`` (node i reads only its own) or ``taking node`` (a sensor's key: read
#: by the trackers that take that sensor, ``[sensor_timing]`` ``takes``)
READERS = ("truth", "node", "own node", "taking node")


@dataclass(frozen=True)
class Channel:
    """One data key of a run, ``<prefix>/<name>`` or, ``per_node``, ``<prefix>/<name>/<i>``: who publishes on it
    (``truth``; ``node``: node i on its own key only; ``sensor``: sensor s on ``<name>/<s>`` only) and who reads it (:data:`READERS`). The router's access
    control of a secure run is made from these (``zentrack/transport/secure.py``)."""

    name: str
    per_node: bool
    publisher: str
    readers: tuple[str, ...] = ()


#: every data channel of a run (the control keys ``ctl/*`` and the liveliness tokens ``alive/*`` are the run's own)
CHANNELS: dict[str, Channel] = {c.name: c for c in (
    Channel("meas", True, "truth", ("own node",)),
    Channel("prior", True, "node", ("node",)),
    Channel("est", True, "node", ("truth",)),
    Channel("scan", True, "node", ("node",)),
    Channel("tracks", True, "node", ("node", "truth")),
    Channel("truth", False, "truth"),
    Channel("det", True, "sensor", ("taking node",)),
)}

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

    def of(self, channel: str, node: int | str | None = None) -> str:
        """The key of ``channel`` (:data:`CHANNELS`), node ``node``'s for a per-node one (``*`` for all of them)."""
        if CHANNELS[channel].per_node != (node is not None):
            raise ValueError(f"channel {channel!r} is {'' if CHANNELS[channel].per_node else 'not '}one key per node")
        return f"{self.prefix}/{channel}" if node is None else f"{self.prefix}/{channel}/{node}"

    @property
    def truth(self) -> str:
        return self.of("truth")

    def meas(self, node: int | str) -> str:
        return self.of("meas", node)

    def prior(self, node: int | str) -> str:
        return self.of("prior", node)

    def scan(self, node: int | str) -> str:
        return self.of("scan", node)

    def det(self, sensor: int | str) -> str:
        return self.of("det", sensor)

    def est(self, node: int | str) -> str:
        return self.of("est", node)

    def tracks(self, node: int | str) -> str:
        return self.of("tracks", node)

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


def sensor_name(sensor: int) -> str:
    """Sensor ``sensor``'s process name and liveliness token, ``sensor-<s>`` (``alive/sensor-<s>``: not a node id,
    so the truth, the trackers and ``zentrack status`` never count it as a tracker)."""
    return f"sensor-{int(sensor)}"


def sensor_id(name: str) -> int | None:
    """The sensor a process name ``sensor-<s>`` (:func:`sensor_name`) names, else None."""
    digits = name[7:] if name.startswith("sensor-") else ""
    return int(digits) if 0 < len(digits) <= 4 and digits.isascii() and digits.isdigit() else None


def node_id(name: str) -> int | None:
    """``name`` as a node id if it is one (1 to 4 ASCII digits), else None."""
    return int(name) if 0 < len(name) <= 4 and name.isascii() and name.isdigit() else None
