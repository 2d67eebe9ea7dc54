"""Results tables of the runtime benchmarks: speed, step, latency, hops, scale, startup, gate, multitarget, async,
isolated.

Each renderer takes a bench's JSON (as ``zentrack bench NAME --json`` writes it) and returns Markdown; the
keys it reads are the bench's own, so a renamed key fails the docs build (results_tables.ResultsError).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from results_tables import Column, ResultsError, band, get, median_iqr, num, render_table, text, yes_no

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
    if "idle" in data:  # the same steps with an idle gap before every call (bench step --idle-ms)
        idle = data["idle"]
        head += (f" With {get(idle, 'idle_ms', where):g} ms idle before every call, as a tracker process idles "
                 f"between its messages, the same node step costs **{get(idle, 'us_per_node_step_idle', where):.0f} µs"
                 f"**, {get(idle, 'idle_over_busy', where):.1f}× its {get(idle, 'us_per_node_step_busy', where):.0f} µs "
                 f"without ({get(idle, 'steps', where)} steps).")
    return head + "\n\n" + render_table(rows, [Column("piece", "what"), Column("µs", "us", num(1))], where)


def latency_figures(data: dict[str, Any], where: str) -> str:
    rows = [{"what": "raw Zenoh round trip, 1.5 KB, two processes (same run)", **get(data, "round_trip_ms", where)},
            {"what": "tracker compute per step (local update)", **get(data, "update_ms", where)},
            {"what": "step latency (measurement published → posterior published)",
             **get(data, "step_latency_ms", where)}]
    head = (f"{get(data, 'nodes', where)} trackers, {get(data, 'duration_s', where):.0f} s at Ts = "
            f"{get(data, 'ts', where)} s, fusion `{get(data, 'fusion', where)}`, embedded peers. Deadline misses: "
            f"**{get(data, 'deadline_misses', where)}**; steps without an estimate: "
            f"{get(data, 'steps_without_estimate', where)}; step-latency p99 / (round-trip p99 + compute p99) = "
            f"**{get(data, 'ratio_p99', where):.2f}**.")
    return head + "\n\n" + render_table(rows, [Column("figure", "what"), Column("p50 (ms)", "p50", num(3)),
                                               Column("p99 (ms)", "p99", num(3))], where)


SCALE_KINDS = ("tracker", "truth", "recorder", "router")


def scale_sizes(data: dict[str, Any], where: str) -> str:
    rows = [{**r, "est": f"{r['estimates']}/{r['expected_estimates']}",
             **{f"cpu_{k}": v.get("mean_ms") for k, v in r.get("cpu_ms_per_step", {}).items()},
             **{f"rss_{k}": v.get("rss_mean_mb") for k, v in r.get("memory_mb", {}).items()},
             "router_mbps": r["router_links"]["total_bytes_per_s"] / 1e6 if r.get("router_links") else None}
            for r in get(data, "results", where)]
    head = (f"{get(data, 'duration_s', where):.0f} s per size at {1 / get(data, 'ts', where):.0f} Hz, topology "
            f"`{get(data, 'topology', where)}`. Largest size passing: **{get(data, 'largest_passing_n', where)}**. "
            "CPU in ms per 100 ms step, per process of the type.")
    columns = [Column("N", "nodes", text), Column("topology", "topology"), Column("passes", "passes", yes_no),
               Column("misses", "deadline_misses", text), Column("lost", "lost_estimates", text),
               Column("estimates", "est"), Column("latency p50 (ms)", "latency_ms.p50", num(2)),
               Column("p99 (ms)", "latency_ms.p99", num(2))]
    columns += [Column(k, f"cpu_{k}", num(2), optional=True) for k in SCALE_KINDS]
    columns += [Column(f"{k} RSS (MB)", f"rss_{k}", num(0), optional=True) for k in SCALE_KINDS]
    columns += [Column("router links (MB/s)", "router_mbps", num(3), optional=True),
                Column("degree", "degree", text, optional=True)]
    columns.append(Column("load (1 min)", "load_avg_1min", num(1)))
    return head + "\n\n" + render_table(rows, columns, where)


def startup_kinds(data: dict[str, Any], where: str) -> str:
    def cell(digits: int) -> Any:
        return lambda st: f"{st['median']:.{digits}f} [{st['min']:.{digits}f}, {st['max']:.{digits}f}]"
    rows = [{"kind": k, **v} for k, v in get(data, "results", where).items()]
    head = (f"Median [min, max] of {get(data, 'repeat', where)} starts per process type, scenario "
            f"`{get(data, 'scenario', where)}`.")
    return head + "\n\n" + render_table(rows, [
        Column("process", "kind"), Column("start to ready (s)", "start_s", cell(2)),
        Column("idle RSS (MB)", "rss_mb", cell(1)), Column("threads", "threads", cell(0)),
        Column("CPU to ready (s)", "cpu_s", cell(2))], where)


def gate_configs(data: dict[str, Any], where: str) -> str:
    rows = [{**r, "rate_text": f"{r['rate']:.1e}" if r.get("rate") is not None else "–"}
            for r in get(data, "configs", where)]
    head = (f"{get(data, 'steps', where)} lockstep steps per configuration at the gate's P = {get(data, 'gate', where)}:"
            f" **{get(data, 'gated', where)} of {get(data, 'received', where)}** honest neighbours' messages refused.")
    return head + "\n\n" + render_table(rows, [
        Column("scenario", "scenario"), Column("filter", "filter", text), Column("fusion", "fusion", text),
        Column("nodes", "nodes", text), Column("received", "received", text), Column("refused", "gated", text),
        Column("rate", "rate_text"), Column("outvoted", "outvoted", text), Column("lifted", "gate_lifted", text)],
        where)


def multitarget_methods(data: dict[str, Any], where: str) -> str:
    rows = [{"method": m, **r} for m, r in get(data, "methods", where).items()]
    aims = get(data, "aims", where)
    yes = {True: "met", False: "not met"}
    head = (f"`{get(data, 'scenario', where)}`, {get(data, 'runs', where)} run(s) of {get(data, 'steps', where)} steps, "
            f"{get(data, 'nodes', where)} nodes; GOSPA α = {get(data, 'alpha', where):g}, p = {get(data, 'order', where):g}, "
            f"cut-off {get(data, 'cutoff', where):g} m. The issue's aims: distributed / centralized GOSPA "
            f"**{get(aims, 'distributed_over_centralized', where):.2f}** (aim ≤ {get(data, 'distributed_ratio_aim', where):g}); "
            f"every node better distributed than alone: {yes[bool(get(aims, 'every_node_better_than_alone', where))]}; "
            f"time per scan below Stone Soup's: centralized "
            f"{yes[bool(get(aims, 'centralized_ms_per_scan_below_stonesoup', where))]}, distributed "
            f"{yes[bool(get(aims, 'distributed_ms_per_scan_below_stonesoup', where))]}.")
    if aims.get("pmbm_distributed_over_pmbm") is not None:  # (benches since the PMBM nodes' row)
        head += (f" PMBM nodes: pmbm-distributed / pmbm GOSPA **{aims['pmbm_distributed_over_pmbm']:.2f}** (aim ≤ "
                 f"{get(data, 'distributed_ratio_aim', where):g}); every PMBM node better than alone: "
                 f"{yes[bool(aims.get('every_pmbm_node_better_than_alone'))]}.")
    if aims.get("stonesoup_best") is not None:  # (benches since Stone Soup's JPDA row)
        ratio = {m: aims.get(f"{m}_over_stonesoup_best")
                 for m in ("centralized", "pmbm", "distributed", "pmbm-distributed")}

        def shown(m: str) -> str:
            return "–" if ratio[m] is None else f"**{ratio[m]:.2f}**"

        head += (f" Against Stone Soup's better row (`{aims['stonesoup_best']}`): centralized {shown('centralized')}, "
                 f"PMBM {shown('pmbm')} (aim ≤ 0.9), distributed {shown('distributed')}, PMBM nodes "
                 f"{shown('pmbm-distributed')} (aim ≤ 1); every zentrack method "
                 f"**{aims['least_speedup_over_stonesoup']:.0f}×** or more faster per scan than Stone Soup's faster row "
                 "(aim ≥ 10×).")
    return head + "\n\n" + render_table(rows, [
        Column("method", "method"), Column("GOSPA (m)", "gospa", num(2)), Column("RMS GOSPA (m)", "rms_gospa", num(2)),
        Column("localisation (m²)", "localisation", num(1)), Column("missed (m²)", "missed", num(1)),
        Column("false (m²)", "false", num(1)), Column("identity switches", "switches", num(2)),
        Column("fragmentations", "fragmentations", num(2)),
        Column("longest false life (steps)", "longest_false", num(0), optional=True),
        Column("ms / scan", "ms_per_scan", num(3))], where)


def _percent(v: Any) -> str:
    return "ref." if v is None else f"{float(v['p']) * 100:+.1f} %"


def async_scenario(scenario: str) -> Renderer:
    """``bench async`` on one scenario: every method's RMSE against the bound and zero latency, ANEES, what became
    of the detections, processor time per detection and the estimate's age."""
    def render(data: dict[str, Any], where: str) -> str:
        found = [s for s in get(data, "scenarios", where) if s.get("scenario") == scenario]
        if not found:
            raise ResultsError(f"{where}: no scenario {scenario!r}")
        s = found[0]
        runs = get(s, "runs", where)
        rows = []
        for r in get(s, "rows", where):
            stonesoup = r["method"].startswith("stonesoup")
            rows.append({**r, "versus": "–" if stonesoup else _percent(r["vs_zero_latency"]),
                         "diverged": f"{r['diverged_runs']}/{runs}",
                         "age": f"{r['age_ms']['max']:.1f} / {r['age_ms']['p99']:.1f}"})
        settings = get(data, "settings", where)
        band_text = next((band(r["anees_band"]) for r in rows if r.get("anees_band")), "")
        aims = [r for r in rows if r["aims"]["within_5_percent"] is not None]
        met = [r["label"] for r in aims if r["aims"]["within_5_percent"]]
        head = (f"`{scenario}`: {get(s, 'nodes', where)} trackers ({get(s, 'filter', where).upper()}, "
                f"{get(s, 'fusion', where)} with the ring neighbours every {get(s, 'ts', where):g} s), "
                f"{get(s, 'steps', where)} fusion periods, {runs} runs, {get(s, 'detections_per_run', where):.0f} "
                f"detections a run (sensors at {', '.join(f'{v:g}' for v in settings['rates_hz'])} Hz), seed "
                f"{get(data, 'seed', where)}; √PCRLB of the position {get(s, 'sqrt_bound_p', where):.2f} m; ANEES band "
                f"{band_text}. Within {get(data, 'aim_excess', where):.0%} of zero latency: "
                f"{', '.join(met) if met else 'none'}; every estimate at most one fusion period plus the lag "
                f"({get(s, 'age_aim_ms', where):.0f} ms) old when published: "
                f"{yes_no(all(r['aims']['age_within_period_plus_lag'] for r in rows))}.")
        return head + "\n\n" + render_table(rows, [
            Column("method", "label"), Column("RMSE p (m)", "rmse.p", median_iqr(2)),
            Column("p / √B", "rmse_over_sqrt_bound.p", median_iqr(2)), Column("vs zero latency", "versus"),
            Column("ANEES", "anees", num(2)), Column("in order", "counts.applied", num(0)),
            Column("late, used", "counts.late", num(0)), Column("dropped", "counts.dropped", num(0)),
            Column("too old", "counts.too_old", num(0)), Column("diverged", "diverged"),
            Column("CPU µs / detection", "cpu_us_per_detection", num(0)), Column("age max / p99 (ms)", "age")],
            where)
    return render


