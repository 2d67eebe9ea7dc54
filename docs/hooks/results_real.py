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
        Column("fragmentations", "fragmentations", num(2)), Column("ms / scan", "ms_per_scan", num(3))], where)


RENDERERS: dict[tuple[str, str], Renderer] = {
    **{(name, "filters"): sim_filters for name in ("real_single_ais_vessel", "real_single_adsb_aircraft",
                                                   "real_single_exp2")},
    **{(name, "methods"): sim_multitarget for name in ("real_sim_ais_nyharbor", "real_sim_ais_nyharbor_cameras",
                                                      "real_sim_adsb_paris", "real_sim_ais_nyharbor_radar",
                                                      "real_sim_adsb_paris_radar")},
}
