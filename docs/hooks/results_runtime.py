"""Results tables of the runtime benchmarks: speed, step, latency, hops, scale, startup, gate.

Each renderer takes a bench's JSON (as ``zentrack bench NAME --json`` writes it) and returns Markdown; the
keys it reads are the bench's own, so a renamed key fails the docs build (results_tables.ResultsError).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from results_tables import Column, get, num, render_table, text

Renderer = Callable[[dict[str, Any], str], str]


def speed_batched(data: dict[str, Any], where: str) -> str:
    batched = get(data, "batched", where)
    rows = [{"name": name.upper(), **fig} for name, fig in batched.items()]
    runs = get(data, "runs", where)
    return render_table(rows, [Column("network filter", "name"),
                               Column("one run (s)", "one_run_s", num(3)),
                               Column("µs / node-step, one run", "us_per_node_step_R1", num(1)),
                               Column(f"µs / node-step, {runs} runs batched", f"us_per_node_step_R{runs}", num(1))],
                        where)


def speed_single(data: dict[str, Any], where: str) -> str:
    steps = get(data, "single_node.us_per_step", where)
    rows = [{"what": k, "us": v} for k, v in steps.items()]
    table = render_table(rows, [Column("one node alone", "what"), Column("µs / step", "us", num(1))], where)
    ratios = [{"what": k, "v": v} for k, v in get(data, "ratios", where).items()]
    table += "\n\n" + render_table(ratios, [Column("ratio (< 1: zentrack faster)", "what"),
                                            Column("value", "v", num(2))], where)
    agree = get(data, "single_node.agreement", where)
    rows = [{"what": k, "v": f"{v:.1e}"} for k, v in agree.items()]
    return table + "\n\n" + render_table(rows, [Column("agreement with FilterPy (max abs difference of the "
                                                       "estimates over the run)", "what"), Column("value", "v")],
                                         where)


def hops_paths(data: dict[str, Any], where: str) -> str:
    rows = get(data, "results", where)
    return (f"{get(data, 'pings', where)} round trips of {get(data, 'size', where)} bytes per path, on loopback.\n\n"
            + render_table(rows, [Column("path", "path"), Column("routers", "routers", text),
                                  Column("round trip p50 (ms)", "rtt_ms.p50", num(3)),
                                  Column("p99 (ms)", "rtt_ms.p99", num(3)),
                                  Column("one way added per router, p50 (ms)", "one_way_added_ms.p50", num(3),
                                         optional=True),
                                  Column("p99 (ms)", "one_way_added_ms.p99", num(3), optional=True)], where))


def step_pieces(data: dict[str, Any], where: str) -> str:
    rows = [{"what": k, "us": v} for k, v in get(data, "pieces_us", where).items()]
    head = (f"{get(data, 'nodes', where)} trackers (`{get(data, 'filter', where)}`, mean degree "
            f"{get(data, 'mean_degree', where):.1f}) in one process, lockstep, {get(data, 'steps', where)} steps: "
            f"**{get(data, 'us_per_node_step', where):.1f} µs of main-thread Python per node-step**; CI's general "
            f"(stacked) path costs {get(data, 'ci_general_over_one', where):.2f}× the single-receiver one.")
    return head + "\n\n" + render_table(rows, [Column("piece", "what"), Column("µs", "us", num(1))], where)


RENDERERS: dict[tuple[str, str], Renderer] = {
    ("hops", "paths"): hops_paths,
    ("step", "pieces"): step_pieces,
    ("speed", "batched"): speed_batched,
    ("speed", "single"): speed_single,
}
