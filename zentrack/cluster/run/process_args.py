"""The command lines a run gives its processes (:class:`~zentrack.cluster.run.cluster.Cluster`): how each one
reaches Zenoh, finds the run's scenario, filter and timing, and (the viewer) its fusion rule."""
from __future__ import annotations

from pathlib import Path

from zentrack.config.run_setup import RunSetup


def zenoh_args(endpoint: str, router: bool, secure: str | None, zenoh_config: str | None) -> list[str]:
    """Everyone connects to the recorder's (or the router's) ``endpoint``; gossip meshes the peers. Through a
    router (``router``, or mutual TLS with the certificates in ``secure``) as a client; ``zenoh_config``: a
    user's Zenoh file, merged over the safe defaults."""
    file = ["--zenoh-config", zenoh_config] if zenoh_config else []
    if secure:
        return ["--zenoh-mode", "client", "--connect", endpoint, "--secure", secure, *file]
    if router:
        return ["--zenoh-mode", "client", "--connect", endpoint, *file]
    return ["--connect", endpoint, *file]


def scenario_args(setup: RunSetup, scenario_path: Path) -> list[str]:
    """How the truth and the viewer find the run: the scenario file the cluster wrote (``scenario_path``); a
    many-target run (no file format yet) by the scenario, seed, steps and nodes it was simulated from
    (deterministic)."""
    if setup.multitarget is None and setup.sensor_timing is None:
        return ["--scenario-file", str(scenario_path)]
    # (sensors of their own: their timing is the scenario file's [sensor_timing], which a .npz does not hold)
    assert setup.scenario_ref is not None
    scn = setup.run_data
    return ["--scenario", setup.scenario_ref, "--seed", str(setup.seed), "--steps", str(scn.steps),
            "--nodes", str(scn.nodes), "--fusion", setup.fusion]


def filter_args(setup: RunSetup, scenario_path: Path, run_name: str) -> list[str]:
    """The scenario, the filter, its parameters and the timing, as the truth and the sensors take them."""
    out = [*scenario_args(setup, scenario_path), "--filter", setup.filter_kind, "--qbar", repr(setup.qbar),
           "--timing", setup.mode, "--deadline-frac", repr(setup.deadline_frac), "--run", run_name]
    if setup.theta is not None:
        out += ["--theta", repr(setup.theta)]
    if setup.period is not None:
        out += ["--period", repr(setup.period)]
    return out


def fusion_args(setup: RunSetup) -> list[str]:
    """The fusion rule and its rounds, for the viewer (it reads the round messages of multi-round rules); none
    for a rule from a plug-in module, which the viewer's flags cannot name, or a many-target run (its scenario
    names its rule)."""
    if setup.plugins or setup.multitarget is not None:
        return []
    out = ["--fusion", setup.fusion]
    rounds = setup.run_parameters().fusion_params.get("rounds")
    if isinstance(rounds, int):
        out += ["--rounds", str(rounds)]
    return out
