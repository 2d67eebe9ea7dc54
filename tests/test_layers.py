"""The package is layered, nothing imports upwards and nothing imports in a circle (docs/architecture.md,
"Packages and layers"):

    fusion (what a tracker computes) < truth.simulation < common < transport < config
        < processes (node, truth, viewer) | study < cluster, bench < cli

Every import statement of every module (module level, inside functions and under ``TYPE_CHECKING``) is read
with ``ast``. An import of a higher layer, of a sibling process package (or of the study tools from a process,
or the other way round) fails; so does a module whose package has no layer of its own, and any cycle in the
graph of these imports (a strongly connected component of more than one module, or a module importing
itself). The tracker (``zentrack.node``) sits above ``truth.simulation`` only so that the configuration can
parse scenarios: nothing it imports, directly or through any chain of these imports, may be the simulation, the
study tools or the benches. Within the cluster layer, its rooms (deployment < engines < recording < run < soak)
import only themselves and the rooms before them, and the evaluator of a live run (recording, run) imports no
study tool. A further test imports each module in a fresh interpreter.
"""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from import_graph import (
    LAYERS,
    NOT_IN_A_TRACKER,
    PROCESS_LAYER,
    ROOT,
    TRACKER,
    cycles,
    import_chains,
    import_graph,
    imports_of,
    in_package,
    layer_of,
    module_name,
    modules,
    resolve,
)


def test_every_module_is_in_a_layer_and_the_map_is_complete():
    mods = modules()
    assert len(mods) > 40
    missing = []
    for name in mods:
        try:
            layer_of(name)
        except KeyError as exc:
            missing.append(str(exc))
    assert not missing, "\n".join(missing)
    for prefix in LAYERS:
        assert prefix in mods, f"package {prefix} is missing"


def test_no_import_cycle():
    found = cycles(import_graph(modules()))
    assert not found, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in found)


def test_the_cycle_check_finds_a_cycle_and_a_package_without_a_layer():
    """The checker itself: a three-module circle, a self import and an unlayered package are reported."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}, "f": set()}
    assert cycles(graph) == [["a", "b", "c"], ["e"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
    with pytest.raises(KeyError, match="no layer"):
        layer_of("zentrack.newpackage.module")


def test_no_module_imports_a_higher_layer_or_a_sibling_process():
    problems = []
    mods = modules()
    for name, path in mods.items():
        mine, my_pkg = layer_of(name)
        for line, target in imports_of(path, name):
            theirs, their_pkg = layer_of(resolve(target, mods))
            if theirs > mine:
                problems.append(f"{path.relative_to(ROOT)}:{line}: {name} (layer {mine}) imports {target} (layer {theirs})")
            elif mine == theirs == PROCESS_LAYER and my_pkg != their_pkg:
                problems.append(f"{path.relative_to(ROOT)}:{line}: process {my_pkg} imports process {their_pkg}")
    assert not problems, "\n".join(problems)


def test_the_layer_check_catches_an_upward_import(tmp_path):
    """The checker itself: a transport module importing cluster tooling is reported."""
    fake = ROOT / "zentrack" / "transport" / "wire.py"
    tree_src = "from zentrack.cluster.run.cluster import Cluster\nfrom ..cluster import soak\n"
    probe = tmp_path / "wire.py"
    probe.write_text(tree_src)
    found = [layer_of(resolve(t, modules()))[0] for _, t in imports_of(probe, module_name(fake))]
    assert found == [LAYERS["zentrack.cluster"]] * 2 and layer_of(module_name(fake))[0] == LAYERS["zentrack.transport"]


def test_a_tracker_imports_no_simulation_study_or_bench():
    """``zentrack.node`` sits above ``zentrack.truth.simulation`` (layer 5 over 1), so the layer order alone would
    let a tracker import the simulator: no module of it may import the simulation, the study tools or the benches,
    directly or through any chain of imports (every import statement: module level, in functions, under
    ``TYPE_CHECKING``). A tracker reads its slice (``zentrack.config.node_config``); cutting one from a scenario is
    ``zentrack.config.node_slice``, which only the command line (``zentrack.cli.node_command``) imports."""
    mods = modules()
    starts = sorted(name for name in mods if in_package(name, TRACKER))
    assert len(starts) > 10
    chains = import_chains(import_graph(mods), starts)
    problems = [" -> ".join(chain) for name, chain in sorted(chains.items()) if in_package(name, NOT_IN_A_TRACKER)]
    assert not problems, "the tracker imports what no tracker may load:\n" + "\n".join(problems)


def test_the_tracker_check_follows_chains_and_parent_packages():
    """The checker itself: an import through another layer, and a package's ``__init__``, are followed."""
    graph = {"zentrack.node.a": {"zentrack.config.x"}, "zentrack.config.x": {"zentrack.truth.simulation.s"},
             "zentrack.truth.simulation.s": set(), "zentrack.node.b": {"zentrack.transport.y"},
             "zentrack.transport": {"zentrack.study.z"}, "zentrack.transport.y": set(), "zentrack.study.z": set()}
    chains = import_chains(graph, ["zentrack.node.a", "zentrack.node.b"])
    assert chains["zentrack.truth.simulation.s"] == ["zentrack.node.a", "zentrack.config.x",
                                                     "zentrack.truth.simulation.s"]
    assert chains["zentrack.study.z"] == ["zentrack.node.b", "zentrack.transport.y", "zentrack.transport",
                                          "zentrack.study.z"]
    assert in_package("zentrack.bench", NOT_IN_A_TRACKER)
    assert not in_package("zentrack.truth.process", NOT_IN_A_TRACKER)


