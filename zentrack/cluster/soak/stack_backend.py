"""A Docker Swarm stack driven for the soak (``zentrack soak --engine stack``): faults go through the orchestrator.

:class:`StackBackend` is the soak's fourth backend. It writes the run's stack file (``zentrack compose --stack``
with the router's port published on this host), joins a single-node swarm when the engine is in none (``docker
swarm init`` on loopback; it leaves again at the end), deploys the stack, records from the host through the
published router port, and maps the soak's faults onto swarm:

- kill (tracker, truth or router): ``docker kill`` of the task's container. Swarm's restart policy starts a
  replacement in the same slot (a tracker: the same id, which warm-starts); the soak's ``restart`` is then
  swarm's own, so it does nothing but wait;
- freeze / thaw and truth stall / resume: ``docker pause`` / ``docker unpause`` of the task's container;
- drain / undrain (``--drain-every``, a swarm with workers: ``deploy/swarm-nodes.sh``): ``docker node update
  --availability drain`` of the worker holding the most trackers, none of them hit by another fault of the
  schedule near the drain (:meth:`StackBackend.plan_drains`, :func:`zentrack.cluster.engines.swarm.pick_drain`; with
  no such worker the drain is skipped and recorded as such),
  then ``active`` again; swarm restarts the drained node's trackers, same slots, on the other nodes. The soak
  records the drain once per tracker moved, so each is judged like a kill;
- link cuts are refused: a swarm task's overlay attachment is the orchestrator's (``docker network
  disconnect`` does not apply).

On a swarm of several nodes the stack has a router per node (``--router-hosts``), and the backend reaches each
task's container through its node's engine (:func:`zentrack.cluster.engines.swarm.engines`).

``stop`` copies the recording out of the volume, saves the services' logs, runs ``docker stack rm``, removes
the recordings volume and leaves the swarm it joined; :meth:`StackBackend.leftovers` lists what is left.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import zenoh

from zentrack.cluster.deployment.stack import render
from zentrack.cluster.engines.docker import DockerError, docker
from zentrack.cluster.engines.swarm import SwarmNode, engines, pick_drain, set_availability, swarm_nodes
from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.cluster.soak.compose_backend import ContainerRun
from zentrack.cluster.soak.fault_kinds import SENSOR_VERBS_WHY_NOT, dispatch
from zentrack.cluster.soak.faults import trackers_faulted_near
from zentrack.common.ports import free_port
from zentrack.config.run_setup import RunSetup
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import loopback_config, open_retrying

log = logging.getLogger("zentrack.stack")

STATE_TTL_S = 0.5  #: how long cached task states are trusted
START_TIMEOUT_S = 600.0  #: how long :meth:`StackBackend.start` waits for the run's first estimate
NAMESPACE = "com.docker.stack.namespace"


def swarm_state() -> str:
    return docker("info", "-f", "{{.Swarm.LocalNodeState}}", timeout=30)


class StackBackend(ContainerRun):
    """One soak run (faulty or reference) as a stack of its own on a (single-node) swarm."""

    ENGINE = "stack"
    #: the verbs it lacks, and why
    WHY_NOT = {"cut": "a swarm task's overlay link is the orchestrator's", **SENSOR_VERBS_WHY_NOT}

    def __init__(self, setup: RunSetup, out: Path, tag: str, image: str, seed: int, scenario: str = "exp2") -> None:
        self.setup, self.out = setup, out
        self.stack = f"ztsoak{tag}{int(time.time()) % 100000}"
        self.run = self.stack
        self.port = free_port()
        self.file = out / "stack.yml"
        scn = setup.scenario
        self.nodes: list[SwarmNode] = swarm_nodes() if swarm_state() == "active" else []
        self.engines: dict[str, str | None] = engines() if self.nodes else {"": None}
        hosts = [n.hostname for n in self.nodes] if len(self.nodes) > 1 else None
        # faults cost the killed trackers steps: the recorder's own verdict is the soak's, not its missing-steps check
        self.file.write_text(render(scn.nodes, scenario, self.run, scn.steps, seed, image, publish_router=self.port,
                                    max_missing_frac=1.0, name=str(self.file), router_hosts=hosts))
        self.drained: dict[str, tuple[SwarmNode, list[int]]] = {}  # target -> the node drained and its trackers
        self.drains: list[dict] = []  # each drain: node, trackers moved (or why it was skipped)
        self.drain_plan: list[set[int]] = []  # per drain to come, in order: the trackers it must not move
        self.joined = False
        self.session: zenoh.Session | None = None
        self.recorder: Recorder | None = None
        self._state: dict[str, dict] = {}
        self._state_at = 0.0
        self.deployed = False

    def start(self) -> Recorder:
        if swarm_state() != "active":
            docker("swarm", "init", "--advertise-addr", "127.0.0.1", "--listen-addr", "127.0.0.1:2377", timeout=120)
            self.joined = True
        docker("stack", "deploy", "--resolve-image", "never", "-c", str(self.file), self.stack, timeout=300)
        self.deployed = True
        self.session = open_retrying(loopback_config("client", connect=[f"tcp/127.0.0.1:{self.port}"]), 120.0)
        self.recorder = Recorder(self.session, Keys(self.run), Estimates.of(self.setup))
        log.info("stack %s deployed, router published on port %d", self.stack, self.port)
        end = time.time() + START_TIMEOUT_S  # the faults' clock starts with the run, however slowly swarm starts it
        while not self.recorder.have().any() and time.time() < end:
            self.recorder.drain(0.2)
        return self.recorder

    def containers(self) -> dict[str, list[dict]]:
        """service (``node-<i>`` for tracker slot i+1) -> its tasks' containers on every node's engine, newest
        first: ``{"id", "engine", "created"}``."""
        found: dict[str, list[dict]] = {}
        for engine in self.engines.values():
            lines = docker("ps", "-a", "--filter", f"label={NAMESPACE}={self.stack}", "--format",
                           "{{.ID}} {{.Names}} {{.CreatedAt}}", host=engine, check=False).splitlines()
            for line in lines:
                cid, name, created = line.split(maxsplit=2)
                service, slot = name[len(self.stack) + 1:].split(".")[:2]
                key = f"node-{int(slot) - 1}" if service == "node" else service
                found.setdefault(key, []).append({"id": cid, "engine": engine, "created": created})
        for tasks in found.values():
            tasks.sort(key=lambda c: c["created"], reverse=True)
        return found

    def states(self) -> dict[str, dict]:
        """service -> {running, pid, exit_code} of its newest container, at most :data:`STATE_TTL_S` old."""
        if time.time() - self._state_at > STATE_TTL_S:
            newest = {s: c[0] for s, c in self.containers().items()}
            state: dict[str, dict] = {}
            for engine in {c["engine"] for c in newest.values()}:
                by_id = {c["id"]: s for s, c in newest.items() if c["engine"] == engine}
                lines = docker("inspect", "-f", "{{.Id}} {{.State.Running}} {{.State.Pid}} {{.State.ExitCode}}",
                               *by_id, host=engine, check=False).splitlines()
                for line in lines:
                    cid, running, pid, code = line.split()
                    service = next(s for c, s in by_id.items() if cid.startswith(c))
                    state[service] = {"running": running == "true", "pid": int(pid), "exit_code": int(code), "id": cid,
                                      "engine": engine}
            self._state, self._state_at = state, time.time()
        return self._state

    def act(self, action: str, target: int | str) -> list[int] | None:
        """Apply one fault action with its verb (:func:`zentrack.cluster.soak.fault_kinds.dispatch`); a drain or
        undrain returns the trackers it concerns (else None)."""
        self._state_at = 0.0
        moved = dispatch(self, action, target)
        self._state_at = 0.0
        return moved

    def _task(self, service: str) -> tuple[str, str | None]:
        """The container id of a service's newest task, and the engine of the node it runs on."""
        task = self.states()[service]
        return task["id"], task["engine"]

    def kill(self, service: str) -> None:
        cid, engine = self._task(service)
        docker("kill", cid, host=engine)

    def restart(self, service: str) -> None:
        log.info("soak: swarm restarts %s itself (restart policy)", service)

    def freeze(self, service: str) -> None:
        cid, engine = self._task(service)
        docker("pause", cid, host=engine)

    def thaw(self, service: str) -> None:
        cid, engine = self._task(service)
        docker("unpause", cid, host=engine, check=False)  # swarm may have replaced a task paused too long

    def plan_drains(self, events: list[tuple[float, str, int | str]]) -> None:
        """Read the run's fault schedule: each drain moves no tracker that another fault hits from
        :data:`~zentrack.cluster.soak.faults.RECOVERY_S` before it to as long after its end."""
        drains = [t for t, action, _ in events if action == "drain"]
        ends = [t for t, action, _ in events if action == "undrain"]
        self.drain_plan = [trackers_faulted_near(events, a, b) for a, b in zip(drains, ends)]

    def drain(self, target: str) -> list[int]:
        """Drain the worker holding the most trackers, none of them near another fault (:meth:`plan_drains`); the
        trackers swarm moves (none: the drain skipped and recorded as such)."""
        nodes = swarm_nodes()
        avoid = self.drain_plan.pop(0) if self.drain_plan else set()
        node, trackers = pick_drain(self.stack, nodes, avoid=avoid)
        if node is None:
            if pick_drain(self.stack, nodes)[0] is None:
                raise ValueError("--drain-every: the swarm has no active worker to drain "
                                 "(bash deploy/swarm-nodes.sh up)")
            why = f"every active worker holds a tracker another fault hits near it ({sorted(avoid)})"
            self.drains.append({"node": None, "trackers": [], "skipped": why})
            log.warning("soak: drain skipped: %s", why)
            return []
        set_availability(node, "drain")
        self.drained[target] = (node, trackers)
        self.drains.append({"node": node.hostname, "trackers": trackers})
        log.info("soak: drained %s, trackers %s move", node.hostname, trackers)
        return trackers

    def undrain(self, target: str) -> list[int]:
        """Make the node ``target``'s drain took out active again; the trackers it had moved."""
        if target not in self.drained:  # the drain was skipped
            return []
        node, trackers = self.drained.pop(target)
        set_availability(node, "active")
        return trackers

    def truth_running(self) -> bool:
        return self.states().get("truth", {}).get("running", False)

    # exit_codes (ContainerRun): each service's newest task container, so a tracker replaced after a kill is
    # its replacement; trackers restart by policy even after the run

    def stop(self) -> None:
        self.close_observers()
        try:
            for target in list(self.drained):  # a drain the run's end cut short: the node is made active again
                self.undrain(target)
            if self.deployed:
                viewer = self.states().get("viewer")
                if viewer:
                    engine = viewer["engine"]
                    try:
                        docker("wait", viewer["id"], timeout=30, host=engine)
                    except DockerError:
                        docker("stop", viewer["id"], timeout=60, check=False, host=engine)
                    docker("cp", f"{viewer['id']}:/recordings/recording.rrd", str(self.out / "recording.rrd"),
                           check=False, host=engine)
                (self.out / "stack.log").write_text("\n".join(self._logs(s) for s in
                                                               ("router", "truth", "node", "viewer", "recorder")))
        finally:
            if self.deployed:
                docker("stack", "rm", self.stack, check=False)
                self._wait_removed()
                for engine in self.engines.values():  # stack rm keeps named volumes, on every node that made one
                    docker("volume", "rm", f"{self.stack}_recordings", check=False, host=engine)
            if self.joined:
                docker("swarm", "leave", "--force", check=False, timeout=120)

    def _logs(self, service: str) -> str:
        """The logs of every container of a service (``node``: every tracker's; ``router``: the hub's and every
        host's), each read from the engine of the node it ran on, headed by its service and container id
        (``docker service logs`` reads nothing of
        the workers' tasks once they are replaced, and can hang on them)."""
        parts = []
        for name, tasks in sorted(self.containers().items()):
            if name != service and not name.startswith(f"{service}-"):  # node-<i>; router-<host>
                continue
            for task in reversed(tasks):  # oldest first
                try:
                    text = docker("logs", "--timestamps", task["id"], host=task["engine"], check=False, timeout=30,
                                  stderr_too=True)
                except DockerError as err:
                    text = str(err)
                parts.append(f"==> {name} {task['id']} <==\n{text}")
        return "\n".join(parts)

    def _wait_removed(self, timeout: float = 120.0) -> None:
        end = time.time() + timeout
        while time.time() < end and self._of_stack(volumes=False):
            time.sleep(0.5)

    def _of_stack(self, volumes: bool = True) -> list[str]:
        """The stack's containers and networks (and volumes) still on any node's engine."""
        label = f"label={NAMESPACE}={self.stack}"
        found = []
        for engine in self.engines.values():
            where = f" on {engine}" if engine else ""
            found += [f"container {c}{where}" for c in docker("ps", "-a", "-q", "--filter", label, host=engine,
                                                              check=False).split()]
            found += [f"network {n}{where}" for n in docker("network", "ls", "-q", "--filter", label, host=engine,
                                                            check=False).split()]
            if volumes:
                found += [f"volume {v}{where}" for v in docker("volume", "ls", "-q", "--filter", f"name={self.stack}_",
                                                                host=engine, check=False).split()]
        return found

    def leftovers(self) -> list[str]:
        found = self._of_stack()
        found += [f"node {n.hostname} still drained" for n, _ in self.drained.values()]
        if self.joined and swarm_state() != "inactive":
            found.append("swarm membership (docker swarm leave --force)")
        return found
