"""Secure mode: certificates, the router's access control, and the Zenoh 1.x facts it relies on.

The integration tests open a router and clients in this process over mutual TLS on loopback and check what
gets through: they pin the behaviour of the Zenoh version in use (a denied put is dropped silently at the
router; a subscription on a key the role may not read gets nothing; a client without a certificate from the
run's CA cannot open a session).
"""
from __future__ import annotations

import json
import queue
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from zentrack.cluster.deployment.certs import make_certificates
from zentrack.common.ports import free_port
from zentrack.transport.secure import Identity, access_control
from zentrack.transport.zsession import build_config

RUN = "sec"


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("certs")
    make_certificates(folder, nodes=3)
    return folder


def test_every_role_has_a_key_and_a_certificate_named_by_its_common_name(certs):
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    for role in ("router", "truth", "recorder", "viewer", "monitor", "node-0", "node-1", "node-2"):
        cert = x509.load_pem_x509_certificate((certs / f"{role}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == role
        ca.public_key().verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))
        assert stat.S_IMODE((certs / f"{role}.key").stat().st_mode) == 0o600
    assert not (certs / "node-3.pem").exists()


def test_access_control_denies_by_default_and_gives_each_node_only_its_own_keys():
    acl = access_control("r", nodes=2)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["node-1/publish"]["key_exprs"] == ["zentrack/r/prior/1", "zentrack/r/est/1", "zentrack/r/scan/1",
                                                   "zentrack/r/tracks/1"]
    assert rules["node-1/token"]["key_exprs"] == ["zentrack/r/alive/1"]
    assert "zentrack/r/truth" not in json.dumps([r for r in acl["rules"] if r["id"].startswith("node-")])
    assert rules["truth/publish"]["key_exprs"] == ["zentrack/r/meas/**", "zentrack/r/truth", "zentrack/r/ctl/**"]
    assert not any(r["id"].startswith(("recorder/publish", "viewer/publish", "monitor/publish")) for r in acl["rules"])
    assert {s["cert_common_names"][0] for s in acl["subjects"]} == {"truth", "node-0", "node-1", "recorder", "viewer", "monitor",
                                                                    "router"}
    # a linked router's role passes the run's keys only (each sender was checked by its own router)
    assert rules["router/link"]["key_exprs"] == ["zentrack/r/**"] and rules["router/link"]["flows"] == ["ingress", "egress"]


def test_secure_configs_refuse_what_would_open_a_way_around_the_router(certs, tmp_path):
    me = Identity(certs, "node-0")
    with pytest.raises(ValueError, match="not tls"):
        build_config("client", connect=["tcp/127.0.0.1:7447"], secure=me)
    with pytest.raises(ValueError, match="listens nowhere"):
        build_config("peer", listen=["tls/127.0.0.1:0"], connect=["tls/127.0.0.1:7447"], secure=me)
    with pytest.raises(ValueError, match="access control"):
        build_config("router", listen=["tls/127.0.0.1:7447"], secure=Identity(certs, "router"))
    with pytest.raises(ValueError, match="node-7.pem is missing"):
        build_config("client", connect=["tls/127.0.0.1:7447"], secure=Identity(certs, "node-7"))
    loose = tmp_path / "loose.json5"  # a file cannot loosen secure mode
    loose.write_text('{ scouting: { multicast: { enabled: true }, gossip: { enabled: true } } }')
    conf = build_config("peer", connect=["tls/127.0.0.1:7447"], file=str(loose), secure=me)
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is False
    assert json.loads(conf.get_json("transport/link/protocols")) == ["tls"]
    assert json.loads(conf.get_json("listen/endpoints")) == []


