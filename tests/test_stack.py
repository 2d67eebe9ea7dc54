"""The Docker Swarm stack file (``zentrack compose --stack``): its structure, fast and without an engine.

The trackers are one replicated service whose task slot is the tracker id; every service has a health check,
a restart policy and resource limits; the tracker service rolls one task at a time, stop first, and rolls
back; secure mode mounts the certificates as swarm configs and secrets, never a bind mount. The real engine
runs the stack in ``tests/test_docker.py`` (deploy/docker-test.sh ``--variants ...,stack,stack-secure``).
"""
from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from zentrack.cluster.deployment.stack import render

ROOT = Path(__file__).resolve().parent.parent
SCHEMA = ROOT / "tests" / "data" / "compose-spec.json"
SCHEMA_SHA256 = "e82b395a9ac423febdba22c159b85d51d972706aea67d64799672a6ae3e56f47"


def test_checked_in_stack_files_are_the_generator_output():
    assert (ROOT / "deploy" / "docker-stack.yml").read_text() == render(10)
    assert (ROOT / "deploy" / "docker-stack.secure.yml").read_text() == render(
        10, secure=True, name="deploy/docker-stack.secure.yml")


def test_the_trackers_are_one_service_whose_task_slot_is_the_tracker_id():
    doc = yaml.safe_load(render(6, steps=50))
    services = doc["services"]
    assert set(services) == {"router", "truth", "node", "viewer", "recorder"}
    node = services["node"]
    assert node["environment"]["ZENTRACK_NODE_SLOT"] == "{{.Task.Slot}}"
    assert node["deploy"]["mode"] == "replicated" and node["deploy"]["replicas"] == "${ZENTRACK_NODES:-6}"
    shell, flag, line = node["command"]
    assert (shell, flag) == ("sh", "-c") and line.startswith("exec zentrack node --id $$((ZENTRACK_NODE_SLOT - 1)) ")
    # what the task's shell runs once `docker stack deploy` has replaced $$ by $ and the variable by its default
    deployed = line.replace("$$", "$").replace("${ZENTRACK_NODES:-6}", "6")
    for slot in (1, 6):
        argv = subprocess.run(["sh", "-c", deployed.replace("exec zentrack node", "printf '%s\\n'")],
                              env={"ZENTRACK_NODE_SLOT": str(slot), "PATH": "/usr/bin:/bin"},
                              capture_output=True, text=True, check=True).stdout.split()
        assert argv[:2] == ["--id", str(slot - 1)] and argv[argv.index("--nodes") + 1] == "6"
    health = node["healthcheck"]["test"]
    assert health[0] == "CMD-SHELL" and "ZENTRACK_NAME=$$((ZENTRACK_NODE_SLOT - 1))" in health[1]
    # every process is told the one tracker count
    for name in ("truth", "viewer", "recorder"):
        command = services[name]["command"]
        assert command[command.index("--nodes") + 1] == "${ZENTRACK_NODES:-6}", name


