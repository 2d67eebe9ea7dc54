"""Generate the wire-protocol reference from the typed messages and the key scheme.

Nothing on the page is typed by hand: the message classes are the frozen dataclasses of
``zentrack.transport.messages``, ``scan_messages``, ``track_messages`` and ``detection_messages`` (fields, types, defaults and
docstrings), the message kind of each is the one its class declares (``@wire_kind``), the key expressions come
from the channels of :mod:`zentrack.transport.keys` with their descriptions from the table in that module's
docstring, and the framing (schema version, size limit, refusal reasons) from
``zentrack.transport.codec``. ``render_page()`` returns the Markdown; the mkdocs hook in ``results_hook.py``
puts it where the page has ``<!-- wire-protocol -->``.
"""
from __future__ import annotations

import dataclasses
import inspect
import re
from types import ModuleType

from zentrack.transport import codec, detection_messages, keys, messages, scan_messages, track_messages

MESSAGE_MODULES: tuple[ModuleType, ...] = (messages, scan_messages, track_messages, detection_messages)
# kinds that travel on another kind's key (a relay shares the forwarded scans' key)
KEY_OF_KIND = {"relay": "scan", "targets": "truth"}
NODE = "<i>"
PREFIX = "zentrack/<run>"


class WireDocError(ValueError):
    """The code and its documentation disagree (a key without a described row, a kind without a key)."""


def message_classes(modules: tuple[ModuleType, ...] = MESSAGE_MODULES) -> list[type]:
    """Every dataclass defined in the message modules, in source order."""
    found: list[type] = []
    for module in modules:
        classes = [c for _, c in inspect.getmembers(module, inspect.isclass)
                   if c.__module__ == module.__name__ and dataclasses.is_dataclass(c)]
        found += sorted(classes, key=lambda c: inspect.getsourcelines(c)[1])
    return found


def kind_of(cls: type) -> str | None:
    """The wire kind a class declares (``@wire_kind``: :data:`zentrack.transport.codec.KINDS`), or None for a part
    of another message."""
    return next((kind for kind, declared in codec.KINDS.items() if declared is cls), None)


def key_expressions() -> dict[str, str]:
    """Key name -> key expression with ``<run>`` and ``<i>`` placeholders: the run's data channels
    (:data:`zentrack.transport.keys.CHANNELS`), the liveliness tokens and the control keys."""
    k = keys.Keys()
    values = {name: k.of(name, NODE if channel.per_node else None) for name, channel in keys.CHANNELS.items()}
    values.update(alive=k.alive(NODE), start=k.start, stop=k.stop)
    return {name: PREFIX + value[len(k.prefix):] for name, value in values.items()}


def key_descriptions() -> dict[str, str]:
    """The ``key -> what is published there`` rows of the table in keys.py's docstring."""
    rows = re.findall(r"^``<prefix>(/\S*)``\s+(.+)$", keys.__doc__ or "", flags=re.M)
    return {PREFIX + path: text.strip() for path, text in rows}


def _type_name(annotation: object) -> str:
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", repr(annotation))
    return text.replace("np.ndarray", "array").replace("|", "\\|")


def _default(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        return f"`{f.default!r}`"
    if f.default_factory is not dataclasses.MISSING:
        return f"`{f.default_factory()!r}`"
    return "required"


def _doc(cls: type) -> str:
    return " ".join(inspect.cleandoc(cls.__doc__ or "").split())


def render_page() -> str:
    """The whole generated part of the wire-protocol page, as Markdown."""
    exprs, described = key_expressions(), key_descriptions()
    lines = ["## Key expressions", "", "Every key starts with `zentrack/<run>` (the run name: "
             "1-64 characters from `A-Z a-z 0-9 _ . -`); `<i>` is a node id.", "",
             "| key | what is published there |", "|---|---|"]
    for name, expr in sorted(exprs.items(), key=lambda kv: kv[1]):
        if expr not in described:
            raise WireDocError(f"key {expr} (Keys.{name}) has no row in the table of zentrack/transport/keys.py's "
                               "docstring")
        lines.append(f"| `{expr}` | {described[expr]} |")
    lines += ["", "## Framing", "",
              f"Every message is one msgpack map. It starts with the header `v` (schema version "
              f"{codec.SCHEMA_VERSION}), `kind`, `k` (step), `t` (sample time k·Ts) and `sender` (a node id or "
              f"`\"truth\"`), then the kind's own fields. Arrays travel as `{{\"shape\": [...], \"data\": "
              f"<little-endian float64 bytes>}}`, symmetric matrices as `{{\"sym\": n, \"data\": <n(n+1)/2 float64, "
              f"upper triangle row by row>}}`. A message larger than {codec.MAX_MESSAGE_BYTES // 1024} KiB is "
              f"refused; a scan has at most {codec.MAX_RETURNS} returns, a round message at most "
              f"{codec.MAX_BLOCKS} information blocks.", "",
              "Decoding returns the typed class or raises `WireError` with one of these reasons: "
              + ", ".join(f"`{r}`" for r in codec.REASONS) + ".", "", "## Messages", ""]
    for cls in message_classes():
        kind = kind_of(cls)
        if kind is None:
            where = "part of another message"
        else:
            key_name = KEY_OF_KIND.get(kind, kind)
            if key_name not in exprs:
                raise WireDocError(f"message {cls.__name__} has kind {kind!r}, which no key of Keys carries")
            where = f"kind `{kind}` on `{exprs[key_name]}`"
        lines += [f"### {cls.__name__}", "", f"`{cls.__module__}.{cls.__name__}`: {where}.", "", _doc(cls), "",
                  "| field | type | default |", "|---|---|---|"]
        lines += [f"| `{f.name}` | `{_type_name(f.type)}` | {_default(f)} |" for f in dataclasses.fields(cls)]
        lines.append("")
    return "\n".join(lines)
