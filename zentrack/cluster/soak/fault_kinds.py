"""The soak's fault registry: every kind of fault a soak can apply, each one :class:`Fault` entry in :data:`KINDS`.

An entry holds all that its kind needs: the events that start and undo it (``kill`` / ``restart``), the flag of
its period and that flag's help, what it hits (a tracker the schedule picks, a sensor of its own it picks, or a
service: ``truth``, ``router``, ``swarm``), how long each one lasts and where a service fault's series starts within its period,
its accuracy window's limits, its colour in ``error.png``, whether the process it hits exits, and the backend
verbs that inject and undo it. Everything else reads the registry: the flags (``soak.command.add_arguments``),
the schedule and ``--plan`` (``soak.faults``), the engine checks made before anything starts, the backends'
``act``, the criteria, the accuracy limits and the figure.

A new kind of fault is one entry here plus the verbs of the backends that can apply it (a method per verb,
``(service) -> None``; a drain returns the trackers it moved; a kind whose undo is only the end of its window, a
sensor's clock step that stays, has no undo verb). A backend without one of its verbs is refused
before the soak starts, in one line that names the fault and the backend (:func:`unsupported`); a backend is
never asked for a verb it lacks (:func:`dispatch`).
"""
from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol, cast

import numpy as np

from zentrack.node.detections import CLOCK_QUANTILE, CLOCK_WINDOW
from zentrack.transport.keys import sensor_id

#: an entry's ``target`` when the schedule picks the tracker it hits (the least busy one)
TRACKER = "tracker"
#: an entry's ``target`` when the schedule picks a sensor of its own (``[sensor_timing]``, issue 52) to hit, the
#: one whose trackers are least busy; the event's target is the sensor's process, ``sensor-<S>``
SENSOR = "sensor"

#: how long a drained swarm node stays out of service by default (``--drain-s``): longer than swarm takes to
#: start its trackers on the other nodes (4-9 s measured on a 2-core host running three engines, docs/swarm.md)
DRAIN_S = 15.0

#: how long one fault lasts: given the soak's flags, a function that draws each fault's length (s) in turn; a
#: sensor fault's is asked once per sensor it may hit, with that sensor's process name (its length may be the
#: sensor's: :func:`follow_length`), every other's once per fault, with None
Lengths = Callable[[argparse.Namespace], Callable[[str | None], float]]


def flag_length(dest: str, default: float | None = None) -> Lengths:
    """Every fault as long as a flag says (``--restart-after``, ``--fault-s``; ``default`` when the flags lack it)."""

    def lengths(args: argparse.Namespace) -> Callable[[str | None], float]:
        def length(target: str | None = None) -> float:
            return getattr(args, dest) if default is None else getattr(args, dest, default)

        return length

    return lengths


def seeded_length(low: float, high: float, salt: int) -> Lengths:
    """Each fault a seeded ``low``-``high`` s long (to 0.01 s), drawn from a generator of its kind's own (the
    soak's ``--seed`` plus ``salt``), so that its lengths do not move the other kinds' draws."""

    def lengths(args: argparse.Namespace) -> Callable[[str | None], float]:
        rng = np.random.default_rng(args.seed + salt)

        def length(target: str | None = None) -> float:
            return round(float(rng.uniform(low, high)), 2)

        return length

    return lengths


#: a tracker follows a sensor's clock that stepped back once this many of its detections came after the step:
#: the offset estimate (``node/detections.py``) is a low quantile of the last ``CLOCK_WINDOW`` samples, so it
#: moves to the stepped clock when no more than the quantile's rank of older samples is left (61 of 64). The
#: ones before it are refused as ``stale`` (a step of more than ``STALE_S``) or dropped ``too_old``
FOLLOW_DETECTIONS = CLOCK_WINDOW - int(CLOCK_QUANTILE * (CLOCK_WINDOW - 1))
#: added to a clock step's window beyond its sensor's :data:`FOLLOW_DETECTIONS` periods: the signal reaches the
#: sensor's loop within 0.2 s, a detection reaches the tracker within its latency (exp2-async: 0.3 s, a tenth a
#: period later still)
FOLLOW_MARGIN_S = 1.0