def test_router_hosts_put_a_router_on_each_host_linked_to_the_hub_and_each_tracker_on_its_own_hosts():
    services = yaml.safe_load(render(6, steps=50, router_hosts=["vm", "edge-2"]))["services"]
    assert set(services) == {"router", "router-vm", "router-edge-2", "truth", "node", "viewer", "recorder"}
    for host in ("vm", "edge-2"):
        router = services[f"router-{host}"]
        assert router["deploy"]["placement"]["constraints"] == [f"node.hostname == {host}"]
        command = router["command"]
        assert command[command.index("--connect") + 1] == "tcp/router:7447"  # linked to the hub
        assert router["deploy"]["restart_policy"]["condition"] == "any" and "healthcheck" in router
    for name in ("truth", "viewer", "recorder"):  # the services on the manager stay the hub's clients
        command = services[name]["command"]
        assert command[command.index("--connect") + 1] == "tcp/router:7447", name
    node = services["node"]
    # swarm spells the task's host name: its own host's router first, the hub when its host has none
    assert node["environment"]["ZENTRACK_CONNECT"] == "tcp/router-{{.Node.Hostname}}:7447,tcp/router:7447"
    line = node["command"][2].replace("$$", "$").replace("${ZENTRACK_NODES:-6}", "6")
    argv = subprocess.run(["sh", "-c", line.replace("exec zentrack node", "printf '%s\\n'")],
                          env={"ZENTRACK_NODE_SLOT": "2", "ZENTRACK_CONNECT": "tcp/router-vm:7447,tcp/router:7447",
                               "PATH": "/usr/bin:/bin"}, capture_output=True, text=True, check=True).stdout.split()
    assert argv[argv.index("--connect") + 1] == "tcp/router-vm:7447,tcp/router:7447"
    assert "router-vm" not in render(6, steps=50)  # without the flag: the one router
    text = render(3, secure=True, router_hosts=["vm"])  # secure: the host's router is a router of the run's too
    secure = yaml.safe_load(text)["services"]
    command = secure["router-vm"]["command"]
    assert command[command.index("--connect") + 1] == "tls/router:7447" and "--secure" in command
    assert {c["source"] for c in secure["router-vm"]["configs"]} == {"ca.pem", "router.pem", "monitor.pem"}
    assert {c["source"] for c in secure["router-vm"]["secrets"]} == {"router.key", "monitor.key"}
    assert secure["node"]["environment"]["ZENTRACK_CONNECT"] == "tls/router-{{.Node.Hostname}}:7447,tls/router:7447"
    assert "zentrack certs --out deploy/certs --nodes 3 --host router --host router-vm" in text  # its name in the certificate


def test_every_service_has_health_restart_policy_and_limits_and_trackers_roll_one_at_a_time():
    services = yaml.safe_load(render(4))["services"]
    for name, svc in services.items():
        assert svc["healthcheck"]["test"][1:3] == ["zentrack", "health"] or "zentrack health" in svc["healthcheck"]["test"][1], name
        deploy = svc["deploy"]
        assert deploy["restart_policy"]["condition"] in ("any", "on-failure"), name
        assert deploy["resources"]["limits"]["memory"] and deploy["resources"]["limits"]["cpus"], name
        assert deploy["resources"]["reservations"]["memory"], name
        assert "volumes" not in svc or svc["volumes"] == ["recordings:/recordings"], name
    assert services["node"]["deploy"]["restart_policy"]["condition"] == "any"
    assert services["router"]["deploy"]["restart_policy"]["condition"] == "any"
    update, rollback = services["node"]["deploy"]["update_config"], services["node"]["deploy"]["rollback_config"]
    # two tasks of one slot at once would be two trackers with one id
    assert update["order"] == rollback["order"] == "stop-first" and update["parallelism"] == 1
    assert update["failure_action"] == "rollback"
    assert services["node"]["deploy"]["placement"]["preferences"] == [{"spread": "node.labels.zentrack.zone"}]
    for name in ("router", "truth", "viewer", "recorder"):
        assert services[name]["deploy"]["placement"]["constraints"] == ["node.role == manager"], name
    assert "ports" not in services["router"]
    published = yaml.safe_load(render(4, publish_router=17447))["services"]["router"]["ports"]
    assert published == [{"target": 7447, "published": 17447, "protocol": "tcp", "mode": "host"}]


