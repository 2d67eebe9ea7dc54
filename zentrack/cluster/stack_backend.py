"""A Docker Swarm stack driven for the soak (``zentrack soak --engine stack``): faults go through the orchestrator.

:class:`StackBackend` is the soak's fourth backend. It writes the run's stack file (``zentrack compose --stack``
with the router's port published on this host), joins a single-node swarm when the engine is in none (``docker
swarm init`` on loopback; it leaves again at the end), deploys the stack, records from the host through the
published router port, and maps the soak's faults onto swarm:

- kill (tracker, truth or router): ``docker kill`` of the task's container. Swarm's restart policy starts a
  replacement in the same slot (a tracker: the same id, which warm-starts); the soak's ``restart`` is then
  swarm's own, so it does nothing but wait;
- freeze / thaw and truth stall / resume: ``docker pause`` / ``docker unpause`` of the task's container;
- link cuts are refused: a swarm task's overlay attachment is the orchestrator's (``docker network
  disconnect`` does not apply), and a node drain on a one-node swarm stops every task (see docs/swarm.md).

``stop`` copies the recording out of the volume, saves the services' logs, runs ``docker stack rm``, removes
the recordings volume and leaves the swarm it joined; :meth:`StackBackend.leftovers` lists what is left.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import zenoh

from zentrack.cluster.docker import ContainerRun, DockerError, docker
from zentrack.cluster.orchestrator import free_port
from zentrack.cluster.recorder import Recorder
from zentrack.cluster.stack import render
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

    def __init__(self, setup: RunSetup, out: Path, tag: str, image: str, seed: int, scenario: str = "exp2") -> None:
        self.setup, self.out = setup, out
        self.stack = f"ztsoak{tag}{int(time.time()) % 100000}"
        self.run = self.stack
        self.port = free_port()
        self.file = out / "stack.yml"
        scn = setup.scenario
        # faults cost the killed trackers steps: the recorder's own verdict is the soak's, not its missing-steps check
        self.file.write_text(render(scn.nodes, scenario, self.run, scn.steps, seed, image,
                                    publish_router=self.port, max_missing_frac=1.0, name=str(self.file)))
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
        self.recorder = Recorder(self.session, Keys(self.run), self.setup.scenario)
        log.info("stack %s deployed, router published on port %d", self.stack, self.port)
        end = time.time() + START_TIMEOUT_S  # the faults' clock starts with the run, however slowly swarm starts it
        while not self.recorder.have().any() and time.time() < end:
            self.recorder.drain(0.2)
        return self.recorder

    def containers(self) -> dict[str, list[dict]]:
        """service (``node-<i>`` for tracker slot i+1) -> its tasks' containers, newest first."""
        lines = docker("ps", "-a", "--filter", f"label={NAMESPACE}={self.stack}", "--format",
                       "{{.ID}} {{.Names}} {{.CreatedAt}}").splitlines()
        found: dict[str, list[dict]] = {}
        for line in lines:  # docker ps lists newest first
            cid, name = line.split()[:2]
            service, slot = name[len(self.stack) + 1:].split(".")[:2]
            key = f"node-{int(slot) - 1}" if service == "node" else service
            found.setdefault(key, []).append({"id": cid})
        return found

    def states(self) -> dict[str, dict]:
        """service -> {running, pid, exit_code} of its newest container, at most :data:`STATE_TTL_S` old."""
        if time.time() - self._state_at > STATE_TTL_S:
            newest = {s: c[0]["id"] for s, c in self.containers().items()}
            state: dict[str, dict] = {}
            if newest:
                lines = docker("inspect", "-f", "{{.Id}} {{.State.Running}} {{.State.Pid}} {{.State.ExitCode}}",
                               *newest.values(), check=False).splitlines()
                by_id = {cid: s for s, cid in newest.items()}
                for line in lines:
                    cid, running, pid, code = line.split()
                    service = next(s for c, s in by_id.items() if cid.startswith(c))
                    state[service] = {"running": running == "true", "pid": int(pid), "exit_code": int(code), "id": cid}
            self._state, self._state_at = state, time.time()
        return self._state

    def act(self, action: str, target: int | str) -> None:
        service = f"node-{target}" if isinstance(target, int) else target
        self._state_at = 0.0
        if action == "restart":
            log.info("soak: swarm restarts %s itself (restart policy)", service)
            return
        if action == "cut" or action == "heal":
            raise ValueError("--engine stack has no link cut (a task's overlay link is swarm's); use --cut-every 0")
        cid = self.states()[service]["id"]
        if action == "kill":
            docker("kill", cid)
        elif action in ("freeze", "stall"):
            docker("pause", cid)
        elif action in ("thaw", "resume"):
            docker("unpause", cid, check=False)  # swarm may have replaced a task paused too long
        else:
            raise ValueError(f"unknown fault action {action!r}")
        self._state_at = 0.0

    def truth_running(self) -> bool:
        return self.states().get("truth", {}).get("running", False)

    # exit_codes (ContainerRun): each service's newest task container, so a tracker replaced after a kill is
    # its replacement; trackers restart by policy even after the run

    def stop(self) -> None:
        self.close_observers()
        try:
            if self.deployed:
                viewer = self.states().get("viewer")
                if viewer:
                    try:
                        docker("wait", viewer["id"], timeout=30)
                    except DockerError:
                        docker("stop", viewer["id"], timeout=60, check=False)
                    docker("cp", f"{viewer['id']}:/recordings/recording.rrd", str(self.out / "recording.rrd"), check=False)
                (self.out / "stack.log").write_text("\n".join(self._logs(s) for s in
                                                               ("router", "truth", "node", "viewer", "recorder")))
        finally:
            if self.deployed:
                docker("stack", "rm", self.stack, check=False)
                self._wait_removed()
                docker("volume", "rm", f"{self.stack}_recordings", check=False)
            if self.joined:
                docker("swarm", "leave", "--force", check=False, timeout=120)

    def _logs(self, service: str) -> str:
        """A service's logs; ``docker service logs`` can hang on a replaced task, so at most 30 s of trying."""
        try:
            return docker("service", "logs", "--timestamps", f"{self.stack}_{service}", check=False, timeout=30)
        except DockerError as err:
            return f"{service}: {err}"

    def _wait_removed(self, timeout: float = 120.0) -> None:
        end = time.time() + timeout
        while time.time() < end:
            if not docker("ps", "-a", "-q", "--filter", f"label={NAMESPACE}={self.stack}", check=False) and not \
                    docker("network", "ls", "-q", "--filter", f"label={NAMESPACE}={self.stack}", check=False):
                return
            time.sleep(0.5)

    def leftovers(self) -> list[str]:
        label = f"label={NAMESPACE}={self.stack}"
        found = [f"container {c}" for c in docker("ps", "-a", "-q", "--filter", label).split()]
        found += [f"network {n}" for n in docker("network", "ls", "-q", "--filter", label).split()]
        found += [f"volume {v}" for v in docker("volume", "ls", "-q", "--filter", f"name={self.stack}_").split()]
        if self.joined and swarm_state() != "inactive":
            found.append("swarm membership (docker swarm leave --force)")
        return found
