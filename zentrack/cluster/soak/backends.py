"""Where a soak's cluster runs and how a fault reaches a process: ``LoopbackBackend`` (processes on this host,
faults as signals) and ``NetnsBackend`` (one network namespace per service, link cuts too); the compose engine's
backend is ``zentrack.cluster.soak.compose_backend.ComposeBackend``. Each starts a run and returns its recorder, applies a
fault action to a target, and reports the processes' pids and exit codes.

A fault action reaches a backend through its verbs, one method per verb (``kill``, ``restart``, ``freeze``,
``thaw``, ``cut``, ``heal``; on loopback, the sensors of their own's ``kill_sensor``, ``restart_sensor`` and
``jump_clock``: ``(service) -> None``): ``act`` looks the action's verb up in the fault registry
(:func:`zentrack.cluster.soak.fault_kinds.dispatch`). A backend has the verbs of the faults it can apply; the soak
refuses the others before it starts (``WHY_NOT`` says why a backend lacks a verb)."""
from __future__ import annotations

import shutil
import signal
import sys
from pathlib import Path

import zenoh

from zentrack.cluster.deployment.compose import render
from zentrack.cluster.engines.netns import SUBNET, Harness
from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.cluster.run.cluster import Cluster
from zentrack.cluster.soak.fault_kinds import SENSOR_VERBS_WHY_NOT, dispatch
from zentrack.config.run_setup import RunSetup
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import loopback_config, open_retrying


class SignalledRun:
    """What the loopback and the namespace backends share: processes that take signals, so that a kill is a
    SIGKILL, a freeze a SIGSTOP and a thaw a SIGCONT (``send``: how the backend signals a service), each applied
    through ``act``."""

    def act(self, action: str, target: int | str) -> list[int] | None:
        return dispatch(self, action, target)

    def send(self, service: str, sig: int) -> None:
        raise NotImplementedError

    def kill(self, service: str) -> None:
        self.send(service, signal.SIGKILL)

    def freeze(self, service: str) -> None:
        self.send(service, signal.SIGSTOP)

    def thaw(self, service: str) -> None:
        self.send(service, signal.SIGCONT)


class LoopbackBackend(SignalledRun):
    ENGINE = "loopback"
    #: the verbs it lacks, and why
    WHY_NOT = {"cut": "loopback processes have no link to cut"}

    def __init__(self, setup: RunSetup, out: Path, viewer: bool, router: bool = False, secure: str | None = None,
                 zenoh_config: str | None = None, clock_jump_s: float | None = None) -> None:
        self.cluster = Cluster(setup, out, viewer=[] if viewer else None, router=router, secure=secure,
                               zenoh_config=zenoh_config, clock_jump_s=clock_jump_s)

    def start(self) -> Recorder:
        self.cluster.start()
        assert self.cluster.recorder is not None  # start() opens it
        return self.cluster.recorder

    def send(self, service: str, sig: int) -> None:
        self.cluster.signal_process(service, sig)

    def restart(self, service: str) -> None:
        self.cluster.restart_process(service)

    def kill_sensor(self, service: str) -> None:
        """A sensor of its own (``sensor-<S>``) crashes: SIGKILL."""
        self.cluster.signal_process(service, signal.SIGKILL)

    def restart_sensor(self, service: str) -> None:
        """... and starts again: it finds the run under way and resumes at the current time (its clock as far back
        as its steps took it)."""
        self.cluster.restart_process(service)

    def jump_clock(self, service: str) -> None:
        """A sensor's clock steps back (``Cluster.jump_sensor_clock``: SIGUSR1) and stays back."""
        self.cluster.jump_sensor_clock(service)

    def node_reports(self) -> dict[int, dict]:
        """Each tracker's final report (``node-<i>.json``), once the run is over."""
        return self.cluster.node_reports()

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.cluster.procs.items() if p.poll() is None}

    def truth_running(self) -> bool:
        return self.cluster.procs["truth"].poll() is None

    def exit_codes(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.cluster.procs.items()}

    def stop(self) -> None:
        self.cluster.stop()


class NetnsBackend(SignalledRun):
    ENGINE = "netns"
    WHY_NOT = SENSOR_VERBS_WHY_NOT

    def __init__(self, setup: RunSetup, out: Path, viewer: bool, tag: str, scenario: str = "exp2", seed: int = 0,
                 zenoh_config: str | None = None) -> None:
        self.setup, self.out = setup, out
        self.harness = Harness(out / "netns", tag)
        self.compose = out / "compose.yml"
        self.compose.write_text(render(setup.scenario.nodes, scenario=scenario, steps=setup.scenario.steps, seed=seed,
                                       zenoh_config=beside(zenoh_config, out)))
        self.session: zenoh.Session | None = None

    def start(self) -> Recorder:
        self.harness.up(self.compose, str(Path(sys.executable).with_name("zentrack")))
        self.session = open_retrying(loopback_config("client", connect=[f"tcp/{SUBNET}.10:7447"]), 30.0)
        self.recorder = Recorder(self.session, Keys("compose"), Estimates.of(self.setup))
        return self.recorder

    def send(self, service: str, sig: int) -> None:
        self.harness.signal(service, sig)

    def restart(self, service: str) -> None:
        self.harness.restart(service)

    def cut(self, service: str) -> None:
        self.harness.set_link(service, False)

    def heal(self, service: str) -> None:
        self.harness.set_link(service, True)

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.harness.procs.items() if p.poll() is None}

    def truth_running(self) -> bool:
        return self.harness.procs["truth"].poll() is None

    def exit_codes(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.harness.procs.items()}

    def stop(self) -> None:
        if self.session is not None:
            self.recorder.close()
            self.session.close()
            self.session = None
        self.harness.down()
        rec = self.out / "netns" / "volumes" / "recordings" / "recording.rrd"
        if rec.exists():
            rec.replace(self.out / "recording.rrd")


def beside(zenoh_config: str | None, folder: Path) -> str | None:
    """Copy a user's Zenoh file next to a run's compose file; its name as the compose file refers to it."""
    if not zenoh_config:
        return None
    shutil.copyfile(zenoh_config, folder / "zenoh.json5")
    return "zenoh.json5"


def rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None
