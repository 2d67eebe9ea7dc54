"""What one tracker process is told: its own slice of the run's configuration, and nothing else.

A :class:`NodeConfig` holds node i's role, its sensor (position, noise, measurement model), its neighbours and
weight row, the motion model and initial covariance, the local filter and fusion rule by name with their
parameters, and the timing. It never holds the truth, the measurements or another node's sensor: the run's
initial estimate arrives in truth's ``ctl/start`` message, and the measurements on ``meas/<i>``.

The orchestrator writes one slice per node (``<out>/config/node-<i>.json``) and starts ``zentrack node
--node-config FILE``; a node started by hand with ``--scenario`` or ``--scenario-file`` has the command line cut
its slice first. Cutting slices out of a scenario is :mod:`zentrack.config.node_slice`: this module, which every
tracker imports, imports no scenario module.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, cast

import numpy as np

from zentrack.common.atomic import write_text_atomically
from zentrack.common.suggest import did_you_mean
from zentrack.config.node_multitarget import multitarget_problem
from zentrack.fusion.defaults import (
    DEFAULT_DEADLINE_FRAC,
    DEFAULT_FILTER,
    DEFAULT_FUSION,
    DEFAULT_GATE,
)
from zentrack.fusion.models import MEASUREMENTS

NODE_CONFIG_VERSION = 1
ROLES = ("sensor", "relay")
#: how a run is timed (docs/runtime.md, "Timing modes")
MODES = ("realtime", "lockstep")


class NodeConfigError(ValueError):
    """A node configuration that cannot be used; the message names the file and the field."""


class DeferredGenerator:
    """NumPy's ``default_rng(entropy)``, made on its first use: ``numpy.random`` (3.2 MB resident, with the
    ``secrets``/``hashlib`` it imports) is loaded only in a tracker whose filter draws (a particle filter), not in
    one whose filter is deterministic. Every attribute is the generator's, so it stands in for one."""

    def __init__(self, entropy: int | list[int]) -> None:
        self._entropy = entropy
        self._generator: np.random.Generator | None = None

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("_entropy", "_generator"):
            raise AttributeError(name)
        if self._generator is None:
            self._generator = np.random.default_rng(self._entropy)
        return getattr(self._generator, name)


def deferred_generator(entropy: int | list[int]) -> np.random.Generator:
    """A :class:`DeferredGenerator` typed as the generator it stands in for."""
    return cast("np.random.Generator", DeferredGenerator(entropy))


@dataclass
class SensorConfig:
    """The node's own sensor: where it is, what it measures and how noisy it is."""

    position: list[float]  # (3,)
    noise_cov: list[list[float]]  # (m, m)

    @property
    def dim(self) -> int:
        return len(self.noise_cov)


