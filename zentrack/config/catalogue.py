"""The scenario catalogue: every built-in scenario is one TOML file in ``deploy/scenarios/`` (installed as the
package ``zentrack.scenarios``), and every command reads it from here (``zentrack scenarios`` lists it).

Lean on purpose (the standard library only, TOML read on demand): a tracker's ``--help`` names the catalogue
without importing the scenario configuration (:mod:`zentrack.config.scenario_config` validates the files).
A scenario argument that contains no ``/`` and does not end in ``.toml`` is a catalogue name; anything else
is a path.
"""
from __future__ import annotations

import argparse
import tomllib
from importlib import resources
from importlib.resources.abc import Traversable

from zentrack.common.suggest import close_match, names_chosen_by

PACKAGE = "zentrack.scenarios"
#: the scenario a command uses when none is named
DEFAULT_SCENARIO = "exp2"


def _files() -> dict[str, Traversable]:
    return {p.name[:-5]: p for p in resources.files(PACKAGE).iterdir() if p.name.endswith(".toml")}


def names() -> list[str]:
    """Every catalogue scenario's name, sorted."""
    return sorted(_files())


def is_path(name_or_path: str) -> bool:
    """Whether a scenario argument is a file path rather than a catalogue name."""
    return "/" in name_or_path or name_or_path.endswith(".toml")


def text(name: str) -> str | None:
    """The TOML text of catalogue scenario ``name`` (None: no such scenario)."""
    found = _files().get(name)
    return found.read_text() if found is not None else None


def description(name: str) -> str:
    """The one-line ``[scenario] description`` of catalogue scenario ``name`` ("" when it has none)."""
    doc = tomllib.loads(text(name) or "")
    value = doc.get("scenario", {}).get("description", "")
    return " ".join(value.split()) if isinstance(value, str) else ""


def listing() -> list[tuple[str, str]]:
    """``(name, description)`` of every catalogue scenario, sorted by name."""
    return [(n, description(n)) for n in names()]


def help_text(default: str | None = DEFAULT_SCENARIO) -> str:
    """What a ``--scenario`` flag's help says: a catalogue name (listed once, by ``zentrack scenarios``) or a path,
    and the default."""
    tail = f" (default {default})" if default else ""
    return f"a catalogue scenario (`zentrack scenarios` lists them) or a TOML path{tail}"


def unknown_scenario(value: str) -> str:
    """Why ``value`` names no scenario, with the nearest catalogue name when one is near, and the catalogue."""
    near = close_match(value, names())
    return (f"unknown scenario {value!r}{f' (did you mean {near!r}?)' if near else ''}: the catalogue has "
            f"{', '.join(names())} (`zentrack scenarios`), or give a path to a .toml file")


def scenario_arg(value: str) -> str:
    """An argparse type: a catalogue name or a path (a name not in the catalogue is refused, with the nearest)."""
    if not is_path(value) and value not in _files():
        raise argparse.ArgumentTypeError(unknown_scenario(value))
    return value


scenario_arg.__name__ = "scenario"
names_chosen_by(scenario_arg, names)


def scenario_list(value: str) -> str:
    """An argparse type: comma-separated catalogue names or paths, each checked as :func:`scenario_arg` does
    (the text is returned as given)."""
    for name in [v.strip() for v in value.split(",")]:
        scenario_arg(name)
    return value


scenario_list.__name__ = "scenarios"
names_chosen_by(scenario_list, names)