def sensor_rates(args: argparse.Namespace) -> dict[int, float]:
    """Each sensor of its own -> its rate (Hz), as the soak put them in its flags (``sensor_rates``); {} when the
    scenario has none."""
    return {int(s): float(r) for s, r in (getattr(args, "sensor_rates", None) or {}).items()}


def sensor_takers(args: argparse.Namespace) -> dict[int, list[int]]:
    """Each sensor of its own -> the trackers that take its detections (``sensor_takers`` in the soak's flags; by
    default tracker S takes sensor S); {} when the scenario has none."""
    return {int(s): [int(i) for i in t] for s, t in (getattr(args, "sensor_takers", None) or {}).items()}


def follow_length(args: argparse.Namespace) -> Callable[[str | None], float]:
    """A sensor's clock step lasts until its trackers follow it: :data:`FOLLOW_DETECTIONS` of its periods and
    :data:`FOLLOW_MARGIN_S` (a 10 Hz sensor 7.1 s, a 1 Hz one 62 s)."""
    rates = sensor_rates(args)

    def length(target: str | None = None) -> float:
        sensor = sensor_of(target) if target is not None else None
        if sensor is None or sensor not in rates:
            raise ValueError(f"a clock step's length is its sensor's: {target!r} is no sensor of this soak's scenario")
        return round(FOLLOW_DETECTIONS / rates[sensor] + FOLLOW_MARGIN_S, 2)

    return length


@dataclass(frozen=True)
class Fault:
    """One kind of fault (module docstring)."""

    #: the kind, as ``accuracy_per_fault`` judges it and names its limits (``kill``, ``truth-stall``, ...)
    name: str
    #: the events that start and undo it, as the schedule, the backends and ``report.json``'s faults name them
    action: str
    undo: str
    #: the flag of its period (``--kill-every``: 0 off) and its ``--help``; ``advanced``: ``--help-all`` only
    flag: str
    help: str
    #: what it hits: :data:`TRACKER` (one the schedule picks) or a service (``truth``, ``router``, ``swarm``)
    target: str
    #: how long each one lasts (:func:`flag_length`, :func:`seeded_length`)
    length: Lengths
    #: its window's limits: (the affected trackers' RMSE ratio to the reference, the network median's)
    limits: tuple[float, float]
    #: its colour in ``error.png``
    colour: str
    #: the backend methods that inject and undo it (:class:`Verb`); ``undo_verb`` empty: its undo is only the end
    #: of its window, nothing is done (a sensor's clock step stays: its trackers follow it)
    verb: str
    undo_verb: str
    #: in the messages that refuse it: ``--engine stack has no link cut``
    noun: str
    default_every: float = 0.0
    advanced: bool = False
    #: a service fault's series starts this long into its period: clear of the tracker faults, which start at
    #: multiples of their periods, and of each other
    phase_s: float = 0.0
    #: a service fault the soak records once per tracker it moved (a node drain), each judged like a tracker fault
    per_tracker: bool = False
    #: the process it hits exits (a kill): a tracker it hit may exit non-zero, a restart brings a new process,
    #: and a run whose truth it hit is not over until that restart
    exits: bool = False

    @property
    def dest(self) -> str:
        """The flag's attribute in the parsed arguments (``--kill-every`` -> ``kill_every``)."""
        return self.flag.lstrip("-").replace("-", "_")

    def hits(self, target: int | str) -> bool:
        """Whether an event's target (a tracker index, a sensor's process or a service) is one this kind hits."""
        if isinstance(target, int):
            return self.target == TRACKER or self.per_tracker
        if sensor_of(target) is not None:
            return self.target == SENSOR
        return self.target == target


def sensor_of(target: int | str | None) -> int | None:
    """The sensor an event's target is (``sensor-3`` -> 3), else None."""
    return sensor_id(target) if isinstance(target, str) else None


def blinds_all(target: int | str) -> bool:
    """Whether a fault on ``target`` hits every tracker at once (the truth, the router): not a tracker, not a
    sensor (whose trackers are the ones it hits)."""
    return not isinstance(target, int) and sensor_of(target) is None


