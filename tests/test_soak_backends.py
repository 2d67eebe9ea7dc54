"""How each soak backend reaches its processes (``zentrack.cluster.soak.backends``, ``compose_backend``,
``stack_backend``), without a cluster: every event of the schedule goes to the backend's verb for it, as the chain
of actions each ``act`` was before the fault registry did, and an event a backend has no verb for is one clear
error with nothing done. The namespace backend's chain ended in ``else: set_link(service, False)``, so any action
it did not know (a typo, a node drain) silently cut a tracker's link."""
from __future__ import annotations

import signal

import pytest

from zentrack.cluster.soak.backends import LoopbackBackend, NetnsBackend


class _Calls:
    """Stands for a namespace harness or a loopback cluster: every call of any of its methods, recorded as
    ``(method, *args)``."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def __getattr__(self, method: str):
        return lambda *args: self.calls.append((method, *args))


#: every event the schedule makes on a process, and what a signal-based backend does for it
SIGNALLED = [(("kill", 2), ("signal", "node-2", signal.SIGKILL)), (("restart", 2), ("restart", "node-2")),
             (("freeze", 1), ("signal", "node-1", signal.SIGSTOP)), (("thaw", 1), ("signal", "node-1", signal.SIGCONT)),
             (("stall", "truth"), ("signal", "truth", signal.SIGSTOP)), (("resume", "truth"), ("signal", "truth", signal.SIGCONT)),
             (("kill", "truth"), ("signal", "truth", signal.SIGKILL)), (("restart", "truth"), ("restart", "truth")),
             (("kill", "router"), ("signal", "router", signal.SIGKILL)), (("restart", "router"), ("restart", "router"))]


def _netns() -> NetnsBackend:
    backend = object.__new__(NetnsBackend)  # its fault verbs alone: no namespaces made
    backend.harness = _Calls()  # type: ignore[assignment]
    return backend


def test_the_namespace_backend_cuts_a_link_only_for_a_cut():
    """The old chain of actions cut the link of any action it did not know (``else: set_link(...)``): an
    unknown action, or a registered fault namespaces cannot apply (a node drain), silently cut a link."""
    backend = _netns()
    with pytest.raises(ValueError, match="unknown fault action 'explode' on node-3"):
        backend.act("explode", 3)
    with pytest.raises(ValueError, match="--drain-every: --engine netns has no node drain"):
        backend.act("drain", "swarm")
    assert backend.harness.calls == [], "nothing reached a process, no link was cut"
    for event, call in [*SIGNALLED, (("cut", 4), ("set_link", "node-4", False)), (("heal", 4), ("set_link", "node-4", True))]:
        assert backend.act(*event) is None
        assert backend.harness.calls[-1] == call, event
    assert len(backend.harness.calls) == len(SIGNALLED) + 2


def test_the_loopback_backend_signals_and_refuses_a_cut_naming_the_fault():
    backend = object.__new__(LoopbackBackend)
    backend.cluster = _Calls()  # type: ignore[assignment]
    for event, (method, *args) in SIGNALLED:  # the cluster's signal_process and restart_process
        assert backend.act(*event) is None and backend.cluster.calls[-1] == (f"{method}_process", *args), event
    with pytest.raises(ValueError) as refused:
        backend.act("cut", 1)
    assert str(refused.value) == ("--cut-every: --engine loopback has no link cut (LoopbackBackend has no 'cut' verb: "
                                  "loopback processes have no link to cut)")
    with pytest.raises(ValueError, match="unknown fault action 'fill'"):
        backend.act("fill", 1)
    assert len(backend.cluster.calls) == len(SIGNALLED)


def test_the_compose_backend_maps_each_fault_onto_the_engine(monkeypatch):
    from zentrack.cluster.soak import compose_backend

    calls: list[tuple] = []
    monkeypatch.setattr(compose_backend, "docker", lambda *a, **kw: calls.append(a) or "")
    backend = object.__new__(compose_backend.ComposeBackend)
    backend.ids, backend.network, backend._state_at = {"node-1": "c1", "truth": "ct", "router": "cr"}, "net", 9.0
    expected = [(("kill", 1), ("kill", "-s", "KILL", "c1")), (("restart", 1), ("start", "c1")),
                (("freeze", 1), ("pause", "c1")), (("thaw", 1), ("unpause", "c1")), (("stall", "truth"), ("pause", "ct")),
                (("resume", "truth"), ("unpause", "ct")), (("cut", 1), ("network", "disconnect", "net", "c1")),
                (("heal", 1), ("network", "connect", "--alias", "node-1", "net", "c1")),
                (("kill", "router"), ("kill", "-s", "KILL", "cr")), (("restart", "router"), ("start", "cr"))]
    for event, call in expected:
        assert backend.act(*event) is None and calls[-1] == call and backend._state_at == 0.0, event
        backend._state_at = 9.0
    with pytest.raises(ValueError, match="--engine compose has no node drain"):
        backend.act("drain", "swarm")
    assert len(calls) == len(expected)


def test_the_stack_backend_kills_and_pauses_tasks_leaves_restarts_to_swarm_and_refuses_cuts(monkeypatch):
    from zentrack.cluster.soak import stack_backend

    calls: list[tuple] = []
    monkeypatch.setattr(stack_backend, "docker", lambda *a, **kw: calls.append((*a, kw)) or "")
    backend = object.__new__(stack_backend.StackBackend)
    backend._state_at = 9.0
    tasks = {"node-2": {"id": "t2", "engine": "tcp://w1:2375"}, "truth": {"id": "tt", "engine": None}}
    backend.states = lambda: tasks  # type: ignore[method-assign]
    expected = [(("kill", 2), ("kill", "t2", {"host": "tcp://w1:2375"})), (("freeze", 2), ("pause", "t2", {"host": "tcp://w1:2375"})),
                (("thaw", 2), ("unpause", "t2", {"host": "tcp://w1:2375", "check": False})),
                (("stall", "truth"), ("pause", "tt", {"host": None})),
                (("resume", "truth"), ("unpause", "tt", {"host": None, "check": False})),
                (("kill", "truth"), ("kill", "tt", {"host": None}))]
    for event, call in expected:
        assert backend.act(*event) is None and calls[-1] == call and backend._state_at == 0.0, event
    assert backend.act("restart", 2) is None and backend.act("restart", "truth") is None  # swarm's own restart
    with pytest.raises(ValueError, match="--engine stack has no link cut"):
        backend.act("cut", 2)
    assert len(calls) == len(expected)


def test_the_loopback_backend_kills_restarts_and_steps_the_clock_of_a_sensor_and_others_refuse_it(monkeypatch):
    """Sensors of their own run on loopback only: its backend reaches a sensor's process through the cluster (a
    kill, a restart that keeps the sensor's clock steps, a clock step by SIGUSR1; nothing at a step's window's
    end: the clock stays back); the other engines refuse each sensor event with nothing done."""
    backend = object.__new__(LoopbackBackend)
    backend.cluster = _Calls()  # type: ignore[assignment]
    for event, call in [(("kill", "sensor-2"), ("signal_process", "sensor-2", signal.SIGKILL)),
                        (("restart", "sensor-2"), ("restart_process", "sensor-2")),
                        (("jump", "sensor-4"), ("jump_sensor_clock", "sensor-4"))]:
        assert backend.act(*event) is None and backend.cluster.calls[-1] == call, event
    assert backend.act("followed", "sensor-4") is None and len(backend.cluster.calls) == 3
    netns = _netns()
    for event in (("kill", "sensor-1"), ("restart", "sensor-1"), ("jump", "sensor-1")):
        with pytest.raises(ValueError, match="--engine netns has no sensor .*: sensors of their own run on loopback only"):
            netns.act(*event)
    assert netns.harness.calls == []
    from zentrack.cluster.soak import compose_backend

    calls: list[tuple] = []
    monkeypatch.setattr(compose_backend, "docker", lambda *a, **kw: calls.append(a) or "")
    compose = object.__new__(compose_backend.ComposeBackend)
    compose.ids, compose._state_at = {"node-1": "c1"}, 9.0
    with pytest.raises(ValueError, match="--engine compose has no sensor kill"):
        compose.act("kill", "sensor-1")
    assert calls == []
