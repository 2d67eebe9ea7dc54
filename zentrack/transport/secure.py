"""Secure mode: mutual TLS to one router that enforces Zenoh access control by certificate common name.

Every process of a secure run is a Zenoh *client* of the router (peers would link to each other and bypass
the router's access control) and proves who it is with its own certificate, signed by the run's CA
(``zentrack certs``). The router lets through only what each role may do (:func:`access_control`):

- ``truth`` publishes ``meas/**``, ``truth`` and ``ctl/**``, answers and asks ``ctl/start``, reads ``est/*`` and
  ``tracks/*`` (a lockstep run's barrier);
- ``node-<i>`` publishes only ``prior/<i>``, ``est/<i>``, ``scan/<i>``, ``tracks/<i>`` and its token
  ``alive/<i>``; it reads measurements, the neighbours' priors, scans and track lists and ``ctl/**``, never
  ``truth``;
- ``sensor-<s>`` (a sensor of its own, ``zentrack sensor``) publishes only ``det/<s>`` and its token
  ``alive/sensor-<s>``, reads ``ctl/**`` and asks ``ctl/start``; node i reads ``det/<s>`` of the sensors it takes
  only (``[sensor_timing]`` ``takes``, :data:`Takes`; by default sensor i), never another sensor's;
- ``recorder`` and ``viewer`` (the evaluators) read everything, ``truth`` included, and publish nothing but
  their own token; ``monitor`` (``zentrack status``/``health``) reads liveliness only;
- ``router``: another router of the run (a swarm host's, linked to the hub; ``docs/swarm.md``) passes the run's
  keys both ways: each message was checked by the router its sender is a client of.

Facts about Zenoh 1.x this relies on (pinned by ``tests/test_secure.py``): the router sees each message twice,
on the sender's link (ingress) and on the receiver's (egress), so receiving needs ``declare_subscriber``
ingress and ``put`` egress; a *declared publisher* also needs the subscriptions declared to it (egress
``declare_subscriber``), or it drops its own puts after the first; rule key expressions must *include* the
message's key expression (a subscription wider than allowed is refused whole); denied messages are dropped
silently (the sender's ``put`` returns; the router logs denials only at TRACE); a client without a
certificate the CA signed cannot open a session (``zenoh.open`` raises).
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import zenoh

from zentrack.transport.keys import CHANNELS

#: the roles a certificate directory holds besides one ``node-<i>`` per tracker and one ``sensor-<s>`` per sensor
#: of its own
SERVICE_ROLES = ("router", "truth", "recorder", "viewer", "monitor")
_ROLE = re.compile(r"^(router|truth|recorder|viewer|monitor|(node|sensor)-(0|[1-9][0-9]{0,3}))$")
#: which sensors each tracker takes, tracker i's at index i (``[sensor_timing]`` ``takes``)
Takes = tuple[tuple[int, ...], ...]


def check_role(role: str) -> str:
    if not _ROLE.match(role):
        raise ValueError(f"unknown secure-mode role {role!r}: one of {', '.join(SERVICE_ROLES)}, node-<i> or "
                         "sensor-<s>")
    return role


def default_takes(nodes: int, sensors: int) -> Takes:
    """Tracker i takes sensor i (the scenario's default), a tracker beyond the last sensor none."""
    return tuple((i,) if i < sensors else () for i in range(nodes))


def takes_text(takes: Takes) -> str:
    """``takes`` as the router's ``--takes`` spells it: one group per tracker, ``/`` between them, the sensor ids
    of one ``,``-separated (``0,1/1/2``: tracker 0 takes sensors 0 and 1, tracker 1 sensor 1, tracker 2 sensor 2)."""
    return "/".join(",".join(map(str, row)) for row in takes)


def parse_takes(text: str, nodes: int, sensors: int) -> Takes:
    """:func:`takes_text`'s spelling back, checked against ``nodes`` trackers and ``sensors`` sensors
    (ValueError, one line)."""
    rows = text.split("/")
    if len(rows) != nodes:
        raise ValueError(f"--takes {text!r} gives {len(rows)} tracker(s), the run has {nodes} (one group per tracker, "
                         "'/' between them)")
    out = []
    for i, row in enumerate(rows):
        ids = [p for p in row.split(",") if p] if row else []
        if not all(p.isascii() and p.isdigit() and int(p) < sensors for p in ids) or len(set(ids)) != len(ids):
            raise ValueError(f"--takes {text!r}: tracker {i}'s group {row!r} must be distinct sensor ids from 0 to "
                             f"{sensors - 1}, ','-separated")
        out.append(tuple(int(p) for p in ids))
    return tuple(out)


@dataclass(frozen=True)
class Identity:
    """One process's certificate, key and the run's CA in a ``zentrack certs`` directory."""

    folder: Path
    role: str

    @property
    def ca(self) -> Path:
        return self.folder / "ca.pem"

    @property
    def cert(self) -> Path:
        return self.folder / f"{self.role}.pem"

    @property
    def key(self) -> Path:
        return self.folder / f"{self.role}.key"

    def check(self) -> Identity:
        """Raise ValueError naming the first missing file (made by ``zentrack certs --out DIR``)."""
        check_role(self.role)
        for path in (self.ca, self.cert, self.key):
            if not path.is_file():
                sensors = " --sensors S" if self.role.startswith("sensor-") else ""
                raise ValueError(f"--secure {self.folder}: {path.name} is missing (make the certificates with "
                                 f"`zentrack certs --out {self.folder} --nodes N{sensors}`)")
        return self


def apply_tls(conf: zenoh.Config, identity: Identity, listen: bool) -> None:
    """Mutual TLS with ``identity``: only ``tls/`` links, the run's CA, the role's certificate and key (as the
    listening side for the router, as the connecting side for everyone else), no scouting of any kind."""
    identity.check()
    tls = {"root_ca_certificate": str(identity.ca.resolve()), "enable_mtls": True, "verify_name_on_connect": True}
    for side in ("listen", "connect") if listen else ("connect",):  # a router may link to another router too
        tls[f"{side}_private_key"] = str(identity.key.resolve())
        tls[f"{side}_certificate"] = str(identity.cert.resolve())
    conf.insert_json5("transport/link/tls", json.dumps(tls))
    conf.insert_json5("transport/link/protocols", json.dumps(["tls"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")


def access_control(run: str, nodes: int, sensors: int = 0, takes: Takes | None = None) -> dict:
    """The router's access control for run ``run`` with trackers ``0..nodes-1`` and sensors of their own
    ``0..sensors-1``, tracker i taking sensors ``takes[i]`` (None: :func:`default_takes`): default deny, one policy
    per role (module docstring), the data keys' from the channels' publishers and readers
    (:data:`~zentrack.transport.keys.CHANNELS`)."""
    takes = default_takes(nodes, sensors) if takes is None else takes
    if len(takes) != nodes or any(not 0 <= s < sensors for row in takes for s in row):
        raise ValueError(f"takes {takes_text(takes)!r} does not fit {nodes} tracker(s) and {sensors} sensor(s)")
    p = f"zentrack/{run}"
    rules: list[dict] = []
    subjects: list[dict] = []
    policies: list[dict] = []

    def role(cn: str, publish=(), subscribe=(), token: str | None = None, watch_alive: bool = False,
             answer=(), ask=()) -> None:
        ids: list[str] = []

        def allow(what: str, messages: list[str], flow: str, keys) -> None:
            rules.append({"id": f"{cn}/{what}", "permission": "allow", "flows": [flow], "messages": messages,
                          "key_exprs": list(keys)})
            ids.append(f"{cn}/{what}")

        if publish:
            allow("publish", ["put", "delete"], "ingress", publish)
            # a declared publisher learns from the router which subscriptions exist and drops its own puts when
            # it is told of none: without this, every put after the first is dropped inside the sender
            allow("matching", ["declare_subscriber"], "egress", [f"{p}/**"])
        if subscribe:
            allow("subscribe", ["declare_subscriber"], "ingress", subscribe)
            allow("receive", ["put", "delete"], "egress", subscribe)
        if token:
            allow("token", ["liveliness_token"], "ingress", [token])
        if watch_alive:
            allow("watch", ["declare_liveliness_subscriber", "liveliness_query"], "ingress", [f"{p}/alive/**"])
            allow("tokens", ["liveliness_token"], "egress", [f"{p}/alive/**"])
        if answer:  # a queryable: declared and queried through the router, its replies go back
            allow("queryable", ["declare_queryable"], "ingress", answer)
            allow("queried", ["query"], "egress", answer)
            allow("reply", ["reply"], "ingress", answer)
        if ask:
            allow("query", ["query"], "ingress", ask)
            allow("replies", ["reply"], "egress", ask)
            allow("queryables", ["declare_queryable"], "egress", ask)
        subjects.append({"id": cn, "cert_common_names": [cn]})
        policies.append({"id": cn, "subjects": [cn], "rules": ids})

    start = f"{p}/ctl/start"
    truth_out = [c for c in CHANNELS.values() if c.publisher == "truth"]
    node_out = [c for c in CHANNELS.values() if c.publisher == "node"]
    role("truth", publish=[f"{p}/{c.name}" + ("/**" if c.per_node else "") for c in truth_out] + [f"{p}/ctl/**"],
         subscribe=[f"{p}/{c.name}/*" for c in CHANNELS.values() if "truth" in c.readers],
         token=f"{p}/alive/truth", watch_alive=True, answer=[start], ask=[start])
    for i in range(nodes):
        role(f"node-{i}", publish=[f"{p}/{c.name}/{i}" for c in node_out],
             subscribe=[f"{p}/{c.name}/{i}" for c in CHANNELS.values() if "own node" in c.readers]
             + [f"{p}/{c.name}/*" for c in CHANNELS.values() if "node" in c.readers]
             + [f"{p}/{c.name}/{s}" for c in CHANNELS.values() if "taking node" in c.readers for s in takes[i]]
             + [f"{p}/ctl/**"],
             token=f"{p}/alive/{i}", watch_alive=True, answer=[start], ask=[start])
    sensor_out = [c for c in CHANNELS.values() if c.publisher == "sensor"]
    for s in range(sensors):
        role(f"sensor-{s}", publish=[f"{p}/{c.name}/{s}" for c in sensor_out], subscribe=[f"{p}/ctl/**"],
             token=f"{p}/alive/sensor-{s}", ask=[start])
    for cn in ("recorder", "viewer"):
        role(cn, subscribe=[f"{p}/**"], token=f"{p}/alive/{cn}", watch_alive=True)
    role("monitor", watch_alive=True)
    # another router of the run (linked routers, one per host): it carries every role's traffic, each checked by
    # the access control of the router its sender is a client of, so the link passes everything of the run
    link = ["put", "delete", "declare_subscriber", "declare_queryable", "query", "reply", "liveliness_token",
            "declare_liveliness_subscriber", "liveliness_query"]
    rules.append({"id": "router/link", "permission": "allow", "flows": ["ingress", "egress"], "messages": link,
                  "key_exprs": [f"{p}/**"]})
    subjects.append({"id": "router", "cert_common_names": ["router"]})
    policies.append({"id": "router", "subjects": ["router"], "rules": ["router/link"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def apply_access_control(conf: zenoh.Config, run: str, nodes: int, sensors: int = 0,
                         takes: Takes | None = None) -> None:
    conf.insert_json5("access_control", json.dumps(access_control(run, nodes, sensors, takes)))