def hit_trackers(window: Mapping, nodes: int) -> list[int]:
    """The trackers a fault hits (``window``: a fault event or window, with its ``node`` and, for a sensor, the
    ``trackers`` that take it): the tracker itself; a sensor's trackers (by default tracker S takes sensor S);
    every tracker for the truth or the router."""
    target = window["node"]
    if isinstance(target, int):
        return [target]
    sensor = sensor_of(target)
    if sensor is None:
        return list(range(nodes))
    takers = window.get("trackers")
    return sorted(int(i) for i in takers) if takers is not None else [sensor] if sensor < nodes else []


#: limits of a tracker fault's window: from a 60 s soak of patrol with every fault kind (docs/soak.md), a tracker
#: kill, freeze or cut cost the tracker hit 0.9-1.8x and the network 1.06-1.13x when no other fault overlapped;
#: the limits leave room above those and still fail a tracker that rejoins at 2.5x its error
TRACKER_LIMITS = (2.5, 1.25)

#: limits of a sensor fault's window (sensors of their own, issue 52): in soaks of exp2-async's six sensors (1, 4 and
#: 10 Hz) with sensor kills and clock steps (docs/soak.md), the tracker whose sensor was out cost 0.66-1.20x when
#: no other fault overlapped (it fuses its neighbours' estimates throughout) and the network 0.89-1.22x: a 10 Hz
#: sensor carries a third of the network's detections, and two thirds of the information is sqrt(1.5) = 1.22x the
#: error at the bound; beside another sensor's fault up to 1.54x and 1.44x. The limits leave room above those; a
#: tracker isolated by two neighbours' sensors out at once (both then warm) cost its network 2.09x, which still
#: fails the compounded 1.4^2
SENSOR_LIMITS = (2.0, 1.4)

#: the registry, in the order the schedule draws the kinds (the trackers a seed picks depend on it) and the flags
#: are listed: the tracker faults first, then the service faults
KINDS: tuple[Fault, ...] = (
    Fault(name="kill", action="kill", undo="restart", flag="--kill-every", default_every=30.0,
          help="SIGKILL + restart period, s (default 30; 0: none)", target=TRACKER, length=flag_length("restart_after"),
          limits=TRACKER_LIMITS, colour="#d62728", verb="kill", undo_verb="restart", noun="tracker kill", exits=True),
    Fault(name="freeze", action="freeze", undo="thaw", flag="--freeze-every", default_every=60.0,
          help="freeze period, s (default 60; 0: none)", target=TRACKER, length=flag_length("fault_s"),
          limits=TRACKER_LIMITS, colour="#1f77b4", verb="freeze", undo_verb="thaw", noun="freeze"),
    Fault(name="cut", action="cut", undo="heal", flag="--cut-every", default_every=90.0,
          help="link-cut period, s (default 90; 0: none; >0 needs root)", target=TRACKER, length=flag_length("fault_s"),
          limits=TRACKER_LIMITS, colour="#ff7f0e", verb="cut", undo_verb="heal", noun="link cut"),
    # a 1 s truth stall cost every tracker 1.2x; a stall lasts 0.5-3 s
    Fault(name="truth-stall", action="stall", undo="resume", flag="--truth-stall-every", advanced=True,
          help="SIGSTOP the truth process for a seeded 0.5-3 s this often, s (0: none)", target="truth", phase_s=15.0,
          length=seeded_length(0.5, 3.0, salt=104729), limits=(4.0, 4.0), colour="#9467bd", verb="freeze",
          undo_verb="thaw", noun="truth stall"),
    # a truth and a router kill together (2 s without measurements or messages: every tracker coasts) cost 3.6x and
    # 4.3x; the limits leave room above those and still fail a network that does not settle after a blackout
    Fault(name="truth-kill", action="kill", undo="restart", flag="--truth-kill-every", advanced=True,
          help="kill and restart the truth this often, s (0: none)", target="truth", phase_s=10.0,
          length=flag_length("restart_after"), limits=(5.0, 5.0), colour="#d62728", verb="kill", undo_verb="restart",
          noun="truth kill", exits=True),
    Fault(name="router-kill", action="kill", undo="restart", flag="--router-every", advanced=True,
          help="kill and restart the router this often, s (0: none; needs --router or namespaces)", target="router",
          phase_s=20.0, length=flag_length("restart_after"), limits=(5.0, 5.0), colour="#d62728", verb="kill",
          undo_verb="restart", noun="router kill", exits=True),
    # a node drain restarts each tracker it moves on another node: each is judged like a kill (a drain that moves k
    # trackers at once: k overlapping windows, so each network limit compounds)
    Fault(name="drain", action="drain", undo="undrain", flag="--drain-every", advanced=True,
          help="--engine stack on a swarm with workers (deploy/swarm-nodes.sh): drain the worker holding the most "
               "trackers for --drain-s this often, s (0: none; docs/swarm.md)", target="swarm", phase_s=7.5,
          per_tracker=True, length=flag_length("drain_s", DRAIN_S), limits=TRACKER_LIMITS, colour="#2ca02c",
          verb="drain", undo_verb="undrain", noun="node drain"),
    # sensors of their own (issue 52): the trackers that take the sensor lose its detections and coast on their
    # neighbours' estimates; the sensor's process is killed and restarted (it resumes at the current time)
    Fault(name="sensor-kill", action="kill", undo="restart", flag="--sensor-kill-every", advanced=True,
          help="scenarios with sensors of their own ([sensor_timing]): SIGKILL a sensor's process and restart it "
               "after --restart-after this often, s (0: none)", target=SENSOR, phase_s=5.0,
          length=flag_length("restart_after"), limits=SENSOR_LIMITS, colour="#8c564b", verb="kill_sensor",
          undo_verb="restart_sensor", noun="sensor kill", exits=True),
    # ... or its clock steps back --clock-jump-s and stays there (the process runs on, its stamps jump): its trackers
    # refuse its detections (stale) until their offset estimate follows; the window ends when it is due to have
    Fault(name="clock-jump", action="jump", undo="followed", flag="--clock-jump-every", advanced=True,
          help="scenarios with sensors of their own: step a sensor's clock back --clock-jump-s (it stays back) this "
               "often, s (0: none; its window lasts until the trackers follow, 61 detections)", target=SENSOR,
          phase_s=12.5, length=follow_length, limits=SENSOR_LIMITS, colour="#e377c2", verb="jump_clock",
          undo_verb="", noun="sensor clock jump"),
)