def isolated_cuts(data: dict[str, Any], where: str) -> str:
    """``bench isolated``: per scenario and cut, every rule's error over the cut beside prediction's and its NEES
    beside the band."""
    rows = []
    for cut in get(data, "cuts", where):
        for rule, r in get(cut, "rules", where).items():
            rows.append({**r, "rule": rule, "cut": f"{cut['scenario']}, {cut['seconds']:g} s",
                         "band": band(cut["nees_band"])})
    head = (f"Node 4 cut off both ways from step 200 of each run, {get(data, 'runs', where)} runs (seed "
            f"{get(data, 'seed', where)}); errors are the position error's mean over the runs (RMS over the cut and "
            "runs), NEES the kinematic state's (6-D) mean over the runs per step.")
    return head + "\n\n" + render_table(rows, [
        Column("cut", "cut"), Column("rule", "label"), Column("RMS error (m)", "rms_error_m", num(1)),
        Column("vs prediction", "rms_vs_prediction", num(2)), Column("error at the end (m)", "end_error_m", num(1)),
        Column("vs prediction", "end_vs_prediction", num(2)), Column("NEES max", "max_nees", _nees),
        Column("NEES mean", "mean_nees", _nees), Column("95 % band", "band"),
        Column("1 s after (m)", "after_error_m", num(1))], where)


