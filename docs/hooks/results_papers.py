"""Results tables of the paper benchmarks (``zentrack bench paper0`` .. ``paper4``) and ``bench accuracy``.

Each renderer takes the bench's JSON as it wrote it and returns Markdown; the keys read are the bench's own.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from results_tables import Column, ResultsError, band, bullets, get, joined, median_iqr, num, render_table, text, yes_no

Renderer = Callable[[dict[str, Any], str], str]


def _first_band(filters: dict[str, Any], key: str = "anees_band") -> str:
    return next((band(f.get(key)) for f in filters.values() if band(f.get(key))), "")


def paper0_table(experiment: str) -> Renderer:
    """Paper 0's Table 2 (Experiment 1) or 3 (Experiment 2): the paper's one run beside our median [IQR]."""
    def render(data: dict[str, Any], where: str) -> str:
        exp = get(data, f"experiments.{experiment}", where)
        cols, filters = get(exp, "cols", where), get(exp, "filters", where)
        rows = []
        for name, f in filters.items():
            paper = f.get("paper")
            rows.append({**f, "name": name.upper(), "diverged": f"{get(f, 'diverged_runs', where)}/{exp['runs']}",
                         "paper_text": " / ".join(f"{paper[c]:.3f}" for c in cols) if paper else "not in the paper"})
        columns = [Column("algorithm", "name"), Column("paper RMSE " + " / ".join(cols), "paper_text")]
        columns += [Column(f"ours RMSE {c}", f"rmse.{c}", median_iqr(2)) for c in cols]
        columns += [Column(f"ours {cols[0]} / √bound", f"rmse_over_sqrt_bound.{cols[0]}", median_iqr(2)),
                    Column(f"ANEES (band {_first_band(filters)})", "anees", num(2)), Column("η", "eta", num(2)),
                    Column("diverged runs", "diverged")]
        head = (f"Scenario `{get(exp, 'scenario', where)}`: {exp['nodes']} nodes, {exp['steps']} steps, "
                f"{exp['runs']} runs (seed {get(data, 'seed', where)}).")
        return head + "\n\n" + render_table(rows, columns, where)
    return render


def paper0_checks(data: dict[str, Any], where: str) -> str:
    return bullets(get(data, "shape_checks", where), where)


def paper3_errors(data: dict[str, Any], where: str) -> str:
    rows = []
    for scen, s in get(data, "scenarios", where).items():
        for name, f in get(s, "filters", where).items():
            rows.append({**f, "scenario": scen, "name": "SecKF" if name == "seckf" else name.upper()
                         if name != "lin" else "lin", "band": band(get(s, "anees_band_95", where))})
    columns = [Column("scenario", "scenario"), Column("filter", "name"),
               Column("error at obs 1 (m)", "error_per_observation.0", num(2)),
               Column("error at obs 20 (m)", "error_at_20", num(3)),
               Column("RMSE / √bound at obs 20", "rmse_over_sqrt_bound.at_last", num(3)),
               Column("ANEES at obs 20", "anees_at_20", num(2)), Column("ANEES band", "band"),
               Column("diverged", "diverged_runs", text), Column("all SPD", "all_spd", yes_no),
               Column("µs / run-step, batched", "us_per_run_step_batched", num(1))]
    return (f"{get(data, 'runs', where)} runs per scenario, seed {get(data, 'seed', where)}; error = mean "
            "position error (the paper's MAE_r).\n\n" + render_table(rows, columns, where))


def paper3_timing(data: dict[str, Any], where: str) -> str:
    paper = get(data, "paper.reduction_at_20", where)
    rows = []
    for scen, s in get(data, "scenarios", where).items():
        r = get(s, "ratios", where)
        rows.append({"scenario": scen, "reduction": f"{100 * get(s, 'reduction_at_last', where):.2f} %",
                     "paper_reduction": f"{100 * paper['table']:.1f} % (abstract {100 * paper['abstract']:.1f} %)",
                     "sec_ekf": r["seckf/ekf"], "paper_sec_ekf": r["paper seckf/ekf"],
                     "ukf_sec": r["ukf/seckf"], "paper_ukf_sec": r["paper ukf/seckf"], "best": s["best"]})
    return render_table(rows, [Column("scenario", "scenario"), Column("SecKF's error below EKF's at obs 20",
                                                                      "reduction"),
                               Column("paper", "paper_reduction"), Column("best filter", "best"),
                               Column("single-step time SecKF / EKF", "sec_ekf", num(2)),
                               Column("paper", "paper_sec_ekf", num(2)),
                               Column("UKF / SecKF", "ukf_sec", num(2)), Column("paper", "paper_ukf_sec", num(2))],
                        where)


PAPER002_LABELS = {"local": "Local", "ci-centre": "CI (centre)", "fci-centre": "fast CI (centre)",
                   "ici-centre": "ICI (centre)", "diff-fci": "Diff-FCI", "diff-ici": "Diff-ICI", "dce-fci": "DCE-FCI",
                   "dce-ici": "**DCE-ICI**", "dce-ici-metropolis": "DCE-ICI, Metropolis weights",
                   "centralized": "centralized SRCIF (all scans)"}


def paper2_scenario(scenario: str) -> Renderer:
    """One of paper 2's scenarios: every method's RMSE, RMSE / √bound and ANEES, then the ranking checked."""
    def render(data: dict[str, Any], where: str) -> str:
        s = get(data, f"scenarios.{scenario}", where)
        rows = [{**r, "name": PAPER002_LABELS.get(name, name)} for name, r in get(s, "rows", where).items()]
        head = (f"{get(data, 'runs', where)} runs, {get(s, 'steps', where)} steps of {get(s, 'ts', where)} s; "
                f"graph: λ₂ {get(s, 'lambda_2', where):.3f} with the centrality weights (Metropolis "
                f"{get(s, 'lambda_2_metropolis', where):.3f}), L* = {get(s, 'l_star', where):.2f}, "
                f"L = {get(s, 'rounds', where)}, diameter {get(s, 'diameter', where)}. ANEES band: network "
                f"{band(get(s, 'anees_band_network', where))}, one node {band(get(s, 'anees_band_single', where))}.")
        table = render_table(rows, [Column("method", "name"), Column("RMSE p (m)", "rmse_p", num(1)),
                                    Column("RMSE v (m/s)", "rmse_v", num(2)),
                                    Column("p / √B", "rmse_p_over_sqrt_bound", num(2)),
                                    Column("v / √B", "rmse_v_over_sqrt_bound", num(2)),
                                    Column("ANEES", "anees", num(2)),
                                    Column("diverged", "diverged_runs", text)], where)
        ranking = [f"{claim}: {'holds' if ok else '**does not hold**'}"
                   for claim, ok in get(s, "ranking", where).items()]
        return head + "\n\n" + table + "\n\nThe paper's ranking on this scenario:\n\n" + bullets(ranking, where)
    return render


def paper2_sweep(data: dict[str, Any], where: str) -> str:
    sweep = get(data, "rmse_vs_rounds", where)
    rows = [{"L": L, "p": p, "v": v} for L, p, v in zip(get(sweep, "L", where), get(sweep, "rmse_p", where),
                                                       get(sweep, "rmse_v", where), strict=True)]
    return (f"DCE-ICI on `{get(sweep, 'scenario', where)}` against the number of consensus rounds L:\n\n"
            + render_table(rows, [Column("L", "L", text), Column("RMSE p (m)", "p", num(1)),
                                  Column("RMSE v (m/s)", "v", num(2))], where))


PAPER001_LABELS = {"pda-fpf+ci": "pda-fpf with CI feedback (zentrack)"}


def paper1_fused(data: dict[str, Any], where: str) -> str:
    """Paper 1: the three local filters and the fusion centre per filter, against the bound."""
    timing = get(data, "timing", where)
    rows = [{**f, "name": PAPER001_LABELS.get(name, name), **{f"t_{k}": v for k, v in timing.get(name, {}).items()}}
            for name, f in get(data, "filters", where).items()]
    lam, irf = get(data, "lambda_v_gate", where), get(data, "information_reduction_factor", where)
    head = (f"{get(data, 'runs', where)} runs × {get(data, 'steps', where)} scans, figures over scans "
            f"{'–'.join(str(w) for w in get(data, 'window', where))}; λ·V_gate per sensor "
            f"{', '.join(f'{x:.2f}' for x in lam)}; information reduction factor "
            f"{', '.join(f'{x:.2f}' for x in irf)}; √PCRLB: position "
            f"{get(data, 'sqrt_pcrlb_position_m', where):.1f} m, velocity "
            f"{get(data, 'sqrt_pcrlb_velocity_mps', where):.2f} m/s.")
    columns = [Column("filter (3 local filters, then the fusion centre)", "name"),
               Column("local v RMSE (m/s)", "local_rmse_v", joined(2)), Column("fused v", "fused_rmse_v", num(2)),
               Column("fused p (m)", "fused_rmse_p", num(1)),
               Column("p / √bound", "fused_rmse_p_over_sqrt_bound", num(2)),
               Column("v / √bound", "fused_rmse_v_over_sqrt_bound", num(2)),
               Column(f"fused ANEES (band {band(get(data, 'anees_band', where))})", "fused_anees", num(1)),
               Column("fused better than every local", "fused_beats_every_local", yes_no),
               Column("ms / node-step", "t_ms_per_node_step", num(3)),
               Column("µs / particle-step", "t_us_per_particle_step", num(1), optional=True)]
    return head + "\n\n" + render_table(rows, columns, where)


def paper4_cases(data: dict[str, Any], where: str) -> str:
    """Paper 4: one table per scenario and point rate, each followed by the paper's findings checked."""
    parts = [f"{get(data, 'runs', where)} runs per case, seed {get(data, 'seed', where)}, consensus rounds L in "
             f"{', '.join(str(L) for L in get(data, 'rounds', where))}."]
    for key, case in get(data, "cases", where).items():
        at = f"{where}, case {key!r}"
        bands = get(case, "anees_band_95", at)
        rows = [{**m, "name": name} for name, m in get(case, "methods", at).items()]
        parts.append(f"### {get(case, 'scenario', at)} ({get(case, 'shape', at)}), λ = {get(case, 'rate', at):g}")
        parts.append(render_table(rows, [
            Column("method", "name"), Column(get(case, "metric", at), "shape_error", num(3)),
            Column("ACEE kin", "acee_kinematic", num(3)), Column("ACEE ext", "acee_extent", num(3)),
            Column(f"ANEES kin (band {band(get(bands, 'kinematic', at))})", "anees_kinematic", num(2)),
            Column(f"ANEES ext (band {band(get(bands, 'extent', at))})", "anees_extent", num(2)),
            Column("ms / scan", "ms_per_scan", num(1))], at))
        parts.append(bullets([f"{'holds' if get(f, 'holds', at) else '**does not hold**'}: {get(f, 'finding', at)} "
                              f"({get(f, 'numbers', at)})" for f in get(case, "findings", at)], at))
    return "\n\n".join(parts)