class Net:
    """A secure router and named clients, all in this process."""

    def __init__(self, certs: Path, linked: bool = False, access: tuple = (RUN, 3)) -> None:
        self.certs, self.port = certs, free_port()
        self.endpoint = f"tls/127.0.0.1:{self.port}"
        self.router = zenoh.open(build_config("router", [self.endpoint], secure=Identity(certs, "router"),
                                              access=access))
        self.routers = [self.router]
        # linked: the trackers are clients of a second router (a host's), linked to the first (the hub's)
        self.node_endpoint = self.endpoint
        if linked:
            self.node_endpoint = f"tls/127.0.0.1:{free_port()}"
            self.routers.append(zenoh.open(build_config("router", [self.node_endpoint], [self.endpoint],
                                                        secure=Identity(certs, "router"), access=access)))
            hub = str(self.router.info.zid())  # the link up before the clients declare anything
            _wait(lambda: hub in {str(z) for z in self.routers[1].info.routers_zid()}, "the routers' link")
        self.sessions: dict[str, zenoh.Session] = {}
        self.entities: list = []

    def client(self, role: str) -> zenoh.Session:
        at = self.node_endpoint if role.startswith("node-") else self.endpoint
        conf = build_config("client", connect=[at], secure=Identity(self.certs, role))
        self.sessions[role] = zenoh.open(conf)
        return self.sessions[role]

    def listen(self, role: str, key: str) -> queue.Queue:
        got: queue.Queue = queue.Queue()
        sub = self.sessions[role].declare_subscriber(f"zentrack/{RUN}/{key}",
                                                     lambda s: got.put((str(s.key_expr), s.payload.to_bytes())))
        self.entities.append(sub)
        return got

    def close(self) -> None:
        for e in self.entities:
            e.undeclare()
        for s in self.sessions.values():
            s.close()
        for r in reversed(self.routers):
            r.close()


def _wait(condition, what: str, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"{what}: not within {timeout:.0f} s")
        time.sleep(0.02)


def _until(q: queue.Queue, *markers, timeout: float = 10.0) -> list:
    """Everything ``q`` receives until every one of ``markers`` (payloads, or liveliness keys) has come: each a
    message its sender put after the messages under test. One session's messages reach a subscriber in the
    order sent, so whatever that sender sent before its marker, and was let through, has arrived by then.
    Late probes are left out."""
    got, end = [], time.monotonic() + timeout
    waiting = set(markers)
    while waiting:
        try:
            item = q.get(timeout=max(0.0, end - time.monotonic()))
        except queue.Empty:
            raise AssertionError(f"markers {sorted(waiting)} did not arrive within {timeout:.0f} s; got {got}") from None
        if isinstance(item, tuple) and item[1] == b"probe":
            continue
        got.append(item)
        waiting.discard(item[1] if isinstance(item, tuple) else item)
    return got


def _routed(send, q: queue.Queue, timeout: float = 10.0) -> None:
    """Call ``send()`` (a put of b"probe") every 50 ms until ``q`` receives a probe: the subscription behind
    ``q`` is known to the router and the sender. Empties ``q``."""
    end = time.monotonic() + timeout
    while True:
        send()
        try:
            if q.get(timeout=0.05)[1] == b"probe":
                break
        except queue.Empty:
            if time.monotonic() > end:
                raise AssertionError(f"no probe through within {timeout:.0f} s") from None
    while not q.empty():  # (probes still in flight are left out by _until)
        q.get()


@pytest.fixture(params=["one router", "linked routers"])
def net(certs, request):
    n = Net(certs, linked=request.param == "linked routers")
    try:
        for role in ("truth", "node-0", "node-1", "recorder"):
            n.client(role)
        yield n
    finally:
        n.close()


def test_a_node_publishes_only_its_own_keys_and_never_reads_the_truth(net):
    to_node0 = net.listen("node-0", "prior/*")
    meas0 = net.listen("node-0", "meas/0")
    truth_at_node0 = net.listen("node-0", "truth")
    at_recorder = net.listen("recorder", "**")
    n1, truth = net.sessions["node-1"], net.sessions["truth"]
    own = n1.declare_publisher(f"zentrack/{RUN}/prior/1")  # as a node publishes: a declared publisher ...
    net.entities.append(own)
    _routed(lambda: own.put(b"probe"), to_node0)  # ... told of node-0's subscription (the recorder's too)
    _routed(lambda: truth.put(f"zentrack/{RUN}/meas/0", b"probe"), meas0)
    _routed(lambda: truth.put(f"zentrack/{RUN}/meas/0", b"probe"), at_recorder)
    n1.put(f"zentrack/{RUN}/prior/0", b"forged")  # put() returns: the router drops it silently
    for _ in range(3):  # the declared publisher's puts get through
        own.put(b"real")
    for key in ("truth", "meas/0", "est/0", "ctl/stop"):
        n1.put(f"zentrack/{RUN}/{key}", b"forged")
    own.put(b"last")  # after node-1's forgeries: they had arrived before it, had the router let them through
    truth.put(f"zentrack/{RUN}/meas/0", b"z")
    truth.put(f"zentrack/{RUN}/truth", b"x")
    truth.put(f"zentrack/{RUN}/meas/0", b"end")  # after the truth, on a key node-0 may read
    assert _until(to_node0, b"last") == [(f"zentrack/{RUN}/prior/1", b"real")] * 3 + [
        (f"zentrack/{RUN}/prior/1", b"last")]
    assert _until(meas0, b"end") == [(f"zentrack/{RUN}/meas/0", b"z"), (f"zentrack/{RUN}/meas/0", b"end")]
    assert truth_at_node0.empty()
    seen = _until(at_recorder, b"last", b"end")
    assert b"forged" not in {payload for _, payload in seen}
    assert {key for key, _ in seen} == {f"zentrack/{RUN}/prior/1", f"zentrack/{RUN}/meas/0", f"zentrack/{RUN}/truth"}
    assert sum(payload == b"real" for _, payload in seen) == 3