def registered() -> tuple[Fault, ...]:
    """The registry as it stands (read at each call, so that a test may register a kind of its own)."""
    return KINDS


class UnknownFault(ValueError):
    """An event no registered kind of fault starts or undoes on that target."""


def fault_of(action: str, target: int | str) -> Fault:
    """The kind of fault an event (an action that starts or undoes one, on a tracker index or a service) belongs
    to: ``("kill", 3)`` -> kill, ``("restart", "router")`` -> router-kill, ``("undrain", 2)`` -> drain."""
    for fault in registered():
        if action in (fault.action, fault.undo) and fault.hits(target):
            return fault
    raise UnknownFault(f"unknown fault action {action!r} on {service_name(target)} (no kind of fault in the "
                       "registry, zentrack.cluster.soak.fault_kinds, starts or undoes it there)")


def fault_named(name: str) -> Fault:
    """The registered kind called ``name`` (``kill``, ``truth-stall``, ...)."""
    for fault in registered():
        if fault.name == name:
            return fault
    raise UnknownFault(f"no kind of fault is called {name!r}")


def fault_actions() -> dict[str, str]:
    """Each action that starts a fault -> the action that undoes it (``kill`` -> ``restart``, ...)."""
    return {f.action: f.undo for f in registered()}


def undo_actions() -> dict[str, str]:
    """Each action that undoes a fault -> the action that started it (``restart`` -> ``kill``, ...)."""
    return {f.undo: f.action for f in registered()}


def window_limits() -> dict[str, tuple[float, float]]:
    """Each kind -> its window's limits (affected, network): the kinds whose windows are a tracker's first (a
    node drain's too: it is recorded per tracker moved), then a sensor's, then those that hit every tracker at
    once."""
    kinds = registered()
    order = [*(f for f in kinds if f.hits(0)), *(f for f in kinds if f.target == SENSOR)]
    return {f.name: f.limits for f in [*order, *(f for f in kinds if f not in order)]}