def _accuracy_label(row: dict[str, Any]) -> str:
    name = row["filter"]
    return name[0].upper() + name[1:].upper()


def accuracy_scenario(scenario: str) -> Renderer:
    """``bench accuracy`` on one scenario: every filter with every single-round rule, against the bound."""
    def render(data: dict[str, Any], where: str) -> str:
        found = [s for s in get(data, "scenarios", where) if s.get("scenario") == scenario]
        if not found:
            raise ResultsError(f"{where}: no scenario {scenario!r}")
        s = found[0]
        runs = get(s, "runs", where)
        rows = [{**r, "name": _accuracy_label(r), "rule_text": r["rule"] or "centralized",
                 "diverged": f"{r['diverged_runs']}/{runs}"} for r in get(s, "rows", where)]
        band_text = next((band(r["anees_band"]) for r in rows if r.get("anees_band")), "")
        best = get(data, "best", where).get(scenario)
        head = (f"`{scenario}`: {get(s, 'nodes', where)} nodes, {get(s, 'steps', where)} steps, {runs} runs, seed "
                f"{get(data, 'seed', where)}; ANEES band {band_text}.")
        if best:
            head += (f" Best distributed configuration within the band: **{_accuracy_label(best)} + {best['rule']}**, "
                     f"RMSE p / √bound {best['ratio_p']:.2f} at {best['bytes_per_node_step']} bytes per node-step.")
        return head + "\n\n" + render_table(rows, [
            Column("filter", "name"), Column("rule", "rule_text"), Column("RMSE p (m)", "rmse.p", median_iqr(2)),
            Column("p / √B", "rmse_over_sqrt_bound.p", median_iqr(2)),
            Column("v / √B", "rmse_over_sqrt_bound.v", median_iqr(2)), Column("ANEES", "anees", num(2)),
            Column("diverged", "diverged"), Column("bytes / node-step", "bytes_per_node_step", text),
            Column("µs / node-step", "us_per_node_step", num(1))], where)
    return render


RENDERERS: dict[tuple[str, str], Renderer] = {
    ("paper4", "cases"): paper4_cases,
    ("accuracy", "exp2"): accuracy_scenario("exp2"),
    ("accuracy", "exp2-irregular"): accuracy_scenario("exp2-irregular"),
    ("paper1", "fused"): paper1_fused,
    ("paper2", "scenario1"): paper2_scenario("dce-ici"),
    ("paper2", "scenario2"): paper2_scenario("dce-ici-manoeuvre"),
    ("paper2", "sweep"): paper2_sweep,
    ("paper0", "table2"): paper0_table("1"),
    ("paper0", "table3"): paper0_table("2"),
    ("paper0", "checks"): paper0_checks,
    ("paper3", "errors"): paper3_errors,
    ("paper3", "timing"): paper3_timing,
}
