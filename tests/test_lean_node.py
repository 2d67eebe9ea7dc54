"""A tracker process imports only what a tracker uses (issue: a lean tracker process).

``zentrack node`` loads no scenario simulation, no batched simulator, no bound, no ``scipy.stats`` or
``scipy.optimize``: checked in fresh interpreters, for the module alone and for a tracker built from its slice
through the command line. The registries that make this possible are pinned too: a filter's, rule's or model's
module is imported when its name is first asked for, and the names are listed in the same order whatever was
imported first; LAPACK is loaded without the ``scipy.linalg`` package and is the same LAPACK.

Only the standard library and pytest are imported at module level, so that the first test runs (and fails) on
an older installation too: ``OLD/.venv/bin/python -m pytest tests/test_lean_node.py -k sys_modules``.
"""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

#: the simulation and study side, which no tracker needs
FORBIDDEN = (
    "zentrack.truth",  # the simulation (zentrack.truth.simulation) and the truth process
    "zentrack.study",  # the batched simulator, the bound, the study metrics
    "zentrack.fusion.consistency",
    "zentrack.config.scenario_config",
    "zentrack.config.scenario_file",
    "scipy.stats",
    "scipy.optimize",
)
#: the order the registries list their names in (built-ins first, then the package's modules by file name)
FILTER_ORDER = ("teskf", "eskf", "ekf", "ukf", "ckf", "mem-ekf", "mem-if", "pda-fpf", "pda-pf", "pdaf-ekf", "nn-ekf",
                "seckf", "lin", "srcif")
RULE_ORDER = ("ci", "independent", "ci3", "ci-fast", "ci-trace", "dce-ici", "dce-fci", "diff-ici", "diff-fci", "local",
              "eot-ci", "eot-cm", "hcmci")


def fresh(script: str, *args: str) -> dict:
    """Run ``script`` in a fresh interpreter; it prints one JSON document as its last line."""
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def loaded(modules: list[str], names: tuple[str, ...]) -> list[str]:
    """Which of ``names`` (or their submodules) are in ``modules``."""
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


def test_the_tracker_module_imports_no_simulation_sys_modules():
    modules = fresh("import zentrack.node.process, sys, json; print(json.dumps(sorted(sys.modules)))")
    assert "zentrack.node.process" in modules
    assert loaded(modules, FORBIDDEN) == []
    # nor any other process, the cluster tooling, the benches or Rerun
    assert loaded(modules, ("zentrack.viewer", "zentrack.cluster", "zentrack.bench", "rerun")) == []
    # and no filter, rule or model beyond what every tracker has: those come with the tracker's configuration
    assert loaded(modules, ("zentrack.fusion.filters.pda_common", "zentrack.fusion.filters.mem",
                            "zentrack.fusion.rules.consensus", "zentrack.fusion.motion_ship")) == []


def test_a_tracker_built_from_its_slice_through_the_cli_imports_only_its_own_filter_and_rule(tmp_path):
    from zentrack.config.node_config import RunParameters
    from zentrack.config.node_slice import node_config_from_spec
    from zentrack.config.scenario_config import builtin_spec

    cfg = node_config_from_spec(builtin_spec("exp2", nodes=4, steps=10), 0.1, 0, 0, RunParameters(filter="ukf"))
    path = cfg.save(tmp_path / "node-0.json")
    result = fresh("""
        import json, sys
        from zentrack.cli import build_parser
        argv = ["node", "--id", "0", "--node-config", sys.argv[1], "--run", "lean"]
        args = build_parser(argv).parse_args(argv)
        from zentrack.cli.node_command import node_config
        from zentrack.node.diffusion.tracker import Tracker
        tracker = Tracker(node_config(args))
        print(json.dumps({"modules": sorted(sys.modules), "filter": tracker.cfg.filter, "dim": tracker.state_dim}))
    """, str(path))
    modules = result["modules"]
    assert result["filter"] == "ukf" and result["dim"] == 6
    assert loaded(modules, FORBIDDEN) == []
    assert "zentrack.fusion.filters.sigma_point" in modules and "zentrack.fusion.rules.ci" in modules
    others = ("zentrack.fusion.filters.extended_state", "zentrack.fusion.filters.seckf", "zentrack.fusion.filters.mem",
              "zentrack.fusion.filters.pda_common", "zentrack.fusion.rules.independent", "zentrack.fusion.rules.consensus",
              "zentrack.fusion.rules.hybrid")
    assert loaded(modules, others) == []