@dataclass
class NodeConfig:
    """Node ``node``'s slice of the run (see module docstring). Plain JSON types only."""

    node: int
    nodes: int
    role: str
    neighbours: list[int]
    weights: dict[int, float]  # the weight row over self and neighbours (paper 0 W, row i)
    sensor: SensorConfig | None  # None for a relay
    measurement: str  # the network's measurement model (bearing | point | linear): a relay fuses its estimates
    linear_matrix: list[list[float]] | None
    plant: str
    plant_params: dict[str, float]
    ts: float
    p0: list[list[float]]
    lumped_var: float
    filter: str
    filter_params: dict[str, Any] = field(default_factory=dict)
    fusion: str = DEFAULT_FUSION
    fusion_params: dict[str, Any] = field(default_factory=dict)
    mode: str = "realtime"
    deadline_frac: float = DEFAULT_DEADLINE_FRAC
    #: how far (ms) the node's schedule runs behind the run's, for slow links (node/timing.py, docs/networks.md)
    latency_budget_ms: float = 0.0
    #: the false-rejection probability of the chi-square gate on neighbours' messages (0: no gate)
    gate: float = DEFAULT_GATE
    #: the gate's chi-square bound for a message of dimension d at index d - 1 (d = 1 .. MAX_GATE_DIM),
    #: computed where the slice is cut, so a tracker never loads SciPy's special functions (empty: computed
    #: by the tracker when first needed)
    gate_thresholds: list[float] = field(default_factory=list)
    seed: int = 0  # the node's random generator is SeedSequence([seed, node]) (reproducible per node and run)
    scenario: str = ""
    plugins: list[str] = field(default_factory=list)
    #: each neighbour's own neighbours: the origins whose scans it may relay (``relay_scans``)
    neighbour_links: dict[int, list[int]] = field(default_factory=dict)
    #: a many-target run: the multi-target tracker's parameters besides the models (the fields of
    #: :class:`~zentrack.fusion.multitarget.network.TrackerSettings` after ``ts``: P_D, clutter density, ...);
    #: None: the node tracks one target
    multitarget: dict[str, Any] | None = None
    #: a mixed many-target network: the neighbours whose scans a node that exchanges scans takes (those of its
    #: own kind); None: every neighbour
    scan_neighbours: list[int] | None = None
    #: sensors of their own (issue 52, ``node/detections.py``): ``{"lag_ms": L, "clock": c, "sensors": [{"sensor":
    #: s, "rate_hz": r, "offset_s": o or None (estimated), "min_latency_s": l}, ...]}`` (``clock``: the
    #: section's, whether the offsets to the neighbours' clocks are estimated or taken as synchronised,
    #: ``node/diffusion/neighbour_clocks.py``); None: the truth's synchronous measurements on ``meas/<i>``
    detections: dict[str, Any] | None = None
    version: int = NODE_CONFIG_VERSION

    # ------------------------------------------------------------------ derived
    @property
    def measurement_dim(self) -> int:
        if self.measurement == "linear":
            return len(self.linear_matrix or [])
        return {"bearing": 2, "point": 3, "extent-ellipse": 2, "extent-rectangle": 2}.get(self.measurement, 0)

    def rng(self) -> np.random.Generator:
        """The node's generator, ``default_rng(SeedSequence([seed, node]))``, made when a filter first draws."""
        return deferred_generator([self.seed, self.node])

    def weight_array(self) -> np.ndarray:
        """The weight row as an ``(nodes,)`` array (zeros outside self and the neighbours)."""
        w = np.zeros(self.nodes)
        for j, v in self.weights.items():
            w[j] = v
        return w

    # ------------------------------------------------------------------ checks and files
    def validate(self, where: str = "node config") -> None:
        def bad(key: str, why: str) -> None:
            raise NodeConfigError(f"{where}: {key}: {why}")

        if self.version != NODE_CONFIG_VERSION:
            bad("version", f"{self.version!r} is not {NODE_CONFIG_VERSION}")
        if not 1 <= self.nodes <= 1000 or not 0 <= self.node < self.nodes:
            bad("node", f"{self.node} is not in 0..{self.nodes - 1}")
        if self.role not in ROLES:
            bad("role", f"{self.role!r} is not one of {', '.join(ROLES)}")
        if (self.sensor is None) != (self.role == "relay"):
            bad("sensor", "a sensor node needs a sensor and a relay has none")
        if any(not 0 <= j < self.nodes or j == self.node for j in self.neighbours):
            bad("neighbours", f"{self.neighbours} must be other nodes of 0..{self.nodes - 1}")
        allowed = set(self.neighbours) | {self.node}
        if set(self.weights) - allowed or self.node not in self.weights:
            bad("weights", "must hold this node's own weight and only its neighbours'")
        if self.neighbour_links and (set(self.neighbour_links) != set(self.neighbours) or any(
                j in links or any(not 0 <= o < self.nodes for o in links)
                for j, links in self.neighbour_links.items())):
            bad("neighbour_links", "must list each neighbour's own neighbours (nodes of the network, never itself)")
        if self.scan_neighbours is not None and (not isinstance(self.scan_neighbours, list)
                                                 or not set(self.scan_neighbours) <= set(self.neighbours)):
            bad("scan_neighbours", "must be a list of the node's neighbours")
        w = np.array(list(self.weights.values()), dtype=float)
        if not (np.all(np.isfinite(w)) and np.all(w >= 0) and abs(w.sum() - 1.0) < 1e-9):
            bad("weights", f"must be non-negative and sum to 1, got {self.weights}")
        if not (math.isfinite(self.ts) and 1e-4 <= self.ts <= 60.0):
            bad("ts", f"must be from 0.0001 to 60 s, got {self.ts}")
        def spd(key: str, value: Any) -> None:
            m = np.asarray(value, dtype=float)
            if m.ndim != 2 or m.shape[0] != m.shape[1] or not np.all(np.isfinite(m)):
                bad(key, "must be a finite square matrix")
            try:
                np.linalg.cholesky(m)
            except np.linalg.LinAlgError:
                bad(key, "must be positive definite")

        spd("p0", self.p0)
        if self.sensor is not None:
            pos = np.asarray(self.sensor.position, dtype=float)
            if pos.shape != (3,) or not np.all(np.isfinite(pos)):
                bad("sensor.position", "must be 3 finite numbers")
            spd("sensor.noise_cov", self.sensor.noise_cov)
        if self.measurement not in MEASUREMENTS or (self.measurement == "linear") != bool(self.linear_matrix):
            bad("measurement", f"{self.measurement!r}: one of {', '.join(MEASUREMENTS)} (linear with a linear_matrix)")
        if self.sensor is not None and len(self.sensor.noise_cov) != self.measurement_dim:
            bad("sensor.noise_cov", f"must be {self.measurement_dim} x {self.measurement_dim} for {self.measurement}")
        if self.mode not in MODES:
            bad("mode", f"{self.mode!r} is not realtime or lockstep")
        if not 0 < self.deadline_frac < 1:
            bad("deadline_frac", f"must be between 0 and 1, got {self.deadline_frac}")
        if not (isinstance(self.latency_budget_ms, (int, float)) and 0 <= self.latency_budget_ms <= MAX_LATENCY_BUDGET_MS):
            bad("latency_budget_ms", f"must be from 0 to {MAX_LATENCY_BUDGET_MS:g} ms, got {self.latency_budget_ms}")
        if not (isinstance(self.gate, (int, float)) and 0 <= self.gate < 1):
            bad("gate", f"must be a probability from 0 (no gate) up to 1, got {self.gate!r}")
        limits = self.gate_thresholds
        if not isinstance(limits, list) or len(limits) > MAX_GATE_DIM or not all(
                isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in limits):
            bad("gate_thresholds", f"must be at most {MAX_GATE_DIM} finite positive numbers")
        if self.multitarget is not None:
            self._validate_multitarget(bad)
        if self.detections is not None:
            self._validate_detections(bad)

    def _validate_detections(self, bad: Any) -> None:
        """Sensors of their own: the lag, and each sensor's id, rate, clock offset and least latency."""
        det = self.detections
        if not isinstance(det, dict) or set(det) != {"lag_ms", "clock", "sensors"}:
            bad("detections", "must be a map of lag_ms, clock and sensors")
        assert isinstance(det, dict)
        if det["clock"] not in DETECTION_CLOCKS:
            bad("detections.clock", f"must be one of {', '.join(DETECTION_CLOCKS)}, got {det['clock']!r}")
        lag = det["lag_ms"]
        if not (isinstance(lag, (int, float)) and not isinstance(lag, bool) and 0 <= lag <= MAX_LATENCY_BUDGET_MS):
            bad("detections.lag_ms", f"must be from 0 to {MAX_LATENCY_BUDGET_MS:g} ms, got {lag!r}")
        links = det["sensors"]
        if not isinstance(links, list) or not links:
            bad("detections.sensors", "must list at least one sensor")
        seen: set[int] = set()
        for i, link in enumerate(links):
            where = f"detections.sensors[{i}]"
            if not isinstance(link, dict) or set(link) != set(DETECTION_LINK_KEYS):
                bad(where, f"must be a map of {', '.join(DETECTION_LINK_KEYS)}")
            sensor = link["sensor"]
            if not (type(sensor) is int and 0 <= sensor < MAX_SENSOR_ID) or sensor in seen:
                bad(f"{where}.sensor", f"must be a distinct sensor id from 0 to {MAX_SENSOR_ID - 1}, got {sensor!r}")
            seen.add(sensor)
            rate, offset, latency = link["rate_hz"], link["offset_s"], link["min_latency_s"]
            if not (_number(rate) and 0 < rate <= 1000):
                bad(f"{where}.rate_hz", f"must be above 0 and at most 1000 Hz, got {rate!r}")
            if offset is not None and not (_number(offset) and abs(offset) <= 3600):
                bad(f"{where}.offset_s", f"must be null (estimated) or within 3600 s, got {offset!r}")
            if not (_number(latency) and 0 <= latency <= 60):
                bad(f"{where}.min_latency_s", f"must be from 0 to 60 s, got {latency!r}")
        if self.mode != "realtime":
            bad("detections", "sensors of their own run in realtime only (a lockstep run is the truth's grid)")

    def _validate_multitarget(self, bad: Any) -> None:
        """The many-target parameters (:func:`~zentrack.config.node_multitarget.multitarget_problem`) and the
        sensors (``bad(key, why)`` raises)."""
        problem = multitarget_problem(self.multitarget)
        if problem is not None:
            bad(*problem)
        if self.measurement not in ("point", "bearing"):
            bad("measurement", f"a many-target node needs point or bearing sensors, not {self.measurement!r}")

    def to_json(self) -> str:
        doc = asdict(self)
        doc["weights"] = {str(j): v for j, v in self.weights.items()}
        doc["neighbour_links"] = {str(j): v for j, v in self.neighbour_links.items()}
        return json.dumps(doc, indent=1) + "\n"

    @classmethod
    def from_json(cls, text: str, where: str = "node config") -> NodeConfig:
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise NodeConfigError(f"{where}: not JSON ({exc.msg} at line {exc.lineno})") from None
        if not isinstance(doc, dict):
            raise NodeConfigError(f"{where}: expected a JSON object")
        _known_keys(doc, cls, where, "")
        if isinstance(doc.get("sensor"), dict):
            _known_keys(doc["sensor"], SensorConfig, where, "sensor.")
        try:
            sensor = doc.pop("sensor", None)
            doc["weights"] = {int(j): float(v) for j, v in doc.get("weights", {}).items()}
            doc["neighbour_links"] = {int(j): [int(o) for o in v] for j, v in doc.get("neighbour_links", {}).items()}
            cfg = cls(sensor=SensorConfig(**sensor) if sensor is not None else None, **doc)
        except (TypeError, ValueError) as exc:
            raise NodeConfigError(f"{where}: {exc}") from None
        cfg.validate(where)
        return cfg

    def save(self, path: str | os.PathLike) -> Path:
        """Write atomically (a node started meanwhile never reads half a file)."""
        return write_text_atomically(path, self.to_json())

    @classmethod
    def load(cls, path: str | os.PathLike) -> NodeConfig:
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise NodeConfigError(f"{path}: cannot read ({exc.strerror or exc})") from None
        return cls.from_json(text, str(path))


