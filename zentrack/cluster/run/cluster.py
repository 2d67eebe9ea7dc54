"""One run's processes: :class:`Cluster` starts truth, N trackers (and optionally a router and the viewer) as
separate processes, records their estimates in this process and stops them all.

It is the programmatic handle ``zentrack run`` (:mod:`zentrack.cluster.run.orchestrator`), the tests and the
benchmarks use: ``start()``, ``kill(i)``, ``restart(i)``, ``wait()``, ``stop()``. Every child gets its own
session (``start_new_session``) and log file under ``<out>/logs``; ``stop()`` (also run on Ctrl-C, errors and
exit) sends SIGTERM, then SIGKILL after a grace period, so no process outlives the cluster.

A scenario with sensors of their own (``[sensor_timing]``) also gets one ``zentrack sensor --id S`` per sensor
(``sensor-<S>`` in :attr:`Cluster.procs`), started before the truth by the cluster's
:class:`~zentrack.cluster.run.sensors.SensorProcesses`; ``kill("sensor-2")`` and ``restart("sensor-2")`` act on
one of them, and ``jump_sensor_clock("sensor-2")`` steps its clock back.
"""
from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import zenoh

from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.cluster.recording.track_lists import TrackLists
from zentrack.cluster.run.out_lock import claim_out, release_out
from zentrack.cluster.run.process_args import filter_args, fusion_args, scenario_args, zenoh_args
from zentrack.cluster.run.results import read_node_reports, write_results
from zentrack.cluster.run.sensors import SensorProcesses
from zentrack.common.atomic import EXIT_WRITE_FAILED
from zentrack.common.ports import free_port
from zentrack.common.procs import die_with_parent, freeze_heap, signal_group
from zentrack.common.progress import Progress
from zentrack.common.run_summary import trackers_stopped
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_file import save_scenario
from zentrack.transport.keys import Keys
from zentrack.transport.router import access_flags
from zentrack.transport.secure import Identity
from zentrack.transport.zsession import build_config, open_retrying, open_zenoh
from zentrack.truth.simulation.multitarget import MultiTargetData
from zentrack.truth.simulation.scenario import ScenarioData

log = logging.getLogger("zentrack.run")


def zentrack_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "zentrack", *args]


#: the least Zenoh lease (ms) of a lockstep run's nodes (see :meth:`Cluster.start_node_args`)
LOCKSTEP_LEASE_MS = 10_000

#: the environment a tracker under a ``node_prefix`` gets besides this process's (whose own values win): keep a
#: ``faketime`` prefix's monotonic clock real, as on a host whose wall clock is off. With libfaketime 0.9.10's
#: defaults (``faketime -f +0.3s`` as such) a Python timed wait never returns, so the tracker woke only when a
#: message came and counted a fusion overrun at nearly every step (issue 52); with only the first variable every
#: handover of the GIL takes about a millisecond (docs/networks.md, "Clocks")
PREFIX_ENV = {"FAKETIME_DONT_FAKE_MONOTONIC": "1", "FAKETIME_FORCE_MONOTONIC_FIX": "0"}



class RunFailed(RuntimeError):
    """The cluster cannot do its job any more (e.g. every tracker process has exited)."""