def brings_back(action: str, target: int | str) -> bool:
    """Whether the event starts again a process that a fault ended (a restart after a kill)."""
    try:
        fault = fault_of(action, target)
    except UnknownFault:
        return False
    return fault.exits and action == fault.undo


def period(args: argparse.Namespace, fault: Fault) -> float:
    """The period of ``fault`` in the soak's flags (0: off, also when the flags lack it)."""
    return getattr(args, fault.dest, 0.0) or 0.0


def asked(args: argparse.Namespace) -> list[Fault]:
    """The kinds of fault the soak's flags ask for (a period above 0)."""
    return [f for f in registered() if period(args, f) > 0]


def service_name(target: int | str) -> str:
    """The process a fault hits: ``node-<i>`` for tracker i, else the service itself (``truth``, ``router``,
    ``sensor-<S>``)."""
    return f"node-{target}" if isinstance(target, int) else target


#: why a backend whose services run no sensor processes lacks the sensor faults' verbs (its ``WHY_NOT``)
SENSOR_VERBS_WHY_NOT = {verb: "its services run no sensor processes: sensors of their own run on loopback only"
                        for verb in ("kill_sensor", "restart_sensor", "jump_clock")}


class Verb(Protocol):
    """A backend's verb: one thing done to one service (``node-<i>``, ``truth``, ``router``; ``swarm`` for a
    node drain). A drain (and its undo) returns the trackers it concerns, every other verb None."""

    def __call__(self, service: str, /) -> list[int] | None: ...


def has_verbs(backend: type | object, fault: Fault) -> bool:
    """Whether a backend (class or instance) has the verbs of ``fault`` (both, or the one of a kind without an
    undo verb)."""
    return all(callable(getattr(backend, v, None)) for v in (fault.verb, fault.undo_verb) if v)


def lacking_line(fault: Fault, backend: type, engine: str, engines: Mapping[str, type] | None = None) -> str:
    """The line that refuses ``fault`` on ``backend`` (the class of ``--engine engine``): the fault, the engine and
    the verb it lacks (and why, from the backend's ``WHY_NOT``), and which of ``engines`` (when given) can apply
    it."""
    verb = next(v for v in (fault.verb, fault.undo_verb) if v and not callable(getattr(backend, v, None)))
    why = getattr(backend, "WHY_NOT", {}).get(verb)
    able = [name for name, cls in (engines or {}).items() if has_verbs(cls, fault)]
    needs = ":" if engines is None else f" needs --engine {' or '.join(able)}:" if able else \
        " can be applied by no engine:"
    return (f"{fault.flag}{needs} --engine {engine} has no {fault.noun} ({backend.__name__} has no {verb!r} verb"
            + (f": {why})" if why else ")"))


def unsupported(faults: Iterable[Fault], engine: str, engines: Mapping[str, type]) -> str | None:
    """Before anything starts: the line refusing the first of ``faults`` whose verbs the backend of ``engine``
    (one of ``engines``: ``--engine`` name -> backend class, each naming itself in ``ENGINE``) lacks, or None
    when it has them all."""
    backend = engines[engine]
    return next((lacking_line(f, backend, engine, engines) for f in faults if not has_verbs(backend, f)), None)


def dispatch(backend: object, action: str, target: int | str) -> list[int] | None:
    """Apply one event of the schedule with ``backend``'s verb for it (what its ``act`` does): the trackers a
    drain moved, else None. An event no kind of fault has, or a verb the backend lacks, is one clear error
    (:class:`UnknownFault`; the soak checks the verbs before it starts, :func:`unsupported`)."""
    fault = fault_of(action, target)
    if not has_verbs(backend, fault):
        raise UnknownFault(lacking_line(fault, type(backend), getattr(backend, "ENGINE", type(backend).__name__)))
    name = fault.verb if action == fault.action else fault.undo_verb
    if not name:  # the end of its window only (a clock step stays)
        return None
    verb = cast(Verb, getattr(backend, name))
    return verb(service_name(target))
