"""Secure mode with sensors of their own (issue 52): a ``sensor-<s>`` certificate per sensor, and the router's access
control letting sensor s publish only ``det/<s>`` and its token, and tracker i read only the detections of the
sensors it takes (``[sensor_timing]`` ``takes``).

The router and its clients run in this process over mutual TLS on loopback, as in ``tests/test_secure.py``
(whose :class:`Net` and message helpers this reuses): a sensor's detections reach the trackers that take it and
the recorder; what it puts on another sensor's key, a tracker's or the truth's is dropped by the router.
"""
from __future__ import annotations

import queue

import pytest
from test_secure import RUN, Net, _routed, _until

from zentrack.cluster.deployment.certs import make_certificates, run_roles
from zentrack.transport.router import access_flags
from zentrack.transport.secure import access_control, default_takes, parse_takes, takes_text

#: tracker 2 takes sensors 0 and 2 (a sensor may feed several trackers); tracker 1 takes sensor 1 only
TAKES = ((0,), (1,), (0, 2))


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("certs")
    make_certificates(folder, nodes=3, sensors=3)
    return folder


def test_each_sensor_has_a_certificate_of_its_own_signed_by_the_runs_ca(certs):
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    for role in ("sensor-0", "sensor-1", "sensor-2"):
        cert = x509.load_pem_x509_certificate((certs / f"{role}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == role
        ca.public_key().verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))
    assert not (certs / "sensor-3.pem").exists()
    assert run_roles(2, 1)[-3:] == ["node-0", "node-1", "sensor-0"] and "sensor-0" not in run_roles(2)


def test_a_sensor_may_publish_its_own_detections_only_and_a_tracker_read_only_the_sensors_it_takes():
    acl = access_control("r", nodes=3, sensors=3, takes=TAKES)
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["sensor-1/publish"]["key_exprs"] == ["zentrack/r/det/1"]
    assert rules["sensor-1/token"]["key_exprs"] == ["zentrack/r/alive/sensor-1"]
    assert rules["sensor-1/subscribe"]["key_exprs"] == ["zentrack/r/ctl/**"]
    publishing_det = {r["id"] for r in acl["rules"] if r["id"].endswith("/publish")
                      and any("/det/" in k for k in r["key_exprs"])}
    assert publishing_det == {"sensor-0/publish", "sensor-1/publish", "sensor-2/publish"}
    for i, taken in enumerate(TAKES):
        reads = [k for k in rules[f"node-{i}/subscribe"]["key_exprs"] if "/det/" in k]
        assert reads == [f"zentrack/r/det/{s}" for s in taken]
    # by default tracker i takes sensor i; no sensors: no tracker reads a detection
    default = {r["id"]: r for r in access_control("r", nodes=2, sensors=2)["rules"]}
    assert [k for k in default["node-1/subscribe"]["key_exprs"] if "/det/" in k] == ["zentrack/r/det/1"]
    assert "det" not in str(access_control("r", nodes=2)["rules"])
    with pytest.raises(ValueError, match="does not fit"):
        access_control("r", nodes=2, sensors=1, takes=((0,), (1,)))


def test_the_routers_takes_flag_spells_each_trackers_sensors():
    assert takes_text(TAKES) == "0/1/0,2" and parse_takes("0/1/0,2", 3, 3) == TAKES
    assert parse_takes("0//1", 3, 2) == ((0,), (), (1,))
    for bad, why in (("0/1", "gives 2 tracker"), ("0/1/3", "from 0 to 2"), ("0/1/1,1", "distinct"),
                     ("0/1/x", "sensor ids")):
        with pytest.raises(ValueError, match=why):
            parse_takes(bad, 3, 3)
    assert access_flags("r", 3, 3, TAKES) == ["--run", "r", "--nodes", "3", "--sensors", "3", "--takes", "0/1/0,2"]
    assert access_flags("r", 3, 3, default_takes(3, 3)) == ["--run", "r", "--nodes", "3", "--sensors", "3"]
    assert access_flags("r", 3) == ["--run", "r", "--nodes", "3"]


@pytest.fixture(params=["one router", "linked routers"])
def net(certs, request):
    n = Net(certs, linked=request.param == "linked routers", access=(RUN, 3, 3, TAKES))
    try:
        for role in ("sensor-0", "sensor-1", "node-0", "node-1", "node-2", "recorder"):
            n.client(role)
        yield n
    finally:
        n.close()


