"""Where a soak's cluster runs and how a fault reaches a process: ``LoopbackBackend`` (processes on this host,
faults as signals) and ``NetnsBackend`` (one network namespace per service, link cuts too); the compose engine's
backend is ``zentrack.cluster.soak.compose_backend.ComposeBackend``. Each starts a run and returns its recorder, applies a
fault action to a target, and reports the processes' pids and exit codes."""
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
from zentrack.cluster.soak.faults import service_name
from zentrack.config.run_setup import RunSetup
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import loopback_config, open_retrying


class LoopbackBackend:
    def __init__(self, setup: RunSetup, out: Path, viewer: bool, router: bool = False, secure: str | None = None,
                 zenoh_config: str | None = None) -> None:
        self.cluster = Cluster(setup, out, viewer=[] if viewer else None, router=router, secure=secure,
                               zenoh_config=zenoh_config)

    def start(self) -> Recorder:
        self.cluster.start()
        assert self.cluster.recorder is not None  # start() opens it
        return self.cluster.recorder

    def act(self, action: str, target: int | str) -> None:
        c, name = self.cluster, service_name(target)
        if action == "kill":
            c.signal_process(name, signal.SIGKILL)
        elif action == "restart":
            c.restart_process(name)
        elif action in ("freeze", "stall", "thaw", "resume"):
            c.signal_process(name, signal.SIGSTOP if action in ("freeze", "stall") else signal.SIGCONT)
        else:
            raise ValueError("link cuts need namespace mode")

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.cluster.procs.items() if p.poll() is None}

    def truth_running(self) -> bool:
        return self.cluster.procs["truth"].poll() is None

    def exit_codes(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.cluster.procs.items()}

    def stop(self) -> None:
        self.cluster.stop()


class NetnsBackend:
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
        self.recorder = Recorder(self.session, Keys("compose"), Estimates(self.setup.scenario))
        return self.recorder

    def act(self, action: str, target: int | str) -> None:
        service = service_name(target)
        if action == "kill":
            self.harness.signal(service, signal.SIGKILL)
        elif action == "restart":
            self.harness.restart(service)
        elif action in ("freeze", "stall", "thaw", "resume"):
            self.harness.signal(service, signal.SIGSTOP if action in ("freeze", "stall") else signal.SIGCONT)
        else:
            self.harness.set_link(service, action == "heal")

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
