"""The import graph of the package, read with ``ast`` (tests/test_layers.py): every module's name and layer, its
zentrack imports (relative ones resolved), the graph's cycles and the chains that lead from a package to a module."""
from __future__ import annotations

import ast
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: folder -> import prefix: every top-level folder of pyproject's package-dir (so a new package is read too)
FOLDERS = {folder: name for name, folder in
           tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].items()
           if "/" not in folder}
#: import prefix -> layer (the longest matching prefix wins; a module no prefix matches fails the test)
LAYERS = {
    "zentrack.fusion": 0,
    "zentrack.truth.simulation": 1,
    "zentrack.common": 2,
    "zentrack.transport": 3,
    "zentrack.config": 4,
    "zentrack.node": 5, "zentrack.truth": 5, "zentrack.viewer": 5, "zentrack.study": 5,
    "zentrack.cluster": 6, "zentrack.bench": 6,
    "zentrack.cluster.deployment": 6, "zentrack.cluster.engines": 6, "zentrack.cluster.recording": 6,
    "zentrack.cluster.run": 6, "zentrack.cluster.soak": 6,
    "zentrack.cli": 7, "zentrack.__main__": 7,
}
#: the package root itself (``zentrack/__init__.py``: only ``__version__``), below everything that imports it
ROOT_MODULE, ROOT_LAYER = "zentrack", 0
#: one layer whose packages do not import each other: the processes and the study tools
PROCESS_LAYER = 5
PROCESSES = ("zentrack.node", "zentrack.truth", "zentrack.viewer", "zentrack.study")
#: the tracker process's package, and what nothing it imports (directly or through other modules) may be
TRACKER = "zentrack.node"
NOT_IN_A_TRACKER = ("zentrack.truth.simulation", "zentrack.study", "zentrack.bench")


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
    """(layer, the prefix that gave it); KeyError for a module of a package without a layer."""
    if name == ROOT_MODULE:
        return ROOT_LAYER, ROOT_MODULE
    matching = [p for p in LAYERS if name == p or name.startswith(p + ".")]
    if not matching:
        raise KeyError(f"{name}: no layer in tests/test_layers.py LAYERS (give its package one)")
    best = max(matching, key=len)
    return LAYERS[best], best


def resolve(target: str, mods: dict[str, Path]) -> str:
    """The module an import names: ``zentrack.x.mod.Class`` -> ``zentrack.x.mod`` (unchanged if none is known)."""
    name = target
    while name not in mods and "." in name:
        name = name.rpartition(".")[0]
    return name if name in mods else target


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the modules of the package it imports (``from pkg import name``: ``pkg.name`` when that is a
    module, else ``pkg``)."""
    graph = {}
    for name, path in mods.items():
        targets = {resolve(target, mods) for _, target in imports_of(path, name)}
        graph[name] = {t for t in targets if t in mods}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected component with more than one module, and every module importing itself
    (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in graph[node]:
                    found.append(sorted(component))
    return found


def in_package(name: str, prefixes: str | tuple[str, ...]) -> bool:
    """Whether module ``name`` is one of ``prefixes`` or inside one of them."""
    packages = (prefixes,) if isinstance(prefixes, str) else prefixes
    return any(name == p or name.startswith(p + ".") for p in packages)


def import_chains(graph: dict[str, set[str]], starts: list[str]) -> dict[str, list[str]]:
    """Every module that importing ``starts`` can bring in (breadth first over ``graph``; importing a module runs
    its parent packages' ``__init__`` too), each with one shortest chain of imports from a start to it."""
    chains = {start: [start] for start in starts}
    queue = list(starts)
    while queue:
        name = queue.pop(0)
        parts = name.split(".")
        parents = {".".join(parts[:k]) for k in range(1, len(parts))} & set(graph)
        for target in sorted(graph.get(name, set()) | parents):
            if target not in chains:
                chains[target] = [*chains[name], target]
                queue.append(target)
    return chains


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
                # ``from zentrack.transport import wire`` names the module zentrack.transport.wire (see resolve)
                out += [(node.lineno, f"{target}.{a.name}") for a in node.names]
    return out
