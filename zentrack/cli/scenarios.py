"""``zentrack scenarios``: the scenario catalogue (``deploy/scenarios/``), one line per scenario; ``--keys``: every
key a scenario file may hold (:mod:`zentrack.config.scenario_schema`)."""
from __future__ import annotations

import argparse
import json

from zentrack.config import catalogue


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print {name: description} as JSON instead of text")
    p.add_argument("--keys", action="store_true",
                   help="print every key a scenario file may hold, section by section (Markdown: docs/scenario-keys.md)")


def run(args: argparse.Namespace) -> int:
    if args.keys:
        from zentrack.config.scenario_schema import keys_markdown

        print(keys_markdown(), end="")
        return 0
    listing = catalogue.listing()
    if args.json:
        print(json.dumps(dict(listing), indent=2))
        return 0
    width = max(len(name) for name, _ in listing)
    for name, text in listing:
        print(f"{name:<{width}}  {text}")
    print("every command takes these names (--scenario NAME) or the path of a TOML file")
    return 0