class Cluster:
    """One run: a scenario file, truth, trackers, an optional router, and the recorder in this process."""

    def __init__(self, setup: RunSetup, out: Path, run: str | None = None, router: bool = False,
                 node_args: list[str] | None = None, truth_args: list[str] | None = None, lease_ms: int = 1000,
                 viewer: list[str] | None = None, zenoh_config: str | None = None, secure: str | None = None,
                 node_prefix: dict[int, list[str]] | None = None, clock_jump_s: float | None = None,
                 external_sensors: set[int] | None = None) -> None:
        self.setup, self.out, self.router = setup, Path(out), router or secure is not None
        #: the sensors of their own (``clock_jump_s``: how far back a clock jump steps one; ``external_sensors``:
        #: those that publish from outside the run); late-bound, so that a test may stand in for _spawn
        self.sensors = SensorProcesses(setup, lambda name, args: self._spawn(name, args),
                                       lambda name, sig: self.signal_process(name, sig), self._sensor_args,
                                       clock_jump_s, external_sensors)
        #: node index -> a command its process runs under (e.g. ``faketime -f +0.3s``: a host clock that is off),
        #: with :data:`PREFIX_ENV` in its environment; a restarted node runs under it again
        self.node_prefix = node_prefix or {}
        self.secure = secure  # a `zentrack certs` folder: mutual TLS through a router with access control
        self.zenoh_config = zenoh_config  # a user's Zenoh file, merged over the safe defaults by every process
        self.run_name = run or f"r{os.getpid()}x{int(time.time() * 1000) % 100000}"
        self.keys = Keys(self.run_name)
        self.port = free_port()
        self.node_args, self.truth_args, self.lease_ms = node_args or [], truth_args or [], lease_ms
        self.procs: dict[str, subprocess.Popen] = {}
        self.spawn_args: dict[str, list[str]] = {}
        self.viewer = viewer  # None: no viewer; else extra viewer flags (the recording goes to <out>/recording.rrd)
        self.logs_dir = self.out / "logs"
        self.scenario_path = self.out / "scenario.npz"
        self.session: zenoh.Session | None = None
        self.recorder: Recorder | None = None
        self.out_lock: int | None = None  # <out>/.lock, held from claim_out() to stop()

    @property
    def scn(self) -> ScenarioData | MultiTargetData:
        return self.setup.run_data

    @property
    def multitarget(self) -> bool:
        return self.setup.multitarget is not None

    def _zenoh_args(self, role: str) -> list[str]:
        return zenoh_args(self.endpoint, self.router, self.secure, self.zenoh_config)

    @property
    def endpoint(self) -> str:
        """Where every process connects: the recorder's (or the router's) port; TLS in secure mode."""
        return f"{'tls' if self.secure else 'tcp'}/127.0.0.1:{self.port}"

    def _scenario_args(self) -> list[str]:
        return scenario_args(self.setup, self.scenario_path)

    def _filter_args(self) -> list[str]:
        return filter_args(self.setup, self.scenario_path, self.run_name)

    def _spawn(self, name: str, args: list[str]) -> subprocess.Popen:
        self.logs_dir.mkdir(parents=True, exist_ok=True)
        logf = open(self.logs_dir / f"{name}.log", "ab")
        prefix = self.node_prefix.get(int(name[5:]), []) if name.startswith("node-") else []
        env = {**PREFIX_ENV, **os.environ} if prefix else None  # (PREFIX_ENV: a faketime prefix's monotonic clock)
        proc = subprocess.Popen([*prefix, *zentrack_cmd(*args)], stdout=logf, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True, preexec_fn=die_with_parent, env=env)
        logf.close()
        self.procs[name] = proc
        self.spawn_args[name] = args
        return proc

    def claim_out(self) -> None:
        """Take the output folder for this run (:mod:`~zentrack.cluster.run.out_lock`): :class:`OutInUse` (one
        line naming the other run) when another live run writes there."""
        if self.out_lock is None:
            self.out_lock = claim_out(self.out, self.run_name)

    def start(self) -> None:
        """Claim the output folder, write the scenario, open the recorder (or start the router), then truth and
        the trackers."""
        self.claim_out()
        for old in (self.out / "config").glob("node-*.json"):  # an earlier run's slices in this folder: not this run's
            old.unlink()  # (start_node writes a slice once, so that a restarted node gets the one it started with)
        if not self.multitarget:
            save_scenario(self.scenario_path, self.setup.scenario)
        endpoint = self.endpoint
        file = ["--zenoh-config", self.zenoh_config] if self.zenoh_config else []
        if self.secure:
            timing = self.setup.sensor_timing  # sensors of their own: each publishes its det/<s>, read by its takers
            access = access_flags(self.run_name, self.scn.nodes, 0 if timing is None else timing.sensors,
                                  None if timing is None else timing.takes)
            self._spawn("router", ["router", "--listen", endpoint, "--secure", self.secure, *access, *file])
            conf = build_config("client", connect=[endpoint], file=self.zenoh_config,
                                secure=Identity(Path(self.secure), "recorder"))
            self.session = open_retrying(conf, 15.0)
        elif self.router:
            self._spawn("router", ["router", "--listen", endpoint, *file])
            self.session = open_retrying(build_config("client", connect=[endpoint], file=self.zenoh_config), 15.0)
        else:
            self.session = open_zenoh(build_config("peer", listen=[endpoint], file=self.zenoh_config), "the recorder")
        self.recorder = Recorder(self.session, self.keys, TrackLists.of(self.setup) if self.multitarget
                                 else Estimates.of(self.setup))
        freeze_heap()
        waits = ["--wait-for", "recorder"]
        if self.viewer is not None:
            self._spawn("viewer", ["viewer", *self._filter_args(), *fusion_args(self.setup), *self._zenoh_args("viewer"),
                                   "--save", str(self.out / "recording.rrd"), *self.viewer])
            waits += ["--wait-for", "viewer"]
        waits += self.sensors.start_all()  # sensors of their own: up before the start (the truth waits for them)
        self._spawn("truth", ["truth", *self._filter_args(), *self._zenoh_args("truth"), *waits, *self.truth_args])
        for i in range(self.scn.nodes):
            self.start_node(i)

    @property
    def sensor_ids(self) -> list[int]:
        """The sensors of their own this run starts a process for (none: the truth measures)."""
        return self.sensors.ids

    def _sensor_args(self) -> list[str]:
        """The flags every sensor process shares: the run's scenario, its lease and Zenoh."""
        return [*self._filter_args(), "--lease-ms", str(self.lease_ms), *self._zenoh_args("sensor")]

    def start_sensor(self, sensor: int) -> subprocess.Popen:
        """Start sensor ``sensor``'s process (``sensor-<S>``): :meth:`SensorProcesses.start`."""
        return self.sensors.start(sensor)

    def jump_sensor_clock(self, name: str) -> float:
        """Step the clock of sensor ``name`` back (:meth:`SensorProcesses.jump_clock`); how far back it is in all."""
        return self.sensors.jump_clock(name)

    def node_config_path(self, i: int) -> Path:
        return self.out / "config" / f"node-{i}.json"

    def start_node_args(self, i: int) -> list[str]:
        """The command line of node i: its own configuration slice (no truth, no other node's sensor).

        Realtime nodes keep the short lease (a stalled peer is noticed within ``lease_ms``). A lockstep run
        has no deadline to detect and cannot lose a message (a lost one stalls it until the truth's step
        timeout), so its nodes get at least :data:`LOCKSTEP_LEASE_MS`: a node starved of CPU for a second
        (every process of a lockstep run computes flat out) must not have its links closed under it."""
        lease = self.lease_ms if self.setup.mode == "realtime" else max(self.lease_ms, LOCKSTEP_LEASE_MS)
        return ["node", "--id", str(i), "--node-config", str(self.node_config_path(i)), "--run", self.run_name,
                "--out", str(self.out), "--lease-ms", str(lease), *self._zenoh_args("node"), *self.node_args]

    def start_node(self, i: int) -> subprocess.Popen:
        """Hand node i its slice of the run (written once, atomically) and start it."""
        path = self.node_config_path(i)
        if not path.exists():
            self.setup.node_config(i).save(path)
        return self._spawn(f"node-{i}", self.start_node_args(i))

    def kill(self, i: int | str, sig: int = signal.SIGKILL) -> None:
        """Signal node ``i`` (or the process named ``i``, e.g. ``sensor-2``); SIGKILL waits for it."""
        name = i if isinstance(i, str) else f"node-{i}"
        proc = self.procs.get(name)
        if proc and proc.poll() is None:
            self._signal(name, proc, sig)
            if sig == signal.SIGKILL:
                proc.wait(timeout=10)

    def _signal(self, name: str, proc: subprocess.Popen, sig: int) -> None:
        """``sig`` to a child; to its whole group when it runs under a prefix (``faketime`` forks the node)."""
        if name.startswith("node-") and int(name[5:]) in self.node_prefix:
            signal_group(proc, sig)
        else:
            proc.send_signal(sig)

    def restart(self, i: int | str) -> subprocess.Popen:
        """Kill node ``i`` (or the process named ``i``: ``sensor-<S>``, ...) and start it again."""
        if isinstance(i, str) and not i.startswith("node-"):
            return self.restart_process(i)
        node = i if isinstance(i, int) else int(i[5:])
        self.kill(node)
        return self.start_node(node)

    def signal_process(self, name: str, sig: int) -> None:
        """Send ``sig`` to one child (``truth``, ``router``, ``viewer``, ``node-<i>``); SIGKILL waits for it."""
        proc = self.procs.get(name)
        if proc and proc.poll() is None:
            self._signal(name, proc, sig)
            if sig == signal.SIGKILL:
                proc.wait(timeout=10)

    def restart_process(self, name: str) -> subprocess.Popen:
        """Kill one child (if still running) and start it again with the same arguments (a sensor: with its
        clock as far back as its steps took it)."""
        self.signal_process(name, signal.SIGKILL)
        if self.sensors.runs(name):
            return self.sensors.restart(name)
        return self._spawn(name, self.spawn_args[name])

    def pump(self, seconds: float) -> None:
        """Record estimates for ``seconds``."""
        recorder = self.recorder
        assert recorder is not None  # opened by start()
        end = time.time() + seconds
        while time.time() < end:
            recorder.drain(min(0.1, max(0.0, end - time.time())))

    def wait(self, timeout: float, progress: Progress | None = None) -> int:
        """Record until truth exits (or ``timeout``); then give the nodes a moment to stop. Returns truth's code.
        ``progress``: a line updated with the steps the run got through (drawn only on a terminal).
        :class:`RunFailed` when every tracker process has failed (exited non-zero) while the truth still runs
        (nothing left to track: the truth would only wait for its join timeout); trackers that finished their
        steps and exited 0 leave the truth to end the run."""
        recorder = self.recorder
        assert recorder is not None  # opened by start()
        end = time.time() + timeout
        truth = self.procs["truth"]
        trackers = {name: proc for name, proc in self.procs.items() if name.startswith("node")}
        while truth.poll() is None:
            if time.time() > end:
                raise TimeoutError(f"the run did not finish within {timeout:.0f} s")
            if trackers and all(proc.poll() not in (None, 0) for proc in trackers.values()):
                raise RunFailed(trackers_stopped({name: proc.returncode for name, proc in trackers.items()},
                                                 self.logs_dir.parent, self.logs_dir))
            recorder.drain(0.1)
            if progress is not None and progress.enabled and recorder.steps_reached() != progress.done:
                progress.update(recorder.steps_reached())
        settle = time.time() + 10.0
        # sensors of their own measure without the truth: a truth that failed mid-run leaves its trackers tracking
        # to the run's end (node/run_control.py), recorded while their estimates come
        orphaned = truth.returncode != 0 and self.setup.sensor_timing is not None
        while time.time() < settle and any(p.poll() is None for n, p in self.procs.items()
                                           if n.startswith(("node", "viewer", "sensor"))):
            if recorder.drain(0.1) and orphaned:
                settle = min(end, max(settle, time.time() + 10.0))
        recorder.drain(0.2)
        codes = {name: proc.poll() for name, proc in trackers.items()}
        if EXIT_WRITE_FAILED in codes.values():  # they ran, but their reports are lost: the run's output is not complete
            raise RunFailed(trackers_stopped(codes, self.logs_dir.parent, self.logs_dir))
        return truth.returncode

    def stop(self, grace: float = 5.0) -> None:
        """Terminate every child still running (SIGTERM, then SIGKILL) and close the recorder session."""
        for proc in self.procs.values():
            if proc.poll() is None:
                signal_group(proc, signal.SIGTERM)
        end = time.time() + grace
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(0.1, end - time.time()))
            except subprocess.TimeoutExpired:
                signal_group(proc, signal.SIGKILL)
                proc.wait(timeout=5)
        if self.recorder is not None and self.session is not None:
            self.recorder.close()
        if self.session is not None:
            self.session.close()
            self.session = None
        if self.out_lock is not None:
            release_out(self.out_lock)
            self.out_lock = None

    def node_reports(self) -> dict[int, dict]:
        """Each node's final counters (:func:`~zentrack.cluster.run.results.read_node_reports`)."""
        return read_node_reports(self.out, self.scn.nodes)

    @property
    def estimates_path(self) -> Path:
        """Where the recorded estimates go: ``estimates.npz`` (one target), ``tracks.npz`` (many)."""
        return self.out / ("tracks.npz" if self.multitarget else "estimates.npz")

    def write_results(self, interrupted: bool = False) -> dict:
        """The run's summary and estimates written (:func:`~zentrack.cluster.run.results.write_results`)."""
        recorder = self.recorder
        assert recorder is not None  # opened by start()
        run = {"name": self.run_name, "mode": self.setup.mode, "filter": self.setup.filter_kind,
               "fusion": self.setup.fusion, "fusion_params": self.setup.fusion_params, "scenario": self.scn.name,
               "source": self.setup.source, "ts": self.scn.ts, "period_s": self.setup.wall_period,
               "deadline_frac": self.setup.deadline_frac, "router": self.router}
        return write_results(recorder, self.node_reports(), run, self.out, self.estimates_path, interrupted)

    def __enter__(self) -> Cluster:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