def _nees(v: Any) -> str:
    return f"{float(v):.3g}" if float(v) < 1e4 else f"{float(v):.1e}"


RENDERERS: dict[tuple[str, str], Renderer] = {
    ("multitarget", "methods"): multitarget_methods,
    ("multitarget_ais", "methods"): multitarget_methods,
    ("multitarget_adsb", "methods"): multitarget_methods,
    ("multitarget_bearing", "methods"): multitarget_methods,
    ("multitarget_ais_mixed", "methods"): multitarget_methods,
    ("multitarget_ais_cameras", "methods"): multitarget_methods,
    ("multitarget_adsb_stations", "methods"): multitarget_methods,
    ("multitarget_mt50", "methods"): multitarget_methods,
    ("multitarget_birth_death", "methods"): multitarget_methods,
    ("latency", "figures"): latency_figures,
    ("scale", "sizes"): scale_sizes,
    ("startup", "kinds"): startup_kinds,
    ("gate", "configs"): gate_configs,
    ("hops", "paths"): hops_paths,
    ("step", "pieces"): step_pieces,
    ("speed", "batched"): speed_batched,
    ("speed", "single"): speed_single,
    ("async", "exp2"): async_scenario("exp2"),
    ("async", "adsb-aircraft"): async_scenario("adsb-aircraft"),
    ("isolated", "cuts"): isolated_cuts,
}
