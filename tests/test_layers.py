"""The package is layered and nothing imports upwards (DESIGN.md "Layout"):

    fusion (pure maths) < common < transport < config < processes (node, truth, viewer) < cluster, bench < cli

Every import statement of every module (module level and inside functions) is read with ``ast``; an import of
a higher layer, or of a sibling process package, fails. A second test imports each module in a fresh
interpreter, so an import cycle (which only shows in some import orders) cannot hide.
"""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: folder -> import prefix (pyproject's package-dir)
FOLDERS = {"fusion": "zentrack.fusion", "core": "zentrack", "node": "zentrack.node", "truth": "zentrack.truth",
           "viewer": "zentrack.viewer", "bench": "zentrack.bench"}
#: import prefix -> layer (the longest matching prefix wins)
LAYERS = {
    "zentrack.fusion": 0,
    "zentrack.common": 1,
    "zentrack.transport": 2,
    "zentrack.config": 3,
    "zentrack.node": 4, "zentrack.truth": 4, "zentrack.viewer": 4,
    "zentrack.cluster": 5, "zentrack.bench": 5,
    "zentrack.cli": 6, "zentrack.__main__": 6,
    "zentrack": 1,  # the package root holds only __version__
}
PROCESSES = ("zentrack.node", "zentrack.truth", "zentrack.viewer")


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [FOLDERS[rel.parts[0]], *rel.parts[1:]]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    found = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            found[module_name(path)] = path
    return found


def layer_of(name: str) -> tuple[int, str]:
    best = max((p for p in LAYERS if name == p or name.startswith(p + ".")), key=len)
    return LAYERS[best], best


def imports_of(path: Path, name: str) -> list[tuple[int, str]]:
    """(line, absolute module) of every zentrack import in ``path`` (relative imports resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("zentrack")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("zentrack"):
                # ``from zentrack.transport import wire`` imports the module zentrack.transport.wire
                out += [(node.lineno, f"{target}.{a.name}" if target in ("zentrack", "zentrack.transport") else target)
                        for a in node.names]
    return out


def test_every_module_is_in_a_layer_and_the_map_is_complete():
    mods = modules()
    assert len(mods) > 40
    for name in mods:
        layer_of(name)  # raises if a module fits no layer
    for prefix in ("zentrack.common", "zentrack.transport", "zentrack.config", "zentrack.cluster", "zentrack.cli"):
        assert prefix in mods, f"package {prefix} is missing"


def test_no_module_imports_a_higher_layer_or_a_sibling_process():
    problems = []
    for name, path in modules().items():
        mine, my_pkg = layer_of(name)
        for line, target in imports_of(path, name):
            theirs, their_pkg = layer_of(target)
            if theirs > mine:
                problems.append(f"{path.relative_to(ROOT)}:{line}: {name} (layer {mine}) imports {target} (layer {theirs})")
            elif mine == theirs == 4 and my_pkg != their_pkg:
                problems.append(f"{path.relative_to(ROOT)}:{line}: process {my_pkg} imports process {their_pkg}")
    assert not problems, "\n".join(problems)


def test_the_layer_check_catches_an_upward_import(tmp_path):
    """The checker itself: a transport module importing cluster tooling is reported."""
    fake = ROOT / "core" / "transport" / "wire.py"
    tree_src = "from zentrack.cluster.orchestrator import Cluster\nfrom ..cluster import soak\n"
    probe = tmp_path / "wire.py"
    probe.write_text(tree_src)
    found = [layer_of(t)[0] for _, t in imports_of(probe, module_name(fake))]
    assert found == [5, 5] and layer_of(module_name(fake))[0] == 2


def test_fusion_imports_only_numpy_scipy_and_itself():
    allowed = {"numpy", "scipy", "__future__", "abc", "dataclasses", "collections", "typing", "math", "functools",
               "itertools", "importlib", "pkgutil", "enum", "types", "inspect", "warnings", "zentrack"}
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


@pytest.mark.slow
def test_every_module_imports_alone_in_a_fresh_interpreter():
    names = sorted(n for n in modules() if n != "zentrack.__main__")
    script = ("import importlib, sys\nbad = []\nfor n in sys.argv[1:]:\n"
              "    try:\n        importlib.import_module(n)\n"
              "    except Exception as e:\n        bad.append(f'{n}: {type(e).__name__}: {e}')\n"
              "print('\\n'.join(bad)); sys.exit(1 if bad else 0)\n")

    def import_alone(name: str) -> str | None:  # one interpreter per module: the import order is that module's own
        proc = subprocess.run([sys.executable, "-c", script, name], capture_output=True, text=True, timeout=120)
        return None if proc.returncode == 0 else proc.stdout + proc.stderr[-500:]

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:  # independent interpreters, one per core
        failures = [f for f in pool.map(import_alone, names) if f is not None]
    assert len(names) > 50 and not failures, "\n".join(failures)