def test_a_trackers_first_steps_load_no_scipy_package_its_slice_carries_the_gate_bounds(tmp_path):
    """Three trackers of a lockstep network step through decoding, the gate and CI fusion from their JSON slices:
    nothing of SciPy is imported on the way, not even its LAPACK (numpy's does the wire's and the gate's
    factorisations; the gate's chi-square bounds come with the slice and equal what scipy.special computes)."""
    from zentrack.config.node_config import RunParameters, gate_thresholds
    from zentrack.config.node_slice import node_config_from_spec
    from zentrack.config.scenario_config import builtin_spec
    from zentrack.fusion.gate import gate_threshold
    from zentrack.truth.simulation.simulate import simulate

    spec = builtin_spec("exp2", nodes=3, steps=5)
    scn = simulate(spec, runs=1, seed=3)
    paths = [str(node_config_from_spec(spec, 0.1, 0, i, RunParameters(mode="lockstep")).save(tmp_path / f"n{i}.json"))
             for i in range(3)]
    data = json.dumps({"x0": scn.x0_estimate[0].tolist(), "z": scn.measurements[0, :3].tolist()})
    assert gate_thresholds(1e-3)[11] == gate_threshold(12, 1e-3) and gate_thresholds(0.0) == []
    result = fresh("""
        import json, sys
        import numpy as np
        from zentrack.config.node_config import NodeConfig
        from zentrack.node.schedule import NodeSchedule
        from zentrack.node.diffusion.tracker import Tracker
        from zentrack.transport.keys import Keys
        from zentrack.transport.codec import Message
        from zentrack.transport.messages import Measurement, Start
        keys, sent = Keys("lean"), []
        nodes = []
        data = json.loads(sys.argv[1])
        for i, path in enumerate(sys.argv[2:]):
            cfg = NodeConfig.load(path)
            nodes.append(NodeSchedule.diffusion(keys, cfg, Tracker(cfg), clock=lambda: 0.0,
                                      send=lambda ch, data, i=i: sent.append((i, ch, data))))
        before = sorted(m for m in sys.modules if m.startswith("scipy"))
        start = Start(0.0, 0.1, 5, "lockstep", (0, 1, 2), 0.5, np.array(data["x0"])).encode()
        for node in nodes:
            node.handle(Message("start", keys.start, start, 0.0))
        for k in range(3):
            for i, node in enumerate(nodes):
                z = np.array(data["z"][k][i])
                node.handle(Message("meas", keys.meas(i), Measurement(k, 0.1 * k, i, z, None, 0.0).encode(), 0.0))
                node.advance()
            while sent:
                i, ch, payload = sent.pop(0)
                if ch == "prior":
                    for node in nodes:
                        if i in node.payload.tracker.neighbours:
                            node.handle(Message("prior", keys.prior(i), payload, 0.0))
                            node.advance()
        after = sorted(m for m in sys.modules if m.startswith("scipy"))
        print(json.dumps({"before": before, "after": after, "steps": [n.payload.counters.steps for n in nodes],
                          "fused": [n.payload.state.last_fused for n in nodes], "gated": [n.payload.counters.gated for n in nodes]}))
    """, data, *paths)
    assert result["steps"] == [3, 3, 3] and result["fused"] == [3, 3, 3] and result["gated"] == [0, 0, 0], result
    assert result["after"] == result["before"], ("SciPy modules loaded by the first steps", result["after"])
    assert "scipy.linalg._flapack" not in result["after"]
    assert "scipy.linalg" not in result["after"] and not loaded(result["after"], ("scipy.special", "scipy.stats"))


