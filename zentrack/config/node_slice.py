"""Node i's slice cut out of a scenario: what the orchestrator writes to ``<out>/config/node-<i>.json`` and what
``zentrack node --scenario`` builds for itself, as a :class:`~zentrack.config.node_config.NodeConfig`.

:func:`node_config_from_spec` slices a scenario *spec* (no run is simulated, no truth computed);
:func:`node_config_from_data` the static parts of a simulated or recorded run (``--scenario-file``). Both give
the same slice for the same scenario. A tracker reads only the slice (:mod:`zentrack.config.node_config`): this
module, which needs the scenario's graph (:mod:`zentrack.truth.simulation.scenario_spec`), is never imported by
``zentrack.node`` (``tests/test_layers.py``).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from zentrack.config.node_config import NodeConfig, NodeConfigError, RunParameters, SensorConfig, gate_thresholds

if TYPE_CHECKING:
    from zentrack.truth.simulation.scenario import ScenarioData
    from zentrack.truth.simulation.scenario_spec import ScenarioSpec


def _slice(i: int, nodes: int, role: str, adjacency: np.ndarray, weights: np.ndarray, sensor: SensorConfig | None,
           measurement: str, linear_matrix: np.ndarray | None, plant: str, plant_params: dict, ts: float, p0: np.ndarray, lumped_var: float, seed: int, name: str,
           run: RunParameters, multitarget: dict[str, Any] | None = None) -> NodeConfig:
    neighbours = [int(j) for j in np.flatnonzero(adjacency[i]) if j != i]
    row = {j: float(weights[i, j]) for j in [i, *neighbours]}
    cfg = NodeConfig(
        node=i, nodes=nodes, role=role, neighbours=neighbours, weights=row,
        neighbour_links={j: [int(o) for o in np.flatnonzero(adjacency[j]) if o != j] for j in neighbours},
        sensor=sensor if role == "sensor" else None, measurement=measurement,
        linear_matrix=None if linear_matrix is None else np.asarray(linear_matrix, float).tolist(), plant=plant,
        plant_params={k: float(v) for k, v in plant_params.items()}, ts=float(ts), p0=np.asarray(p0, float).tolist(),
        lumped_var=float(lumped_var), filter=run.filter, filter_params=dict(run.filter_params), fusion=run.fusion,
        fusion_params=dict(run.fusion_params), mode=run.mode, deadline_frac=float(run.deadline_frac), seed=int(seed),
        latency_budget_ms=float(run.latency_budget_ms),
        gate=float(run.gate), gate_thresholds=gate_thresholds(float(run.gate)),
        scenario=name, plugins=list(run.plugins), multitarget=None if multitarget is None else dict(multitarget),
    )
    cfg.validate(f"node {i}")
    return cfg


def node_config_from_data(scn: ScenarioData, i: int, run: RunParameters) -> NodeConfig:
    """Node i's slice of a simulated or recorded run (only the static parts are read)."""
    if not 0 <= i < scn.nodes:
        raise NodeConfigError(f"node {i} is outside the scenario's 0..{scn.nodes - 1}")
    roles = getattr(scn, "roles", None)
    role = str(roles[i]) if roles is not None and len(roles) else "sensor"
    sensor = SensorConfig(position=np.asarray(scn.sensors[i], float).tolist(),
                          noise_cov=np.asarray(scn.noise_cov[i], float).tolist())
    return _slice(i, scn.nodes, role, scn.adjacency, scn.weights, sensor, scn.measurement, scn.linear_matrix, scn.plant, scn.plant_params, scn.ts, scn.p0,
                  scn.lumped_var, scn.seed, scn.name, run)


def node_config_from_spec(spec: ScenarioSpec, ts: float, seed: int, i: int, run: RunParameters,
                          multitarget: dict[str, Any] | None = None, kinds: Sequence[str] = ()) -> NodeConfig:
    """Node i's slice straight from a scenario spec: no run is simulated, so no truth is ever computed
    (``multitarget``: a many-target run's tracker parameters; ``kinds``: each sensor's measurement kind in a
    mixed many-target network, whose node i measures by its own sensor's kind and takes scans from the
    neighbours of that kind only)."""
    if not 0 <= i < spec.nodes:
        raise NodeConfigError(f"node {i} is outside the scenario's 0..{spec.nodes - 1}")
    from zentrack.truth.simulation.scenario_spec import graph_weights  # here: `zentrack node --node-config` loads none

    adjacency, weights = graph_weights(spec)
    roles = getattr(spec, "roles", None)
    role = str(roles[i]) if roles else "sensor"
    kind = kinds[i] if kinds else spec.measurement
    m = {"bearing": 2, "point": 3}.get(kind)
    if m is None:
        m = int(np.asarray(spec.linear_matrix).shape[0]) if spec.measurement == "linear" else 2
    noise = (np.diag(spec.extent.noise_diag) if spec.extent is not None
             else spec.noise_levels()[i] ** 2 * np.eye(m))
    sensor = SensorConfig(position=np.asarray(spec.sensors[i], float).tolist(), noise_cov=noise.tolist())
    cfg = _slice(i, spec.nodes, role, adjacency, weights, sensor, kind, spec.linear_matrix, spec.plant, spec.plant_params,
                 ts, spec.p0, spec.lumped_var, seed, spec.name, run, multitarget)
    if kinds:
        cfg.scan_neighbours = [j for j in cfg.neighbours if kinds[j] == kind]
    return cfg
