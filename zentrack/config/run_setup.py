"""Scenario and filter selection shared by ``zentrack truth``, ``node`` and ``run``.

A process takes ``--scenario NAME|PATH`` (a TOML scenario file, see ``deploy/scenarios/``) or
``--scenario-file PATH.npz`` (a recorded scenario); the filter and timing come from the TOML file and can be
overridden by flags (a ``.npz`` carries no filter settings: the flags' defaults apply).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from zentrack.common.argtypes import (
    fusion_params_with,
)
from zentrack.common.vocabulary import CENTRALIZED_NOT_LIVE
from zentrack.config import catalogue
from zentrack.config.node_config import NodeConfig, RunParameters
from zentrack.config.node_slice import node_config_from_data, node_config_from_spec
from zentrack.fusion.defaults import (
    CENTRALIZED,
    DEFAULT_DEADLINE_FRAC,
    DEFAULT_FILTER,
    DEFAULT_FUSION,
    DEFAULT_GATE,
    DEFAULT_QBAR,
)
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.registry import load_plugins
from zentrack.fusion.rules import RULE_REGISTRY, make_rule

if TYPE_CHECKING:  # a tracker started with --node-config parses these flags without importing the scenarios
    from zentrack.config.scenario_sensor_timing import SensorTiming
    from zentrack.truth.simulation.multitarget import MultiTargetData, MultiTargetSpec
    from zentrack.truth.simulation.scenario import ScenarioData
    from zentrack.truth.simulation.scenario_spec import ScenarioSpec
    from zentrack.truth.simulation.sensor_stream import SensorStreamSpec


@dataclass
class RunSetup:
    """A run as the flags name it. ``scenario`` is simulated on first use (truth, orchestrator, viewer); a node
    never touches it: :meth:`node_config` slices the spec (or a recorded file's static parts) instead."""

    filter_kind: str
    qbar: float
    theta: float | None
    mode: str
    deadline_frac: float
    source: str
    spec: ScenarioSpec | None = None
    ts: float = 0.1
    seed: int = 0
    data: ScenarioData | None = None
    fusion: str = DEFAULT_FUSION
    fusion_params: dict = field(default_factory=dict)
    plugins: list[str] = field(default_factory=list)
    filter_params: dict = field(default_factory=dict)  # besides qbar/theta
    #: wall-clock seconds per step of a realtime run (None: the scenario's ts); the models keep ts, so a run
    #: can go faster (or slower) than real time with the same numbers
    period: float | None = None
    #: false-rejection probability of each node's gate on its neighbours' messages (0: no gate)
    gate: float = DEFAULT_GATE
    #: how far (ms) each node's schedule runs behind the run's, for slow links (docs/networks.md)
    latency_budget_ms: float = 0.0
    #: a many-target run: its targets and sensing (None: one target), the ``--scenario`` it came from (the other
    #: processes derive the same run from it), and the fusion rule of associated tracks
    multitarget: MultiTargetSpec | None = None
    scenario_ref: str | None = None
    track_rule: str | None = None
    #: many targets: each node's tracker (``[tracker] kind`` or ``--tracker``), and whether point sensors' nodes
    #: share their scans (``[tracker] share_scans`` or ``--share-scans``; None: the tracker's default)
    tracker: str = "gnn"
    share_scans: bool | None = None
    #: sensors of their own (``[sensor_timing]``, issue 52): one ``zentrack sensor`` process per sensor, the
    #: trackers take their detections (``NodeConfig.detections``); None: the truth measures every step
    sensor_timing: SensorTiming | None = None
    _mt_data: MultiTargetData | None = None

    @property
    def wall_period(self) -> float:
        """Seconds between steps on the wall clock."""
        return self.period if self.period is not None else self.ts

    @classmethod
    def from_data(cls, scn: ScenarioData, filter_kind: str = DEFAULT_FILTER, qbar: float = DEFAULT_QBAR,
                  theta: float | None = None, mode: str = "realtime", deadline_frac: float = DEFAULT_DEADLINE_FRAC,
                  source: str = "in memory", **more) -> RunSetup:
        """A run of an already simulated (or loaded) scenario."""
        return cls(filter_kind, qbar, theta, mode, deadline_frac, source, data=scn, ts=scn.ts, seed=scn.seed, **more)

    @property
    def scenario(self) -> ScenarioData:
        if self.data is None:
            from zentrack.truth.simulation.simulate import simulate

            assert self.spec is not None
            self.data = simulate(self.spec, runs=1, seed=self.seed, ts=self.ts)
        return self.data

    @property
    def multitarget_data(self) -> MultiTargetData:
        """A many-target run, simulated on first use (ValueError for a single-target one)."""
        if self.multitarget is None:
            raise ValueError(f"{self.source}: not a many-target scenario")
        if self._mt_data is None:
            from zentrack.truth.simulation.multitarget import simulate_multitarget

            assert self.spec is not None
            self._mt_data = simulate_multitarget(self.spec, self.multitarget, self.seed, self.ts)
        return self._mt_data

    @property
    def run_data(self) -> ScenarioData | MultiTargetData:
        """The run's data of either kind (its ``nodes``, ``steps``, ``ts`` and ``name`` are what a cluster reads)."""
        return self.multitarget_data if self.multitarget is not None else self.scenario

    @property
    def nodes(self) -> int:
        return self.data.nodes if self.data is not None else self.spec.nodes  # type: ignore[union-attr]

    def tracking_params(self, node: int = 0) -> dict | None:
        """A many-target run's tracker parameters for node ``node``'s slice, by its sensor's kind (None: one
        target)."""
        if self.multitarget is None:
            return None
        from zentrack.config.scenario_multitarget import shares_scans, tracking_params
        from zentrack.fusion.track_to_track import DEFAULT_TRACK_RULE

        assert self.spec is not None
        kind = self.multitarget.sensor_kinds(self.spec.measurement, self.spec.nodes)[node]
        return {**tracking_params(self.multitarget, kind, self.source),
                "track_rule": self.track_rule or DEFAULT_TRACK_RULE, "tracker": self.tracker,
                "share_scans": shares_scans(self.tracker, self.share_scans)}

    def run_parameters(self) -> RunParameters:
        """The filter and fusion rule by name with their parameters, checked by their registries (after
        importing the run's plug-in modules)."""
        load_plugins(self.plugins)
        params: dict = dict(self.filter_params)
        known = {p.name for p in FILTER_REGISTRY.params(self.filter_kind)}
        if "qbar" in known:
            params["qbar"] = self.qbar
        if "theta" in known and self.theta is not None:
            params["theta"] = self.theta
        FILTER_REGISTRY.validate(self.filter_kind, params)
        fusion_params = RULE_REGISTRY.validate(self.fusion, self.fusion_params)
        if fusion_params.get("rounds") == "auto":  # L* needs the whole graph: worked out here, once for every node
            from zentrack.fusion.rules.consensus import resolve_rounds
            from zentrack.truth.simulation.scenario_spec import graph_weights

            adjacency, weights = ((self.data.adjacency, self.data.weights) if self.data is not None
                                  else graph_weights(self.spec))  # type: ignore[arg-type]
            fusion_params = resolve_rounds(self.fusion, fusion_params, weights, adjacency)
        try:  # what the rule's constructor checks across its parameters, before any node builds it
            make_rule(self.fusion, fusion_params)
        except ValueError as exc:
            raise ValueError(f"--fusion {self.fusion}: {exc}") from None
        spec = self.spec
        extended = (self.data.plant if self.data is not None else spec.plant if spec is not None else "") == "eot"
        cluttered = self.data.has_scans if self.data is not None else spec is not None and spec.clutter is not None
        tags = FILTER_REGISTRY.entry(self.filter_kind).tags
        if extended != ("extent" in tags):
            takes = [n for n in FILTER_REGISTRY.names() if "extent" in FILTER_REGISTRY.entry(n).tags]
            raise ValueError(f"filter {self.filter_kind!r} does not fit the scenario: an extended object (plant "
                             f"eot) takes one of {', '.join(takes)}, and only it does")
        if cluttered and "scans" not in tags:
            takes = [n for n in FILTER_REGISTRY.names() if "scans" in FILTER_REGISTRY.entry(n).tags]
            raise ValueError(f"filter {self.filter_kind!r} takes one return per scan, but the scenario has several "
                             f"returns per scan (clutter); choose one of {', '.join(takes)}")
        return RunParameters(filter=self.filter_kind, filter_params=params, fusion=self.fusion,
                             fusion_params=fusion_params, mode=self.mode,
                             deadline_frac=self.deadline_frac, plugins=list(self.plugins), gate=self.gate,
                             latency_budget_ms=self.latency_budget_ms)

    def node_config(self, i: int) -> NodeConfig:
        """Node i's slice of this run (no truth in it); with sensors of their own, the sensors it takes."""
        if self.data is not None:
            cfg = node_config_from_data(self.data, i, self.run_parameters())
        else:
            assert self.spec is not None
            cfg = node_config_from_spec(self.spec, self.ts, self.seed, i, self.run_parameters(),
                                        self.tracking_params(i),
                                        self.multitarget.kinds if self.multitarget is not None else ())
        if self.sensor_timing is not None:
            cfg.detections = self.sensor_timing.detections(i)
            cfg.validate(f"node {i}")
        return cfg

    def sensor_streams(self) -> list[SensorStreamSpec]:
        """Each sensor's own timing (``[sensor_timing]``), sensor s at index s; [] when the truth measures."""
        return [] if self.sensor_timing is None else list(self.sensor_timing.streams)

    def own_sensors(self) -> set[int]:
        """The trackers that take sensors of their own (the truth publishes no ``meas/<i>`` for them)."""
        return set() if self.sensor_timing is None else set(range(self.nodes))

    def check_asynchronous(self) -> None:
        """Sensors of their own: ValueError (one line) for what cannot run asynchronously once the flags are
        applied (``--timing lockstep``, ``--fusion`` or ``--rounds`` of a rule with scans or rounds, ``--period``)."""
        if self.sensor_timing is None:
            return
        from zentrack.config.scenario_sensor_timing import asynchronous_refusal

        assert self.spec is not None
        if self.period is not None and abs(self.period - self.ts) > 1e-12:
            raise ValueError(f"{self.source}: sensor_timing: sensors of their own run on the wall clock of the "
                             f"scenario's ts ({self.ts:g} s); drop --period")
        why = asynchronous_refusal(self.mode, self.fusion, self.run_parameters().fusion_params, self.spec,
                                   self.multitarget)
        if why is not None:
            raise ValueError(f"{self.source}: sensor_timing: {why}")


def resolve_setup(args: argparse.Namespace) -> RunSetup:
    """Load the scenario the flags name and apply the overrides (every process derives the same run)."""
    from zentrack.config.scenario_config import load_scenario_config, resize
    from zentrack.config.scenario_file import load_scenario

    nodes, steps, seed = getattr(args, "nodes", None), getattr(args, "steps", None), getattr(args, "seed", None)
    if args.scenario_file:
        if nodes or steps or seed is not None:
            raise ValueError("--nodes/--steps/--seed come from the file when --scenario-file is given")
        scn = load_scenario(args.scenario_file)
        if scn.runs != 1:
            scn = scn.run(0)
        setup = RunSetup(
            filter_kind=args.filter_kind or DEFAULT_FILTER, qbar=args.qbar or DEFAULT_QBAR, theta=args.theta,
            mode=args.timing_mode or "realtime", deadline_frac=args.deadline_frac or DEFAULT_DEADLINE_FRAC,
            source=args.scenario_file, data=scn, ts=scn.ts, seed=scn.seed)
    else:
        ref = args.scenario or catalogue.DEFAULT_SCENARIO
        cfg = resize(load_scenario_config(ref, multitarget=True), nodes, steps)
        spec = cfg.spec
        kind = args.filter_kind or cfg.filter_kind
        setup = RunSetup(
            filter_kind=kind, qbar=args.qbar or cfg.qbar, theta=args.theta or cfg.theta,
            mode=args.timing_mode or cfg.mode, deadline_frac=args.deadline_frac or cfg.deadline_frac, source=cfg.source,
            spec=spec, ts=cfg.ts, seed=cfg.seed if seed is None else seed, fusion=cfg.fusion,
            fusion_params=dict(cfg.fusion_params), plugins=list(cfg.plugins),
            filter_params=dict(cfg.filter_params) if kind == cfg.filter_kind else {},
            multitarget=cfg.multitarget, scenario_ref=ref, sensor_timing=cfg.sensor_timing, tracker=cfg.tracker,
            share_scans=cfg.share_scans)
    fusion = getattr(args, "fusion", None)
    if setup.multitarget is not None:
        return _multitarget_setup(setup, args, fusion)
    for flag in ("tracker", "share_scans"):
        if getattr(args, flag, None) is not None:
            raise ValueError(f"{setup.source}: --{flag.replace('_', '-')}: only a many-target scenario ([targets]) "
                             "chooses its tracker")
    if fusion and fusion != setup.fusion:
        setup.fusion, setup.fusion_params = fusion, {}
    if setup.fusion == CENTRALIZED:
        raise ValueError(f"{setup.source}: {CENTRALIZED_NOT_LIVE}")
    rounds = getattr(args, "rounds", None)
    if rounds is not None:
        if "rounds" not in {p.name for p in RULE_REGISTRY.params(setup.fusion)}:
            raise ValueError(f"--rounds: fusion rule {setup.fusion!r} has no 'rounds' parameter")
        setup.fusion_params = {**setup.fusion_params, "rounds": rounds}
    if getattr(args, "fusion_param", None):
        setup.fusion_params = fusion_params_with(setup.fusion, setup.fusion_params, args.fusion_param)
    setup.period = getattr(args, "period", None)
    gate = getattr(args, "gate", None)
    if gate is not None:
        setup.gate = gate
    setup.latency_budget_ms = getattr(args, "latency_budget_ms", None) or 0.0
    setup.run_parameters()  # every name and parameter checked now, before any process starts
    setup.check_asynchronous()
    return setup


def scenario_setup(scenario: str, nodes: int | None = None, steps: int | None = None, seed: int | None = None,
                   timing_mode: str | None = None, tracker: str | None = None) -> RunSetup:
    """The scenario ``scenario`` (a catalogue name or a scenario config's path) as ``zentrack run --scenario S
    [--nodes N] [--steps K] [--seed X] [--timing M] [--tracker T]`` resolves it, every other flag at its default."""
    return resolve_setup(argparse.Namespace(
        scenario=scenario, scenario_file=None, nodes=nodes, steps=steps, seed=seed, timing_mode=timing_mode,
        tracker=tracker, filter_kind=None, fusion=None, rounds=None, qbar=None, theta=None, deadline_frac=None))


def _multitarget_setup(setup: RunSetup, args: argparse.Namespace, fusion: str | None) -> RunSetup:
    """A many-target run: the tracks' fusion rule (``--fusion``, else fast CI), the timing flags; what the
    many-target trackers do not take is refused in one line."""
    from zentrack.config.scenario_multitarget import scan_sharing_refusal, shares_scans, tracker_refusal
    from zentrack.fusion.track_to_track import DEFAULT_TRACK_RULE

    for flag in ("rounds", "fusion_param", "latency_budget_ms"):
        if getattr(args, flag, None):
            raise ValueError(f"{setup.source}: --{flag.replace('_', '-')} does not apply to a many-target run "
                             "(one exchange of track lists per step)")
    setup.track_rule = fusion or DEFAULT_TRACK_RULE
    setup.tracker = getattr(args, "tracker", None) or setup.tracker
    assert setup.spec is not None and setup.multitarget is not None
    why = tracker_refusal(setup.tracker, setup.spec.measurement, setup.multitarget, setup.spec.nodes,
                          setup.sensor_timing is not None)
    if why is not None:
        raise ValueError(f"{setup.source}: --tracker {setup.tracker}: {why}")
    if getattr(args, "share_scans", None) is not None:
        setup.share_scans = args.share_scans
    why = scan_sharing_refusal(shares_scans(setup.tracker, setup.share_scans), setup.sensor_timing is not None)
    if why is not None:
        raise ValueError(f"{setup.source}: --share-scans: {why}")
    try:
        rule = make_rule(setup.track_rule, {})
        one_shot = not rule.exchanges_scans and rule.rounds(1) == 1
    except ValueError:
        one_shot = False
    if not one_shot:
        raise ValueError(f"--fusion {setup.track_rule}: associated tracks are fused by a one-shot rule (e.g. "
                         f"{DEFAULT_TRACK_RULE}, ci)")
    setup.fusion, setup.fusion_params = setup.track_rule, {}
    setup.period = getattr(args, "period", None)
    gate = getattr(args, "gate", None)
    if gate is not None:
        setup.gate = gate
    setup.run_parameters()
    setup.tracking_params()  # point sensors only: refused now, in one line
    setup.check_asynchronous()
    return setup