def test_registries_list_names_in_one_order_whatever_was_imported_first():
    script = """
        import json
        import zentrack.fusion.filters.srcif  # a discovered filter, imported before any built-in
        from zentrack.fusion.filters import FILTER_REGISTRY
        from zentrack.fusion.rules import RULE_REGISTRY
        FILTER_REGISTRY.entry("pda-pf")
        RULE_REGISTRY.entry("hcmci")
        print(json.dumps([FILTER_REGISTRY.names(), RULE_REGISTRY.names()]))
    """
    filters, rules = fresh(script)
    assert tuple(filters) == FILTER_ORDER and tuple(rules) == RULE_ORDER
    from zentrack.fusion.filters import FILTER_REGISTRY, LOCAL_FILTERS
    from zentrack.fusion.rules import FUSION_RULES

    # in this process a plug-in another test loaded may follow them (plug-ins come last)
    assert LOCAL_FILTERS[: len(FILTER_ORDER)] == FILTER_ORDER and FUSION_RULES[: len(RULE_ORDER)] == RULE_ORDER
    # every module a name is expected from registers that name (a wrong expectation would cost a search)
    for name, module in FILTER_REGISTRY._expected.items():
        assert FILTER_REGISTRY.entry(name).factory.__module__ == module, name


def test_asking_for_a_name_imports_its_module_alone():
    script = """
        import json, sys
        from zentrack.fusion.filters import FILTER_REGISTRY
        from zentrack.fusion.rules import RULE_REGISTRY
        before = "zentrack.fusion.filters.seckf" in sys.modules
        FILTER_REGISTRY.entry("lin")
        known = "ci3" in RULE_REGISTRY  # not named anywhere but its own file: found by discovery
        print(json.dumps({"before": before, "known": known, "modules": sorted(sys.modules)}))
    """
    result = fresh(script)
    assert not result["before"] and result["known"]
    modules = result["modules"]
    assert "zentrack.fusion.filters.seckf" in modules
    assert loaded(modules, ("zentrack.fusion.filters.extended_state", "zentrack.fusion.filters.pda_common",
                            "zentrack.fusion.filters.mem")) == []


def test_lapack_without_scipy_linalg_is_scipys_lapack():
    script = """
        import json, sys
        import numpy as np
        from zentrack.fusion.linalg import lapack
        rng = np.random.default_rng(3)
        a = rng.standard_normal((7, 7)); m = a @ a.T + 7 * np.eye(7); b = rng.standard_normal(7)
        low = lapack.dpotrf(m, lower=1, clean=1)[0]
        ours = [low.tolist(), lapack.dpotrs(low, b, lower=1)[0].tolist(), lapack.dtrtrs(low, b, lower=1)[0].tolist()]
        alone = "scipy.linalg" not in sys.modules
        from scipy.linalg import lapack as public
        same = all(getattr(lapack, f) is getattr(public, f) for f in ("dpotrf", "dpotrs", "dtrtrs"))
        low2 = public.dpotrf(m, lower=1, clean=1)[0]
        theirs = [low2.tolist(), public.dpotrs(low2, b, lower=1)[0].tolist(), public.dtrtrs(low2, b, lower=1)[0].tolist()]
        print(json.dumps({"alone": alone, "same": same, "equal": ours == theirs}))
    """
    assert fresh(script) == {"alone": True, "same": True, "equal": True}


