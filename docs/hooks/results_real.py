"""Results tables of the real-trajectory pages (issue 34): ``zentrack sim``'s single-target filter tables on a
recorded path beside the simulated Experiment 2, and its many-target method tables on all 600 scans of the real
scenarios (the four-tracker bench, Stone Soup's included, runs their first 200)."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from results_tables import Column, band, get, median_iqr, num, render_table

Renderer = Callable[[dict[str, Any], str], str]


def sim_filters(data: dict[str, Any], where: str) -> str:
    """Every filter and fusion of a ``zentrack sim --json`` run: RMSE, RMSE / √PCRLB (median [IQR] over the runs)
    and ANEES with its 95 % band."""
    rows = [{"method": name, **row} for name, row in get(data, "filters", where).items()]
    head = (f"`{get(data, 'scenario', where)}`: {get(data, 'runs', where)} runs of {get(data, 'steps', where)} steps, "
            f"{get(data, 'nodes', where)} nodes; median [IQR] over the runs.")
    return head + "\n\n" + render_table(rows, [
        Column("filter + fusion", "method"), Column("RMSE position (m)", "rmse.p", median_iqr(2)),
        Column("RMSE velocity (m/s)", "rmse.v", median_iqr(2)),
        Column("position / √PCRLB", "rmse_over_sqrt_bound.p", median_iqr(2)),
        Column("velocity / √PCRLB", "rmse_over_sqrt_bound.v", median_iqr(2)),
        Column("ANEES", "anees", num(2)), Column("95 % band", "anees_band", band)], where)


def sim_multitarget(data: dict[str, Any], where: str) -> str:
    """zentrack's own many-target methods of a ``zentrack sim --json`` run: GOSPA with its parts."""
    rows = [{"method": m, **r} for m, r in get(data, "methods", where).items()]
    head = (f"`{get(data, 'scenario', where)}`, {get(data, 'runs', where)} run(s) of {get(data, 'steps', where)} steps, "
            f"{get(data, 'nodes', where)} nodes; GOSPA α = {get(data, 'alpha', where):g}, p = "
            f"{get(data, 'order', where):g}, cut-off {get(data, 'cutoff', where):g} m.")
    return head + "\n\n" + render_table(rows, [
        Column("method", "method"), Column("GOSPA (m)", "gospa", num(2)),
        Column("localisation (m²)", "localisation", num(1)), Column("missed (m²)", "missed", num(1)),
        Column("false (m²)", "false", num(1)), Column("identity switches", "switches", num(2)),
        Column("fragmentations", "fragmentations", num(2)),
        Column("longest false life (steps)", "longest_false", num(0), optional=True),
        Column("ms / scan", "ms_per_scan", num(3))], where)


def live_trackers(data: dict[str, Any], where: str) -> str:
    """Live many-target runs side by side (``zentrack run`` per tracker, each run's ``summary.json`` under
    ``runs``, the RSS its trackers' processes sampled every 5 s under ``rss``): per tracker kind, GOSPA per node,
    the local tracker's time per scan and a list's latency (median over the nodes of each node's median, and the
    worst node's p99), deadline misses, identity switches, and the largest RSS of any tracker process."""
    rows = []
    for kind, run in get(data, "runs", where).items():
        nodes = get(run, "nodes", f"{where}: {kind}")
        gospa = [n["gospa"] for n in nodes]
        rss = [v["max_mib"] for v in data.get("rss", {}).get(kind, {}).values()]
        rows.append({
            "kind": kind, "gospa": f"{min(gospa):.2f}-{max(gospa):.2f}",
            "update": f"{_median([n['update_ms']['p50'] for n in nodes]):.1f} / "
                      f"{max(n['update_ms']['p99'] for n in nodes):.1f}",
            "latency": f"{_median([n['latency_ms']['p50'] for n in nodes]):.1f} / "
                       f"{max(n['latency_ms']['p99'] for n in nodes):.1f}",
            "misses": sum(n["deadline_misses"] for n in nodes), "steps": sum(n["steps_estimated"] for n in nodes),
            "switches": f"{min(n['identity_switches'] for n in nodes)}-{max(n['identity_switches'] for n in nodes)}",
            "rss": f"{max(rss):.0f}" if rss else "–"})
    head = (f"`{get(data, 'scenario', where)}`, {get(data, 'steps', where)} steps in realtime, "
            f"{get(data, 'nodes', where)} trackers on one 2-core host, one run per tracker kind.")
    return head + "\n\n" + render_table(rows, [
        Column("tracker", "kind"), Column("GOSPA per node (m)", "gospa"),
        Column("local tracker per scan, ms: median / worst p99", "update"),
        Column("scan to list published, ms: median / worst p99", "latency"),
        Column("deadline misses", "misses", num(0)), Column("lists", "steps", num(0)),
        Column("identity switches per node", "switches"), Column("largest tracker RSS (MiB)", "rss")], where)


def _median(values: list[float]) -> float:
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])


RENDERERS: dict[tuple[str, str], Renderer] = {
    ("multitarget_live_pmbm", "trackers"): live_trackers,
    ("multitarget_live_adsb", "trackers"): live_trackers,
    **{(name, "filters"): sim_filters for name in ("real_single_ais_vessel", "real_single_adsb_aircraft",
                                                   "real_single_exp2")},
    **{(name, "methods"): sim_multitarget for name in ("real_sim_ais_nyharbor", "real_sim_ais_nyharbor_cameras",
                                                      "real_sim_adsb_paris", "real_sim_ais_nyharbor_radar",
                                                      "real_sim_adsb_paris_radar")},
}
