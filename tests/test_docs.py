"""The documentation site's generators (docs/hooks/): results tables rendered from benchmark JSON, and the
wire-protocol page generated from the typed messages.

Fast unit tests: no mkdocs build (.ci/run builds the site with --strict); the hooks are imported from
docs/hooks/ as mkdocs imports them (their folder on sys.path).
"""
from __future__ import annotations

import dataclasses
import inspect
import json
import re
import sys
from pathlib import Path

import pytest

from zentrack.transport import codec, keys, messages, scan_messages

ROOT = Path(__file__).resolve().parent.parent
HOOKS = ROOT / "docs" / "hooks"
sys.path.insert(0, str(HOOKS))

import results_hook  # noqa: E402
import results_tables  # noqa: E402
import wire_protocol  # noqa: E402

STAMP = {"command": "zentrack bench hops --pings 10 --json docs/results/hops.json", "wall_s": 1.5,
         "date": "2026-01-01", "exit_status": 0}


def hops_json(**changes: object) -> dict:
    rows = [{"path": "direct", "routers": 0, "rtt_ms": {"p50": 0.0421, "p99": 0.0722}},
            {"path": "1 router", "routers": 1, "rtt_ms": {"p50": 0.0703, "p99": 0.0991},
             "one_way_added_ms": {"p50": 0.0141, "p99": 0.0135}}]
    return {"command": "bench hops", "pings": 10, "size": 1500, "results": rows, "produced_by": STAMP, **changes}


def write(tmp_path: Path, name: str, data: dict) -> Path:
    (tmp_path / f"{name}.json").write_text(json.dumps(data))
    return tmp_path


def table_rows(markdown: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip("|").split("|")] for line in markdown.splitlines()
            if line.startswith("|") and not line.startswith("|---")]


def test_a_table_is_rendered_from_a_small_json(tmp_path: Path) -> None:
    out = results_hook.render_marker("hops", "paths", write(tmp_path, "hops", hops_json()))
    rows = table_rows(out)
    assert rows[0][:4] == ["path", "routers", "round trip p50 (ms)", "p99 (ms)"]
    assert rows[1][:4] == ["direct", "0", "0.042", "0.072"]
    assert rows[1][4] == "–"  # optional column: no routers, nothing added
    assert rows[2] == ["1 router", "1", "0.070", "0.099", "0.014", "0.013"]
    assert "10 round trips of 1500 bytes" in out
    assert f"*Produced by `{STAMP['command']}` on 2026-01-01" in out


def test_a_marker_in_a_page_becomes_its_table(tmp_path: Path) -> None:
    page = "# Title\n\n<!-- results: hops paths -->\n\nAfter.\n"
    out = results_hook.expand(page, write(tmp_path, "hops", hops_json()))
    assert "<!-- results" not in out and "| direct | 0 | 0.042 |" in out and out.endswith("After.\n")


def test_a_marker_quoted_in_prose_is_left_alone(tmp_path: Path) -> None:
    page = "Ask with a marker, `<!-- results: hops paths -->`, on a line of its own.\n"
    assert results_hook.expand(page, tmp_path) == page


def test_a_missing_key_fails_with_a_line_naming_file_row_and_key(tmp_path: Path) -> None:
    data = hops_json()
    del data["results"][1]["rtt_ms"]["p99"]
    with pytest.raises(results_tables.ResultsError) as err:
        results_hook.render_marker("hops", "paths", write(tmp_path, "hops", data))
    assert str(err.value) == "hops.json (paths), row 1: no key 'p99' (looking up 'rtt_ms.p99')"


def test_a_missing_provenance_stamp_fails(tmp_path: Path) -> None:
    data = hops_json()
    del data["produced_by"]
    with pytest.raises(results_tables.ResultsError, match="no key 'produced_by'"):
        results_hook.render_marker("hops", "paths", write(tmp_path, "hops", data))