def test_the_model_registry_keeps_the_scenario_names_and_checks():
    import numpy as np

    from zentrack.fusion import models
    from zentrack.fusion.measurement import BearingModel, LinearModel, PointModel
    from zentrack.fusion.motion import ContinuousCV3D, Exp1Plant, ManeuveringCV3D
    from zentrack.truth.simulation import scenario, scenario_spec

    assert models.PLANTS == ("exp1", "cv3d", "cv3d-cd", "ca9", "ship-turn", "ship-power", "eot")
    assert models.MEASUREMENTS == ("bearing", "point", "linear", "extent-ellipse", "extent-rectangle")
    assert models.NONLINEAR_TRUTH == ("ship-turn", "ship-power")
    assert models.PLANT_PARAMS == {
        "exp1": ("q", "d_amp", "d_freq"), "cv3d": ("sigma_w", "alpha", "beta", "turn_rate"), "cv3d-cd": ("q", "em_steps"),
        "ca9": ("sigma_w",), "ship-turn": ("a_m", "k_psi"), "ship-power": ("power", "eta", "mass"),
        "eot": ("q_pos", "q_vel", "q_alpha", "q_l1", "q_l2")}
    assert not hasattr(scenario, "PLANT_PARAMS") and not hasattr(scenario_spec, "PLANT_PARAMS")  # one name: the registry's
    for name in models.PLANTS:
        assert models.make_plant(name, 0.5, {}).ts == 0.5
    plant = models.make_plant("exp1", 0.2, {"q": 0.3})
    assert isinstance(plant, Exp1Plant) and np.array_equal(plant.Q, 0.3 * np.eye(2))
    assert isinstance(models.make_plant("cv3d", 0.1, {"sigma_w": 2.0}), ManeuveringCV3D)
    cd = models.make_plant("cv3d-cd", 1.0, {"em_steps": 4.0})
    assert isinstance(cd, ContinuousCV3D) and cd.em_steps == 4 and type(cd.em_steps) is int
    with pytest.raises(ValueError, match="unknown plant 'boat'"):
        models.make_plant("boat", 0.1, {})
    with pytest.raises(ValueError, match=r"has no parameter\(s\) \['wings'\]"):
        models.make_plant("exp1", 0.1, {"wings": 2.0})
    with pytest.raises(ValueError, match="must be finite"):
        models.make_plant("ca9", 0.1, {"sigma_w": float("nan")})
    assert isinstance(models.make_measurement("bearing"), BearingModel)
    assert isinstance(models.make_measurement("point"), PointModel)
    assert isinstance(models.make_measurement("linear", np.eye(2, 6)), LinearModel)
    with pytest.raises(ValueError, match="needs linear_matrix"):
        models.make_measurement("linear")
    with pytest.raises(ValueError, match="unknown measurement 'sonar'"):
        models.make_measurement("sonar")
    assert type(models.make_measurement("extent-ellipse")).__name__ == "ExtentPointModel"


def test_scenario_flags_parse_as_before_without_the_scenario_catalogue():
    import argparse

    from zentrack.common import argtypes
    from zentrack.config import node_config, scenario_config, scenario_flags

    for name in ("steps_int", "nodes_int", "seed_int", "qbar_float", "theta_float", "fusion_param"):
        assert getattr(scenario_flags, name) is getattr(argtypes, name), name  # one module of argument types
    assert argtypes.qbar_float.__name__ == "qbar"
    assert (scenario_config.BOUNDS["filter.qbar"], scenario_config.BOUNDS["filter.theta"]) == \
        (argtypes.QBAR_RANGE, argtypes.THETA_RANGE)  # a flag takes what its TOML key takes
    assert node_config.MODES == scenario_config.MODES
    p = argparse.ArgumentParser()
    scenario_flags.add_scenario_arguments(p)
    args = p.parse_args(["--nodes", "7", "--steps", "20", "--seed", "3", "--qbar", "1e-5", "--fusion-param", "omega=2"])
    assert (args.nodes, args.steps, args.seed, args.qbar, args.fusion_param) == (7, 20, 3, 1e-5, [("omega", 2)])
    with pytest.raises(SystemExit):
        p.parse_args(["--nodes", "0"])