#: the rooms of the cluster tooling (one layer), lowest first: a room imports only itself and the rooms before it
CLUSTER_ROOMS = ("zentrack.cluster.deployment", "zentrack.cluster.engines", "zentrack.cluster.recording",
                 "zentrack.cluster.run", "zentrack.cluster.soak")
#: rooms that import no study tool: the evaluator of a live run judges with the fusion and simulation layers
NO_STUDY_ROOMS = ("zentrack.cluster.recording", "zentrack.cluster.run")


def room_of(name: str) -> int | None:
    """The index of ``name``'s room in :data:`CLUSTER_ROOMS`; None outside them."""
    return next((i for i, room in enumerate(CLUSTER_ROOMS) if name == room or name.startswith(room + ".")), None)


def room_problems(name: str, targets: list[tuple[int, str]], mods: dict[str, Path]) -> list[str]:
    """What is wrong with the imports ``targets`` of the cluster module ``name``: a module in no room, a room
    importing a later room, a study tool imported where :data:`NO_STUDY_ROOMS` forbids it."""
    mine = room_of(name)
    if mine is None:
        return [f"{name}: in no room of the cluster (CLUSTER_ROOMS)"]
    problems = []
    for line, target in targets:
        module = resolve(target, mods)
        theirs = room_of(module)
        if theirs is not None and theirs > mine:
            problems.append(f"{name}:{line}: room {CLUSTER_ROOMS[mine]} imports the later room's {module}")
        if module.startswith("zentrack.study") and CLUSTER_ROOMS[mine] in NO_STUDY_ROOMS:
            problems.append(f"{name}:{line}: {CLUSTER_ROOMS[mine]} imports the study tools' {module}")
    return problems


def test_the_cluster_rooms_import_only_earlier_rooms_and_the_recorders_no_study_tool():
    mods = modules()
    problems = []
    for name, path in mods.items():
        if name.startswith("zentrack.cluster."):
            problems += room_problems(name, imports_of(path, name), mods)
    assert not problems, "\n".join(problems)


def test_the_room_check_catches_a_later_room_a_study_import_and_a_module_without_a_room():
    """The checker itself: a recording module importing the soak and the batched simulator is reported twice;
    a module beside the rooms once."""
    mods = modules()
    found = room_problems("zentrack.cluster.recording.recorder",
                          [(1, "zentrack.cluster.soak.fault_kinds.KINDS"), (2, "zentrack.study.simulator.evaluate"),
                           (3, "zentrack.cluster.deployment.compose.render"), (4, "zentrack.common.report")], mods)
    assert len(found) == 2 and "later room" in found[0] and "study" in found[1], found
    assert room_problems("zentrack.cluster.soak.command", [(1, "zentrack.study.simulator")], mods) == []
    assert "no room" in room_problems("zentrack.cluster.loose", [], mods)[0]


def test_fusion_imports_only_numpy_scipy_and_itself():
    allowed = {"numpy", "scipy", "__future__", "abc", "dataclasses", "collections", "typing", "math", "functools",
               "itertools", "heapq", "importlib", "pkgutil", "enum", "types", "inspect", "warnings", "zentrack"}
    bad = []
    for name, path in modules().items():
        if not name.startswith("zentrack.fusion"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                tops = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                tops = [(node.module or "").split(".")[0]]
            else:
                continue
            bad += [f"{name}: {t}" for t in tops if t not in allowed]
    assert not bad, bad


#: third-party packages the import check's parent loads once before it forks a child per module: their own import
#: order is not what the check is about, and loading them in each of ~270 interpreters cost ~300 s of CPU per
#: suite (beside real-time tests). Rerun is left to the children (it starts threads, which a fork must not copy);
#: so is every module of this project: the parent imports none (checked), so a child's imports of the project
#: run in that module's own order, as in a fresh interpreter.
PRELOADED = ("numpy", "scipy.linalg", "scipy.optimize", "scipy.special", "scipy.stats", "scipy.sparse",
             "scipy.sparse.csgraph", "scipy.interpolate", "msgpack", "zenoh", "matplotlib")
_IMPORT_EACH = """
import importlib, os, sys
os.environ.setdefault("MPLBACKEND", "Agg")
for name in sys.argv[2].split(","):
    importlib.import_module(name)
own = sorted(m for m in sys.modules if m.split(".")[0] in sys.argv[3].split(","))
if own:
    sys.exit(f"the parent imported modules of the project: {own[:5]}")
bad = []
for name in sys.argv[1].split(","):
    sys.stdout.flush(); sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        try:
            importlib.import_module(name)
        except BaseException as e:
            print(f"{name}: {type(e).__name__}: {e}", flush=True)
            os._exit(1)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        bad.append(name)
print("failed: " + ",".join(bad) if bad else "ok", flush=True)
sys.exit(1 if bad else 0)
"""


@pytest.mark.slow
@pytest.mark.cpu_only  # (each child a process of the worker's session)
def test_every_module_imports_alone_in_a_fresh_interpreter():
    """Each module imported by itself, in a child forked from a parent that holds the third-party packages
    (:data:`PRELOADED`) and no module of this project."""
    names = sorted(n for n in modules() if n != "zentrack.__main__")
    packages = sorted({n.split(".")[0] for n in names})
    halves = [names[i::2] for i in range(2)]  # one parent per core

    def import_each(chunk: list[str]) -> str | None:
        proc = subprocess.run([sys.executable, "-c", _IMPORT_EACH, ",".join(chunk), ",".join(PRELOADED),
                               ",".join(packages)], capture_output=True, text=True, timeout=600,
                              env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
        return None if proc.returncode == 0 else proc.stdout + proc.stderr[-2000:]

    with ThreadPoolExecutor(max_workers=2) as pool:
        failures = [f for f in pool.map(import_each, halves) if f is not None]
    assert len(names) > 50 and not failures, "\n".join(failures)
