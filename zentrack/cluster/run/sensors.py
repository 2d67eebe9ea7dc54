"""A run's sensors of their own (``[sensor_timing]``): the ``zentrack sensor`` processes a
:class:`~zentrack.cluster.run.cluster.Cluster` starts, restarts and steps the clocks of.

:class:`SensorProcesses` is the part of a cluster that knows about them; the cluster holds one and calls it. It
starts one ``zentrack sensor --id S`` per sensor of the scenario (``sensor-<S>`` in the cluster's processes, its
log ``logs/sensor-<S>.log``), before the truth, which waits for their liveliness tokens; those named
``external`` publish from outside the run (a third-party sensor on ``det/<S>``): no process is started for them
and the truth does not wait for them. :meth:`SensorProcesses.jump_clock` steps one sensor's clock back (SIGUSR1:
``clock_jump_s``, the sensor's default when None), and it stays back, also across a restart of that sensor (a
host's clock: :meth:`SensorProcesses.start` passes the steps on).

The processes themselves are the cluster's: the part spawns and signals them through the callables it is given.
"""
from __future__ import annotations

import signal
import subprocess
from collections.abc import Callable

from zentrack.config.run_setup import RunSetup
from zentrack.transport.keys import sensor_id, sensor_name
from zentrack.truth.sensor import CLOCK_JUMP_S


class SensorProcesses:
    """The sensor processes of one run (module docstring). ``spawn(name, args)`` starts a ``zentrack`` process
    named ``name``, ``signal_process(name, sig)`` signals one, ``run_args()`` gives the flags every sensor shares
    (the run's scenario, Zenoh and lease)."""

    def __init__(self, setup: RunSetup, spawn: Callable[[str, list[str]], subprocess.Popen],
                 signal_process: Callable[[str, int], None], run_args: Callable[[], list[str]],
                 clock_jump_s: float | None = None, external: set[int] | None = None) -> None:
        self.setup = setup
        self.spawn, self.signal_process, self.run_args = spawn, signal_process, run_args
        #: how far back :meth:`jump_clock` steps a sensor's clock (None: the sensor's default), and how far back
        #: each sensor's clock is in all (a restarted sensor keeps its host's steps)
        self.clock_jump_s = clock_jump_s
        self.clock_back: dict[int, float] = {}
        #: sensors that publish from outside the run: no process, and the truth does not wait for them
        self.external = set(external or ())

    @property
    def ids(self) -> list[int]:
        """The sensors of their own this run starts a process for (none: the truth measures)."""
        return [s for s in range(len(self.setup.sensor_streams())) if s not in self.external]

    def runs(self, name: str) -> bool:
        """Whether ``name`` is one of this run's sensor processes (``sensor-<S>``)."""
        sensor = sensor_id(name)
        return sensor is not None and sensor in self.ids

    def start_all(self) -> list[str]:
        """Start every sensor process; the truth's flags to wait for each (``--wait-for sensor-<S>``)."""
        waits: list[str] = []
        for sensor in self.ids:
            self.start(sensor)
            waits += ["--wait-for", sensor_name(sensor)]
        return waits

    def start(self, sensor: int) -> subprocess.Popen:
        """Start sensor ``sensor``'s process (``sensor-<S>``): the run's scenario, its id, the run's Zenoh, how far
        a SIGUSR1 steps its clock back and how far back its clock is already (restarted after a step)."""
        clock = [] if self.clock_jump_s is None else ["--clock-jump-s", repr(float(self.clock_jump_s))]
        if self.clock_back.get(sensor):
            clock += ["--clock-back-s", repr(self.clock_back[sensor])]
        return self.spawn(sensor_name(sensor), ["sensor", "--id", str(sensor), *self.run_args(), *clock])

    def restart(self, name: str) -> subprocess.Popen:
        """Start sensor process ``name`` again (the caller killed it), its clock as far back as its steps took it."""
        sensor = sensor_id(name)
        assert sensor is not None and self.runs(name), name
        return self.start(sensor)

    def jump_clock(self, name: str) -> float:
        """Step the clock of sensor ``name`` (``sensor-<S>``) back by :attr:`clock_jump_s` (the sensor's default
        when None): a SIGUSR1 to its process, which runs on, its stamps jumped. The step stays, also across a
        restart of the sensor (:meth:`start` passes it on). How far back it is in all."""
        sensor = sensor_id(name)
        if sensor is None or sensor not in self.ids:
            raise ValueError(f"{name!r} is no sensor of this run (its sensors: {', '.join(map(sensor_name, self.ids)) or 'none'})")
        self.clock_back[sensor] = self.clock_back.get(sensor, 0.0) + (
            CLOCK_JUMP_S if self.clock_jump_s is None else float(self.clock_jump_s))
        self.signal_process(name, signal.SIGUSR1)
        return self.clock_back[sensor]
