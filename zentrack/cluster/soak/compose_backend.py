"""The soak's compose backend: a compose cluster on a Docker engine, faults as Docker operations on its containers.

:class:`ComposeBackend` is the soak's third backend beside the loopback cluster and the namespace harness. It
writes the compose file of the run (``zentrack compose`` with an image built before, no build section), brings
it up under its own project name, records from the host through the router (a client session to the router
container's address on the project network) and maps the soak's faults onto the engine:

- kill / restart: ``docker kill -s KILL`` / ``docker start`` (the container keeps its name, network and volume);
- freeze / thaw and truth stall / resume: ``docker pause`` / ``docker unpause`` (the cgroup freezer);
- link cut / heal: ``docker network disconnect`` / ``docker network connect`` (with the service's alias).

``stop`` copies the viewer's recording out of the volume, saves every container's log and runs ``docker
compose down -v``; :meth:`ComposeBackend.leftovers` lists any container, network or volume of the project still
there afterwards.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import zenoh

from zentrack.cluster.deployment.compose import render
from zentrack.cluster.engines.docker import DockerError, docker
from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.cluster.soak.fault_kinds import SENSOR_VERBS_WHY_NOT, dispatch
from zentrack.config.run_setup import RunSetup
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import loopback_config, open_retrying

log = logging.getLogger("zentrack.docker")

#: how long a cached container state is trusted by :meth:`ComposeBackend.truth_running`
STATE_TTL_S = 0.5


class ContainerRun:
    """What the compose and the stack soak backends share: a recorder and a Zenoh session on the run, and the
    containers' state per service (``states()``, refreshed when ``_state_at`` is reset)."""

    recorder: Recorder | None
    session: zenoh.Session | None
    _state_at: float

    def states(self) -> dict[str, dict]:
        raise NotImplementedError

    def pids(self) -> dict[str, int]:
        return {s: v["pid"] for s, v in self.states().items() if v["running"] and v["pid"] > 0}

    def exit_codes(self) -> dict[str, int | None]:
        """Each service's (newest) container: None while it runs."""
        self._state_at = 0.0
        return {s: None if v["running"] else v["exit_code"] for s, v in self.states().items()}

    def close_observers(self) -> None:
        """Close the recorder and the Zenoh session (before the containers are stopped)."""
        if self.recorder is not None:
            self.recorder.close()
        if self.session is not None:
            self.session.close()
            self.session = None


class ComposeBackend(ContainerRun):
    """One soak run (faulty or reference) as a compose project of its own."""

    ENGINE = "compose"
    WHY_NOT = SENSOR_VERBS_WHY_NOT

    def __init__(self, setup: RunSetup, out: Path, tag: str, image: str, seed: int, scenario: str = "exp2",
                 zenoh_config: str | None = None) -> None:
        self.setup, self.out = setup, out
        self.project = f"ztsoak{tag}{int(time.time()) % 100000}"
        self.run = self.project
        self.file = out / "compose.yml"
        scn = setup.scenario
        self.file.write_text(render(scn.nodes, scenario, self.run, scn.steps, seed, image, context=None,
                                    zenoh_config=zenoh_config))
        self.network = f"{self.project}_default"
        self.ids: dict[str, str] = {}  # service -> container id
        self.session: zenoh.Session | None = None
        self.recorder: Recorder | None = None
        self._state: dict[str, dict] = {}
        self._state_at = 0.0

    def compose(self, *args: str, timeout: float = 300.0) -> str:
        return docker("compose", "-p", self.project, "-f", str(self.file), *args, timeout=timeout)

    def start(self) -> Recorder:
        self.compose("up", "-d", "--quiet-pull")
        for service in self.compose("config", "--services").split():
            self.ids[service] = self.compose("ps", "-a", "-q", service)
        address = docker("inspect", "-f", "{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}", self.ids["router"])
        self.session = open_retrying(loopback_config("client", connect=[f"tcp/{address}:7447"]), 60.0)
        self.recorder = Recorder(self.session, Keys(self.run), Estimates.of(self.setup))
        log.info("compose project %s up: %d containers, router at %s", self.project, len(self.ids), address)
        return self.recorder

    def act(self, action: str, target: int | str) -> None:
        """Apply one fault action with its verb (:func:`zentrack.cluster.soak.fault_kinds.dispatch`)."""
        dispatch(self, action, target)
        self._state_at = 0.0

    def kill(self, service: str) -> None:
        docker("kill", "-s", "KILL", self.ids[service])

    def restart(self, service: str) -> None:
        docker("start", self.ids[service])

    def freeze(self, service: str) -> None:
        docker("pause", self.ids[service])

    def thaw(self, service: str) -> None:
        docker("unpause", self.ids[service])

    def cut(self, service: str) -> None:
        docker("network", "disconnect", self.network, self.ids[service])

    def heal(self, service: str) -> None:
        docker("network", "connect", "--alias", service, self.network, self.ids[service])

    def states(self) -> dict[str, dict]:
        """service -> {running, pid, exit_code}, at most :data:`STATE_TTL_S` old."""
        if time.time() - self._state_at > STATE_TTL_S:
            by_id = {cid: s for s, cid in self.ids.items()}
            lines = docker("inspect", "-f", "{{.Id}} {{.State.Running}} {{.State.Pid}} {{.State.ExitCode}}",
                           *self.ids.values()).splitlines()
            state = {}
            for line in lines:
                cid, running, pid, code = line.split()
                service = next(s for c, s in by_id.items() if cid.startswith(c))
                state[service] = {"running": running == "true", "pid": int(pid), "exit_code": int(code)}
            self._state, self._state_at = state, time.time()
        return self._state

    def truth_running(self) -> bool:
        return self.states()["truth"]["running"]

    def stop(self) -> None:
        self.close_observers()
        if not self.ids:
            return
        try:
            viewer = self.ids.get("viewer")
            if viewer:
                try:
                    docker("wait", viewer, timeout=30)
                except DockerError:
                    docker("stop", viewer, timeout=60, check=False)
                docker("cp", f"{viewer}:/recordings/recording.rrd", str(self.out / "recording.rrd"), check=False)
            (self.out / "compose.log").write_text(self.compose("logs", "--no-color", "--timestamps"))
        finally:
            self.compose("down", "-v", "--remove-orphans", "--timeout", "10")

    def leftovers(self) -> list[str]:
        label = f"label=com.docker.compose.project={self.project}"
        found = []
        for kind in ("container", "network", "volume"):
            listing = docker(kind, "ls", "-a", "-q", "--filter", label) if kind == "container" else \
                docker(kind, "ls", "-q", "--filter", label)
            found += [f"{kind} {name}" for name in listing.split()]
        return found