def test_a_missing_file_or_unknown_table_fails_clearly(tmp_path: Path) -> None:
    with pytest.raises(results_tables.ResultsError, match=r"hops\.json: missing \(run docs/hooks/run_benches\.py hops\)"):
        results_hook.render_marker("hops", "paths", tmp_path)
    with pytest.raises(results_tables.ResultsError, match="unknown results table 'hops' 'nope' .*hops paths"):
        results_hook.render_marker("hops", "nope", tmp_path)


def test_values_are_formatted_not_dropped() -> None:
    assert results_tables.median_iqr(2)({"median": 1.234, "q25": 1.0, "q75": 1.5}) == "1.23 [1.00, 1.50]"
    assert results_tables.num(2)("inf") == "diverged" and results_tables.num(2)(float("inf")) == "diverged"
    assert results_tables.num(1)(None) == "–"


def test_every_marker_on_the_site_renders_from_the_committed_json() -> None:
    """The committed docs/results/*.json hold every key the pages' tables read (what mkdocs build does)."""
    pages = sorted((ROOT / "docs").glob("*.md"))
    markers = [(p.name, m) for p in pages for m in results_hook.MARKER.findall(p.read_text())]
    assert len(markers) >= 20
    for page, (bench, table) in markers:
        out = results_hook.render_marker(bench, table)
        assert table_rows(out) or out.startswith("- "), (page, bench, table)


def message_classes_in_code() -> list[type]:
    """Enumerated here independently of the generator: every dataclass defined in the message modules."""
    return [c for m in (messages, scan_messages) for _, c in inspect.getmembers(m, inspect.isclass)
            if c.__module__ == m.__name__ and dataclasses.is_dataclass(c)]


def test_the_wire_page_lists_every_message_class_and_field() -> None:
    page = wire_protocol.render_page()
    classes = message_classes_in_code()
    assert {c.__name__ for c in classes} >= {"Measurement", "RoundMessage", "EstimateMessage", "Truth", "Start",
                                             "Stop", "ForwardedScan", "Relay", "RelayedScan"}
    for cls in classes:
        section = page.split(f"### {cls.__name__}\n", 1)
        assert len(section) == 2, f"{cls.__name__} has no section on the wire-protocol page"
        body = section[1].split("\n### ", 1)[0]
        for f in dataclasses.fields(cls):
            assert f"| `{f.name}` |" in body, f"{cls.__name__}.{f.name} missing"


def test_the_wire_page_names_every_kind_key_and_reason() -> None:
    page = wire_protocol.render_page()
    for kind in codec.KINDS:
        assert f"kind `{kind}` on `zentrack/<run>/" in page, kind
    k = keys.Keys()
    for key in (k.truth, k.meas("<i>"), k.prior("<i>"), k.scan("<i>"), k.est("<i>"), k.alive("<i>"), k.start, k.stop):
        assert f"| `zentrack/<run>{key[len(k.prefix):]}` |" in page, key
    assert all(f"`{r}`" in page for r in codec.REASONS)
    assert f"schema version {codec.SCHEMA_VERSION}" in page


def test_a_key_without_a_described_row_fails_the_page(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(keys, "__doc__", re.sub(r"^``<prefix>/truth``.*$", "", keys.__doc__ or "", flags=re.M))
    with pytest.raises(wire_protocol.WireDocError, match=r"key zentrack/<run>/truth \(Keys.truth\) has no row"):
        wire_protocol.render_page()


def test_the_bench_runner_refuses_an_unknown_bench_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    import run_benches

    assert run_benches.main(["paper9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    known = ", ".join([*run_benches.BENCHES, *run_benches.SIMS])
    assert err == [f"run_benches: unknown bench 'paper9' (known: {known})"]
    assert run_benches.main(["soak_hour_patrol"]) == 2  # hours: its command is given, not run
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"run_benches: soak_hour_patrol is a long run (a live cluster or a soak); run it by hand: "
                   f"{run_benches.LONG_RUNS['soak_hour_patrol']}"]


def test_every_bench_the_runner_knows_has_a_table_on_the_site() -> None:
    import run_benches

    assert {bench for bench, _ in results_hook.RENDERERS} == (set(run_benches.BENCHES) | set(run_benches.SIMS)
                                                              | set(run_benches.LONG_RUNS))