def test_secure_stack_mounts_certificates_as_configs_and_secrets_each_role_its_own_key():
    doc = yaml.safe_load(render(3, secure=True))
    services = doc["services"]
    assert doc["secrets"] == {f"{r}.key": {"file": f"./certs/{r}.key"}
                              for r in ("router", "truth", "viewer", "recorder", "monitor", "node-0", "node-1", "node-2")}
    assert "ca.key" not in json.dumps(doc)  # the CA's key signs; no service gets it
    assert doc["configs"]["ca.pem"] == {"file": "./certs/ca.pem"} and "node-2.pem" in doc["configs"]
    for name, svc in services.items():
        # its own role, and ``monitor`` for its health check (`zentrack health` reads liveliness as monitor)
        roles = [*([f"node-{i}" for i in range(3)] if name == "node" else [name]), "monitor"]
        assert [s["source"] for s in svc["secrets"]] == [f"{r}.key" for r in roles], name
        for s in svc["secrets"]:
            assert s["target"] == f"/certs/{s['source']}" and s["mode"] == 0o400 and s["uid"] == "10001", name
        assert {c["target"] for c in svc["configs"]} == {"/certs/ca.pem", *(f"/certs/{r}.pem" for r in roles)}, name
        assert not any("certs" in v for v in svc.get("volumes", [])), name  # no bind mount of the certificates
        assert svc["environment"]["ZENTRACK_SECURE"] == "/certs", name
        text = " ".join(svc["command"])
        assert "tcp/" not in text and "--secure /certs" in text, name


def test_stack_files_are_valid_compose_specification_documents():
    import jsonschema

    raw = SCHEMA.read_bytes()
    assert hashlib.sha256(raw).hexdigest() == SCHEMA_SHA256, "the vendored schema was modified"
    validator = jsonschema.Draft201909Validator(json.loads(raw))
    for n, text in ((10, render(10)), (10, render(10, secure=True)), (3, render(3, publish_router=7447, max_missing_frac=0.3)),
                    (4, render(4, router_hosts=["vm", "h2"])), (4, render(4, secure=True, router_hosts=["vm"]))):
        # `docker stack deploy` interpolates the tracker count (a string here) before it reads the file
        doc = yaml.safe_load(text.replace(f'replicas: "${{ZENTRACK_NODES:-{n}}}"', f'replicas: {n}'))
        assert [e.message for e in validator.iter_errors(doc)] == []
    broken = yaml.safe_load(render(3))
    broken["services"]["node"]["deploy"]["update_config"]["order"] = "both-at-once"
    assert list(validator.iter_errors(broken)), "the schema must reject a bad update order"


