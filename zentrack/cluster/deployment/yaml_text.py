"""The YAML of the generated compose and stack files, written without a YAML library: block mappings and lists,
scalars as JSON (valid YAML flow scalars), lists of scalars in flow style on their key's line."""
from __future__ import annotations

import json
import re


def yaml_text(value, indent: int = 0) -> str:
    """``value`` (dicts, lists, scalars) as block YAML at ``indent`` levels of two spaces."""
    pad = "  " * indent
    if isinstance(value, dict):
        lines = []
        for k, v in value.items():
            if isinstance(v, (dict, list)) and v:
                lines.append(f"{pad}{k}:\n{yaml_text(v, indent + 1)}")
            else:
                lines.append(f"{pad}{k}: {_scalar(v)}")
        return "\n".join(lines)
    if isinstance(value, list) and all(not isinstance(v, (dict, list)) for v in value):
        return pad + "[" + ", ".join(_scalar(v) for v in value) + "]"
    return "\n".join(f"{pad}- {_scalar(v)}" for v in value)


def _scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, dict) and not v:
        return "{}"
    return json.dumps(v)  # JSON strings are valid YAML flow scalars


def flow_lists(text: str) -> str:
    """Lists of scalars under a key print in flow style on the key's line."""
    return re.sub(r":\n +\[", ": [", text)
