"""Named component registries: filters and fusion rules are found by name, with validated parameters.

A :class:`Registry` maps a name to a factory, a one-line summary and the :class:`Param` list the factory
accepts.  :meth:`Registry.create` checks every parameter (name, type, bounds, choices) before calling the
factory, so a configuration error names the parameter, the value and the allowed range instead of failing
deep inside the maths.

Components register when their module is imported, and a registry imports a module only when it is asked
for a name that module provides: :meth:`Registry.expect` tells it which module registers which names (a
tracker that runs ``teskf`` and ``ci`` imports those two modules and no other filter or rule).  A registry
built with ``discover="pkg"`` also finds what no one told it about: asked for a name it does not know, it
imports the package's modules (``pkgutil``) one by one until the name appears, and listing its names imports
them all, so dropping a file into ``fusion/filters/`` or ``fusion/rules/`` registers a new component without
editing any other file.  Whatever order the modules were imported in, :meth:`Registry.names` lists the
expected built-ins first, then the package's modules in file-name order, then anything else (plug-ins) as it
registered.  :func:`load_plugins` imports modules from elsewhere by dotted name.
"""
from __future__ import annotations

import importlib
import math
import pkgutil
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Generic, TypeVar

import numpy as np

T = TypeVar("T")

PARAM_TYPES = (int, float, str, bool)


@dataclass(frozen=True)
class Param:
    """One parameter of a component: its type, default, bounds or choices, and a help text.

    ``lo``/``hi`` bound numbers (inclusive unless ``lo_open``/``hi_open``); ``choices`` lists the allowed
    values; a ``default`` of ``None`` means the value may be ``None`` ("automatic").
    """

    name: str
    type: type
    default: Any = None
    lo: float | None = None
    hi: float | None = None
    choices: tuple[Any, ...] | None = None
    help: str = ""
    lo_open: bool = False
    hi_open: bool = False
    #: words accepted besides values of ``type`` (e.g. ``("auto",)`` for a number the runtime works out)
    keywords: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.type not in PARAM_TYPES:
            raise ValueError(f"parameter {self.name!r}: type must be one of int, float, str, bool, got {self.type!r}")
        if self.default is not None:
            self.check(self.default, "default")

    def allowed(self) -> str:
        """The allowed range as text, e.g. ``0 < qbar <= 1``, ``rounds >= 1``, ``kind in ('a', 'b')``."""
        parts = []
        if self.choices is not None:
            parts.append(f"{self.name} in {tuple(self.choices)!r}")
        lo_op = "<" if self.lo_open else "<="
        hi_op = "<" if self.hi_open else "<="
        lo, hi = _num(self.lo), _num(self.hi)
        if self.lo is not None and self.hi is not None:
            parts.append(f"{lo} {lo_op} {self.name} {hi_op} {hi}")
        elif self.lo is not None:
            parts.append(f"{self.name} {'>' if self.lo_open else '>='} {lo}")
        elif self.hi is not None:
            parts.append(f"{self.name} {hi_op} {hi}")
        if not parts:
            parts.append(f"any {self.type.__name__}")
        text = " and ".join(parts)
        if self.keywords:
            text += "".join(f" or {k!r}" for k in self.keywords)
        return text + " or None" if self.default is None else text

    def describe(self) -> str:
        return f"{self.name} ({self.type.__name__}, default {self.default!r}, {self.allowed()})"

    def check(self, value: Any, owner: str = "") -> Any:
        """The validated value (ints and floats normalised to Python numbers); ValueError otherwise."""
        where = f"{owner}: " if owner else ""
        problem = f"{where}parameter {self.name!r} must be {self.type.__name__} ({self.allowed()}), got {value!r}"
        if value is None:
            if self.default is None:
                return None
            raise ValueError(problem)
        if isinstance(value, str) and value in self.keywords:
            return value
        value = self._coerce(value, problem)
        if self.choices is not None and value not in self.choices:
            raise ValueError(problem)
        if self.type in (int, float):
            if self.type is float and not math.isfinite(value):
                raise ValueError(problem)
            if self.lo is not None and (value < self.lo or (self.lo_open and value == self.lo)):
                raise ValueError(problem)
            if self.hi is not None and (value > self.hi or (self.hi_open and value == self.hi)):
                raise ValueError(problem)
        return value

    def _coerce(self, value: Any, problem: str) -> Any:
        is_bool = isinstance(value, (bool, np.bool_))
        if self.type is bool:
            if not is_bool:
                raise ValueError(problem)
            return bool(value)
        if self.type is str:
            if not isinstance(value, str):
                raise ValueError(problem)
            return value
        if is_bool:
            raise ValueError(problem)
        if self.type is int:
            if not isinstance(value, (int, np.integer)):
                raise ValueError(problem)
            return int(value)
        if not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(problem)
        return float(value)