def test_the_router_drops_what_a_sensor_puts_on_any_key_but_its_own(net):
    at_node0, at_node2 = net.listen("node-0", "det/0"), net.listen("node-2", "det/0")
    not_taken = net.listen("node-1", "det/0")  # tracker 1 does not take sensor 0
    wide = net.listen("node-1", "det/*")  # wider than tracker 1 may read: it gets sensor 1's only (det/1 below)
    other_sensor = net.listen("node-1", "det/1")
    priors = net.listen("node-1", "prior/*")
    at_recorder = net.listen("recorder", "**")
    s0, s1 = net.sessions["sensor-0"], net.sessions["sensor-1"]
    own = s0.declare_publisher(f"zentrack/{RUN}/det/0")  # as zentrack sensor publishes: a declared publisher
    net.entities.append(own)
    for q in (at_node0, at_node2, at_recorder):
        _routed(lambda: own.put(b"probe"), q)
    theirs = s1.declare_publisher(f"zentrack/{RUN}/det/1")
    net.entities.append(theirs)
    _routed(lambda: theirs.put(b"probe"), other_sensor)  # sensor 1 reaches tracker 1
    own.put(b"real")
    forged = ["det/1", "det/2", "prior/0", "est/0", "scan/0", "tracks/0", "meas/0", "truth", "ctl/stop", "ctl/start"]
    for key in forged:  # put() returns: the router drops each silently
        s0.put(f"zentrack/{RUN}/{key}", b"forged")
    own.put(b"last")  # after sensor 0's forgeries: had the router let them through, they had arrived before it
    seen = _until(at_recorder, b"last")
    assert seen == [(f"zentrack/{RUN}/det/0", b"real"), (f"zentrack/{RUN}/det/0", b"last")], seen
    assert _until(at_node0, b"last") == _until(at_node2, b"last") == seen
    theirs.put(b"end")  # sensor 1's own, after sensor 0's forgeries were dropped
    assert _until(other_sensor, b"end") == [(f"zentrack/{RUN}/det/1", b"end")]
    assert not_taken.empty() and priors.empty()
    # ``wide`` gets sensor 1's message from the same arrival as ``other_sensor``, handed to each subscriber in turn
    # (draining it the moment other_sensor had "end" found it empty once in 2670 tests, run 57): wait for its marker
    assert {key for key, _ in _until(wide, b"end") + _drain(wide)} == {f"zentrack/{RUN}/det/1"}


def _drain(q: queue.Queue) -> list:
    out = []
    while not q.empty():
        out.append(q.get())
    return out


def test_a_sensor_cannot_show_another_sensors_or_a_trackers_liveliness_token(net):
    tokens: queue.Queue = queue.Queue()
    sub = net.sessions["recorder"].liveliness().declare_subscriber(
        f"zentrack/{RUN}/alive/*", lambda s: tokens.put(str(s.key_expr)), history=True)
    net.entities.append(sub)
    s0 = net.sessions["sensor-0"].liveliness()
    net.entities += [s0.declare_token(f"zentrack/{RUN}/alive/sensor-1"), s0.declare_token(f"zentrack/{RUN}/alive/0"),
                     s0.declare_token(f"zentrack/{RUN}/alive/sensor-0")]
    # the others' tokens (node-0 .. node-2 hold none here) were declared first: had they passed, they came first
    assert _until(tokens, f"zentrack/{RUN}/alive/sensor-0") == [f"zentrack/{RUN}/alive/sensor-0"]


def test_compose_and_stack_files_run_each_sensor_as_itself_and_tell_the_router_the_sensors(tmp_path):
    """``zentrack compose --secure`` and ``--stack --secure`` with exp2-async: the router's access control gets
    the sensors (and the trackers' takes when the scenario names them), each sensor its own certificate."""
    import yaml

    from zentrack.cluster.deployment import compose, stack

    text = compose.render(6, "exp2-async", secure=True)
    services = yaml.safe_load(text)["services"]
    assert services["router"]["command"][-6:] == ["--run", "compose", "--nodes", "6", "--sensors", "6"]
    for s in range(6):
        svc = services[f"sensor-{s}"]
        assert svc["command"][svc["command"].index("--secure"):][:2] == ["--secure", "/certs"]
        assert "./certs:/certs:ro" in svc["volumes"] and svc["environment"]["ZENTRACK_NAME"] == f"sensor-{s}"
    assert "zentrack certs --out deploy/certs --nodes 6 --sensors 6 --host router" in text
    assert "--sensors" not in compose.render(6, "exp2", secure=True)
    named = tmp_path / "takes.toml"  # tracker 0 also takes sensor 1
    source = (compose.resolve("exp2-async")[1]).replace("[sensor_timing]\n", "[sensor_timing]\ntakes = [[0, 1], [1], [2], [3], [4], [5]]\n")
    named.write_text(source)
    router = yaml.safe_load(compose.render(6, str(named), secure=True))["services"]["router"]["command"]
    assert router[router.index("--takes") + 1] == "0,1/1/2/3/4/5"
    doc = yaml.safe_load(stack.render(6, "exp2-async", secure=True))
    router = doc["services"]["router"]["command"]
    assert router[router.index("--sensors") + 1] == "${ZENTRACK_NODES:-6}" and "--takes" not in router
    sensor = doc["services"]["sensor"]
    assert [m["source"] for m in sensor["secrets"]] == [f"sensor-{s}.key" for s in range(6)] + ["monitor.key"]
    assert {f"sensor-{s}.key" for s in range(6)} <= set(doc["secrets"]) and "sensor-5.pem" in doc["configs"]
    assert "--nodes 6 --sensors 6 --host router" in stack.render(6, "exp2-async", secure=True)


@pytest.mark.slow
@pytest.mark.cpu_only  # (a Python start and the scenario's set-up, nothing real-time)
def test_run_refuses_a_certificate_folder_without_the_sensors_in_one_line(tmp_path):
    """``zentrack run --secure CERTS_DIR`` with exp2-async: each sensor needs its certificate, checked before
    anything starts (exit 2, one line naming the file and the command that makes it)."""
    import subprocess
    import sys

    make_certificates(tmp_path / "certs", nodes=6)
    out = subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario", "exp2-async", "--steps", "20",
                          "--secure", str(tmp_path / "certs"), "--out", str(tmp_path / "run")], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2 and "sensor-0.pem is missing" in out.stderr and "--sensors S" in out.stderr, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and not (tmp_path / "run").exists()