def test_a_node_cannot_show_another_nodes_liveliness_token(net):
    tokens: queue.Queue = queue.Queue()
    sub = net.sessions["recorder"].liveliness().declare_subscriber(
        f"zentrack/{RUN}/alive/*", lambda s: tokens.put(str(s.key_expr)), history=True)
    net.entities.append(sub)
    forged = net.sessions["node-1"].liveliness().declare_token(f"zentrack/{RUN}/alive/0")
    own = net.sessions["node-1"].liveliness().declare_token(f"zentrack/{RUN}/alive/1")
    net.entities += [forged, own]
    # declared after the forged one: had the router let that through, it had arrived first
    assert _until(tokens, f"zentrack/{RUN}/alive/1") == [f"zentrack/{RUN}/alive/1"]


def _open_plain(conf: zenoh.Config) -> zenoh.Session | None:
    conf.insert_json5("connect/exit_on_failure", "true")
    conf.insert_json5("connect/timeout_ms", "3000")
    try:
        return zenoh.open(conf)
    except zenoh.ZError:
        return None


@pytest.mark.slow
def test_without_a_certificate_from_the_runs_ca_there_is_no_session(net, certs, tmp_path):
    ca = str((certs / "ca.pem").resolve())
    bare = zenoh.Config()
    bare.insert_json5("mode", '"client"')
    bare.insert_json5("connect/endpoints", json.dumps([net.endpoint]))
    bare.insert_json5("transport/link/tls", json.dumps({"root_ca_certificate": ca}))
    assert _open_plain(bare) is None  # TLS without a client certificate
    other = tmp_path / "other"
    make_certificates(other, nodes=1)  # a certificate named node-0, but from another CA
    assert _open_plain(build_config("client", connect=[net.endpoint], secure=Identity(other, "node-0"))) is None
    plain = zenoh.Config()
    plain.insert_json5("mode", '"client"')
    plain.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{net.port}"]))
    assert _open_plain(plain) is None  # plain TCP to the TLS port


def _zentrack(*argv: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zentrack", *argv], capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_run_takes_secure_with_or_without_a_folder(tmp_path):
    """One spelling for every cluster command (issue 50): ``--secure CERTS_DIR`` uses that folder,
    ``--secure`` alone makes the run's certificates in <out>/certs (as the soak does)."""
    out = tmp_path / "made"
    made = _zentrack("run", "--scenario", "exp2", "--nodes", "2", "--steps", "20", "--timing", "lockstep",
                     "--secure", "--out", str(out))
    assert made.returncode == 0, made.stderr[-3000:]
    assert (out / "certs" / "ca.pem").is_file() and (out / "certs" / "node-1.key").is_file()
    assert "secure router" in made.stderr
    assert json.loads((out / "summary.json").read_text())["network"]["steps"] == 20
    given = _zentrack("run", "--scenario", "exp2", "--nodes", "2", "--steps", "20", "--timing", "lockstep",
                      "--secure", str(out / "certs"), "--out", str(tmp_path / "given"))
    assert given.returncode == 0, given.stderr[-3000:]
    assert "secure router" in given.stderr and not (tmp_path / "given" / "certs").exists()
    missing = _zentrack("run", "--scenario", "exp2", "--nodes", "3", "--steps", "20", "--timing", "lockstep",
                        "--secure", str(out / "certs"), "--out", str(tmp_path / "short"))
    assert missing.returncode == 2 and "node-2.pem is missing" in missing.stderr
    assert len(missing.stderr.strip().splitlines()) == 1 and not (tmp_path / "short").exists()