# ---------------------------------------------------------------- what slices are built with (node_slice.py)
@dataclass
class RunParameters:
    """The run-wide settings a slice carries besides the scenario's geometry."""

    filter: str = DEFAULT_FILTER
    filter_params: dict[str, Any] = field(default_factory=dict)
    fusion: str = DEFAULT_FUSION
    fusion_params: dict[str, Any] = field(default_factory=dict)
    mode: str = "realtime"
    deadline_frac: float = DEFAULT_DEADLINE_FRAC
    plugins: list[str] = field(default_factory=list)
    gate: float = DEFAULT_GATE
    latency_budget_ms: float = 0.0


#: the keys of one sensor a tracker takes (``NodeConfig.detections``) and the sensor ids a run may use
DETECTION_LINK_KEYS = ("sensor", "rate_hz", "offset_s", "min_latency_s")
#: how a tracker of sensors of their own knows the clocks (``[sensor_timing] clock``): estimated from the stream,
#: or configured (each sensor's offset given; the trackers' clocks synchronised)
DETECTION_CLOCKS = ("estimated", "configured")
MAX_SENSOR_ID = 10_000


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: the largest latency budget a node accepts (ms)
MAX_LATENCY_BUDGET_MS = 10_000.0
#: message dimensions the slice carries gate bounds for (the wire's largest block)
MAX_GATE_DIM = 64


def _known_keys(doc: dict, kind: type, where: str, prefix: str) -> None:
    """Every key of ``doc`` is a field of the dataclass ``kind`` (the slice's schema), else one line naming the
    key and the nearest field."""
    names = [f.name for f in fields(kind)]
    unknown = sorted(set(doc) - set(names), key=str)
    if unknown:
        raise NodeConfigError(f"{where}: {prefix}{unknown[0]}: unknown key{did_you_mean(str(unknown[0]), names)}")


def gate_thresholds(false_rejection: float) -> list[float]:
    """The gate's bound ``chi2_d(1 - false_rejection)`` for d = 1 .. :data:`MAX_GATE_DIM` (none without a
    gate): the values :func:`~zentrack.fusion.gate.gate_threshold` gives, one call each."""
    if false_rejection <= 0:
        return []
    from zentrack.fusion.gate import gate_threshold

    return [gate_threshold(d, false_rejection) for d in range(1, MAX_GATE_DIM + 1)]