def _num(v: float | None) -> str:
    """A bound as text: ``0`` rather than ``0.0``, ``1e-06`` as repr writes it."""
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e16:
        return str(int(v))
    return repr(v)


@dataclass(frozen=True)
class Entry(Generic[T]):
    """A registered component: its factory, summary and parameters."""

    name: str
    factory: Callable[..., T]
    params: tuple[Param, ...]
    summary: str
    #: what the component can do beyond its family's contract (e.g. a local filter tagged ``"scans"`` takes
    #: every return of a cluttered scan; one without takes one return per scan)
    tags: frozenset[str] = frozenset()

    def describe(self) -> str:
        params = ", ".join(p.describe() for p in self.params) or "none"
        return f"{self.name}: {self.summary}; params: {params}"


class UnknownName(ValueError):
    """A name (a component's, or one of its parameters') that the registry does not hold: ``word`` and the
    ``choices`` it could have been, so that a caller can suggest the nearest."""

    def __init__(self, message: str, word: str, choices: Sequence[str]) -> None:
        super().__init__(message)
        self.word = word
        self.choices = tuple(choices)


class Registry(Generic[T]):
    """Components of one family (``kind``, e.g. ``"local filter"``) by name.

    ``discover`` is the dotted name of a package whose modules are imported when a name no module was
    :meth:`expect`-ed to register is asked for (:meth:`entry`, :meth:`create`, ``in``: module by module until it
    appears) and when every name is (:meth:`names`, :meth:`describe`, iteration: all of them), so that they
    can register.
    """

    def __init__(self, kind: str, discover: str | None = None) -> None:
        self.kind = kind
        self.discover = discover
        self._entries: dict[str, Entry[T]] = {}
        self._discovered = discover is None
        #: name -> the module expected to register it (imported the first time the name is asked for)
        self._expected: dict[str, str] = {}
        #: modules whose names come first in :meth:`names`, in this order
        self._builtin_modules: list[str] = []
        self._modules: list[str] | None = None  # every module in listing order (built-ins, then the package's)
        self._next_module = 0  # modules[:_next_module] have been imported by the discovery
        self._names: tuple[str, ...] | None = None  # the listing, once every module is imported

    def expect(self, module: str, names: Sequence[str], builtin: bool = False) -> None:
        """``module`` registers ``names``: import it (and nothing else) when one of them is first asked for.
        ``builtin`` modules are imported first by the discovery and their names listed first, in the order
        they are expected; the others take their place among the package's modules. A wrong expectation only
        costs time: a name the module does not register is then searched for by discovery."""
        for name in names:
            self._expected[name] = module
        if builtin and module not in self._builtin_modules:
            self._builtin_modules.append(module)
        self._modules, self._names = None, None

    def register(
        self, name: str, factory: Callable[..., T], params: Sequence[Param] = (), summary: str = "",
        tags: Sequence[str] = (),
    ) -> Callable[..., T]:
        """Add ``name``; the factory is called as ``factory(*context, **validated_params)``."""
        if not name or not isinstance(name, str):
            raise ValueError(f"a {self.kind} needs a non-empty name, got {name!r}")
        old = self._entries.get(name)
        if old is not None and not _same_factory(old.factory, factory):
            raise ValueError(f"{self.kind} {name!r} is already registered (by {_origin(old.factory)})")
        names = [p.name for p in params]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.kind} {name!r}: duplicate parameter names {names}")
        self._entries[name] = Entry(name, factory, tuple(params), summary, frozenset(tags))
        self._names = None
        return factory

    def _module_order(self) -> list[str]:
        """The built-in modules, then every public module of the ``discover`` package in file-name order."""
        if self._modules is None:
            found: list[str] = []
            if self.discover is not None:
                package = importlib.import_module(self.discover)
                found = [f"{self.discover}.{info.name}" for info in pkgutil.iter_modules(getattr(package, "__path__", []))
                         if not info.name.startswith("_")]
            self._modules = [*self._builtin_modules, *(m for m in found if m not in self._builtin_modules)]
        return self._modules

    def _discover_next(self) -> bool:
        """Import the next module of the discovery (False when there is none left)."""
        if self._discovered:
            return False
        modules = self._module_order()
        if self._next_module >= len(modules):
            self._discovered = True
            return False
        module = modules[self._next_module]
        self._next_module += 1  # before importing: a module may query the registry while it loads
        importlib.import_module(module)
        return True

    def _ensure_discovered(self) -> None:
        while self._discover_next():
            pass

    def _find(self, name: object) -> bool:
        """Whether ``name`` is registered, importing its expected module or else discovering until it is."""
        if name in self._entries:
            return True
        if not isinstance(name, str):
            return False
        module = self._expected.get(name)
        if module is not None:
            importlib.import_module(module)
            if name in self._entries:
                return True
        while self._discover_next():
            if name in self._entries:
                return True
        return name in self._entries

    def names(self) -> tuple[str, ...]:
        self._ensure_discovered()
        if self._names is None:
            rank = {m: i for i, m in enumerate(self._module_order())}
            other = len(rank)  # plug-ins from elsewhere: after the package's own, as they registered
            self._names = tuple(sorted(self._entries, key=lambda n: rank.get(self._entries[n].factory.__module__, other)))
        return self._names

    def __contains__(self, name: object) -> bool:
        return self._find(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def entry(self, name: str) -> Entry[T]:
        if not self._find(name):
            raise UnknownName(f"unknown {self.kind} {name!r}; choose one of {', '.join(self.names())}", name, self.names())
        return self._entries[name]

    def params(self, name: str) -> tuple[Param, ...]:
        return self.entry(name).params

    def validate(self, name: str, params: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Every parameter of ``name``: the given ones checked, the others at their defaults."""
        entry = self.entry(name)
        given = dict(params or {})
        known = {p.name: p for p in entry.params}
        for key in given:
            if key not in known:
                allowed = ", ".join(known) or "none"
                raise UnknownName(
                    f"{self.kind} {name!r} has no parameter {key!r} (given {given[key]!r}); its parameters: {allowed}",
                    key, tuple(known))
        return {p.name: p.check(given[p.name], f"{self.kind} {name!r}") if p.name in given else p.default
                for p in entry.params}

    def create(self, name: str, params: Mapping[str, Any] | None = None, *context: Any) -> T:
        """Validate ``params`` and build ``name`` as ``factory(*context, **params)``."""
        values = self.validate(name, params)
        return self._entries[name].factory(*context, **values)

    def describe(self) -> list[str]:
        """One line per component: ``name: summary; params: qbar (float, default 1e-06, qbar > 0), ...``."""
        return [self.entry(n).describe() for n in self.names()]


def _same_factory(a: Callable[..., Any], b: Callable[..., Any]) -> bool:
    """The same factory, or the same definition re-imported (a module reload)."""
    return a is b or (_origin(a) == _origin(b))


def _origin(f: Callable[..., Any]) -> str:
    """Where ``f`` is defined: module, qualified name and first line (lambdas differ by line)."""
    code = getattr(f, "__code__", None)
    line = f":{code.co_firstlineno}" if code is not None else ""
    return f"{getattr(f, '__module__', '?')}.{getattr(f, '__qualname__', repr(f))}{line}"


def load_plugins(modules: Sequence[str]) -> list[ModuleType]:
    """Import extra component modules by dotted name (they register on import); ValueError naming a module
    that does not import."""
    loaded = []
    for name in [modules] if isinstance(modules, str) else modules:
        try:
            loaded.append(importlib.import_module(name))
        except Exception as exc:  # any failure inside the plugin is reported against its name
            raise ValueError(f"plugin module {name!r} does not import: {type(exc).__name__}: {exc}") from exc
    return loaded


def lazy_package_getattr(package: str, namespace: dict[str, Any], listing: str, registry: Registry[Any],
                         lazy: Mapping[str, str]) -> Callable[[str], Any]:
    """A package's module ``__getattr__``: ``listing`` (the registry's names, built-ins first) and the names in
    ``lazy`` (name -> the package's module defining it), each imported on first use and then kept in
    ``namespace`` (the package's globals), so a tracker imports only the components it asks for."""

    def getattr_(name: str) -> Any:
        if name == listing:
            value: Any = registry.names()
        elif name in lazy:
            value = getattr(importlib.import_module(f"{package}.{lazy[name]}"), name)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        namespace[name] = value
        return value

    return getattr_