@pytest.mark.parametrize("args, message", [
    (["--stack", "--nodes", "0"], "--nodes"),
    (["--stack", "--publish-router", "70000"], "--publish-router"),
    (["--publish-router", "7447"], "--publish-router is a --stack option"),
    (["--stack", "--hosts", "2", "--nodes", "4"], "--hosts and --zenoh-config do not apply"),
    (["--stack", "--max-missing-frac", "2"], "--max-missing-frac must be from 0 to 1"),
    (["--stack", "--replicas", "3"], "unrecognized argument --replicas"),
    (["--stack", "--router-hosts", "vm.example.org"], "not a host name of one DNS label"),
    (["--stack", "--router-hosts", "vm,vm"], "a host is named twice"),
    (["--router-hosts", "vm"], "--router-hosts is a --stack option"),
])
def test_bad_stack_input_is_one_line_and_exit_status_2(args, message):
    done = subprocess.run([sys.executable, "-m", "zentrack", "compose", *args], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_the_stack_command_line_writes_the_file(tmp_path):
    out = tmp_path / "stack.yml"
    done = subprocess.run([sys.executable, "-m", "zentrack", "compose", "--stack", "--nodes", "4", "--steps", "60",
                           "--run", "zt1", "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert out.read_text() == render(4, run="zt1", steps=60, name=str(out))


@pytest.mark.slow  # the soak simulates its scenario before it checks the flags
def test_the_stack_soak_refuses_link_cuts_in_one_line(tmp_path):
    """A swarm task's overlay link is the orchestrator's: `--engine stack` with cuts is refused before anything runs."""
    done = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--engine", "stack", "--duration", "30",
                           "--nodes", "4", "--cut-every", "10", "--out", str(tmp_path / "soak")], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert "--engine stack has no link cut" in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr


def deployed_argv(line: str, program: str, env: dict[str, str], nodes: int = 6) -> list[str]:
    """The words ``program`` gets from a task's ``sh -c`` line once `docker stack deploy` has replaced $$ by $ and
    the tracker count by ``nodes``."""
    deployed = line.replace("$$", "$").replace("${ZENTRACK_NODES:-6}", str(nodes))
    assert f"exec zentrack {program} " in deployed, deployed
    return subprocess.run(["sh", "-c", deployed.replace(f"exec zentrack {program}", "printf '%s\\n'")],
                          env={**env, "PATH": "/usr/bin:/bin"}, capture_output=True, text=True,
                          check=True).stdout.split()


def test_a_scenario_with_sensors_of_their_own_gets_a_sensor_service_placed_like_the_trackers():
    """exp2-async: a replicated ``sensor`` service, one task per tracker, its slot the sensor id, spread and rolled
    like the trackers; the truth waits for sensor-0 .. sensor-<count - 1> of the count deployed; a synchronous
    scenario's stack is unchanged (the checked-in files above)."""
    doc = yaml.safe_load(render(6, "exp2-async", steps=50, seed=2))
    services = doc["services"]
    assert set(services) == {"router", "truth", "node", "sensor", "viewer", "recorder"}
    sensor, node = services["sensor"], services["node"]
    for key in ("replicas", "placement", "update_config", "rollback_config"):
        assert sensor["deploy"][key] == node["deploy"][key], key
    assert sensor["deploy"]["restart_policy"]["condition"] == "on-failure"  # done once it has published its run
    assert sensor["environment"] == {**{k: v for k, v in node["environment"].items() if k != "ZENTRACK_NODE_SLOT"},
                                     "ZENTRACK_SENSOR_SLOT": "{{.Task.Slot}}"}
    assert sensor["healthcheck"]["test"] == ["CMD-SHELL",
                                             "ZENTRACK_NAME=sensor-$$((ZENTRACK_SENSOR_SLOT - 1)) exec zentrack health"]
    tracker = deployed_argv(node["command"][2], "node", {"ZENTRACK_NODE_SLOT": "1"})
    for slot in (1, 6):
        argv = deployed_argv(sensor["command"][2], "sensor", {"ZENTRACK_SENSOR_SLOT": str(slot)})
        assert argv[:2] == ["--id", str(slot - 1)]
        # the tracker's scenario and Zenoh flags, word for word; a start timeout beyond the truth's wait
        assert argv[2:argv.index("--start-timeout")] == tracker[2:], argv
        assert float(argv[argv.index("--start-timeout") + 1]) > 600
    for nodes in (6, 3):  # the truth waits for the sensors of the count deployed (ZENTRACK_NODES)
        argv = deployed_argv(services["truth"]["command"][2], "truth", {}, nodes)
        assert [argv[i + 1] for i, w in enumerate(argv) if w == "--wait-for"] == [
            "viewer", "recorder", *(f"sensor-{s}" for s in range(nodes))], argv
        assert argv[argv.index("--nodes") + 1] == str(nodes) and argv[argv.index("--seed") + 1] == "2"
    # a router per host: a sensor is a client of its own host's router, as a tracker is
    hosts = yaml.safe_load(render(6, "exp2-async", router_hosts=["vm", "h2"]))["services"]
    assert hosts["sensor"]["environment"]["ZENTRACK_CONNECT"] == hosts["node"]["environment"]["ZENTRACK_CONNECT"]
    assert "--connect $$ZENTRACK_CONNECT" in hosts["sensor"]["command"][2]
    import jsonschema

    validator = jsonschema.Draft201909Validator(json.loads(SCHEMA.read_bytes()))
    doc = yaml.safe_load(render(6, "exp2-async").replace('replicas: "${ZENTRACK_NODES:-6}"', "replicas: 6"))
    assert [e.message for e in validator.iter_errors(doc)] == []
    assert "sensor" not in yaml.safe_load(render(6, "exp2"))["services"]
    # (in secure mode: tests/test_secure_sensors.py)