@pytest.mark.slow
def test_bench_startup_reports_every_figure(tmp_path):
    out = tmp_path / "startup.json"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "bench", "startup", "--repeat", "1", "--kinds",
                           "tracker,router", "--settle", "0.2", "--json", str(out)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "start to ready s" in proc.stdout and "target for an idle tracker" in proc.stdout
    doc = json.loads(out.read_text())
    assert set(doc["results"]) == {"tracker", "router"}
    for figures in doc["results"].values():
        assert 0 < figures["start_s"]["median"] < 60 and 10 < figures["rss_mb"]["median"] < 1000
        assert figures["threads"]["min"] >= 1
    assert 0 < doc["tracker_import_s"]["median"] < 10


def test_a_running_tracker_maps_no_openssl_and_no_scipy_lapack(tmp_path):
    """A tracker process that is up (its filter built, numpy.random imported, its Zenoh session open) has not
    mapped OpenSSL's libcrypto (3.4 MB resident, for nothing a tracker does) nor SciPy's LAPACK and OpenBLAS
    (3.9 MB: numpy's LAPACK does a tracker's factorisations); Python's hashlib still works in such a process,
    on CPython's built-in hashes."""
    import os
    import signal
    import time

    from zentrack.config.node_config import RunParameters
    from zentrack.config.node_slice import node_config_from_spec
    from zentrack.config.scenario_config import builtin_spec

    cfg = node_config_from_spec(builtin_spec("exp2", nodes=4, steps=10), 0.1, 0, 0, RunParameters())
    path = cfg.save(tmp_path / "node-0.json")
    log = tmp_path / "node.log"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "zentrack", "node", "--id", "0", "--node-config", str(path),
                                 "--run", f"lean{os.getpid()}", "--listen", "tcp/127.0.0.1:0"],
                                stdout=subprocess.DEVNULL, stderr=err)
    try:
        deadline = time.monotonic() + 60
        while "node 0 up" not in log.read_text():
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        maps = open(f"/proc/{proc.pid}/maps").read()
        assert "zenoh" in maps and "_multiarray_umath" in maps  # the process is a tracker's, fully loaded
        assert "libcrypto" not in maps
        assert "_flapack" not in maps and "scipy_openblas-" not in maps  # SciPy's LAPACK and OpenBLAS (numpy's: _64_)
        assert "_generator.cpython" not in maps  # numpy.random: its filter (teskf) draws nothing
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert fresh("""
        import json, sys
        from zentrack.common.procs import without_openssl
        without_openssl()
        import numpy.random, hashlib, hmac
        print(json.dumps({"sha": hashlib.sha256(b"zentrack").hexdigest(), "hmac": hmac.new(b"k", b"m", "sha256").hexdigest(),
                          "libcrypto": "libcrypto" in open("/proc/self/maps").read()}))
    """) == {"sha": __import__("hashlib").sha256(b"zentrack").hexdigest(),
             "hmac": __import__("hmac").new(b"k", b"m", "sha256").hexdigest(), "libcrypto": False}


def test_a_deferred_generator_draws_what_numpys_draws_and_is_made_only_when_used():
    result = fresh("""
        import json, sys
        import numpy as np
        from types import SimpleNamespace
        from zentrack.config.node_config import NodeConfig, deferred_generator
        rng = NodeConfig.rng(SimpleNamespace(seed=7, node=3))  # a slice's generator: SeedSequence([seed, node])
        before = "numpy.random" in sys.modules
        ours = rng.standard_normal(4).tolist() + [float(deferred_generator(0).random())]
        theirs = np.random.default_rng(np.random.SeedSequence([7, 3])).standard_normal(4).tolist()
        theirs.append(float(np.random.default_rng(0).random()))
        print(json.dumps({"before": before, "same": ours == theirs}))
    """)
    assert result == {"before": False, "same": True}
