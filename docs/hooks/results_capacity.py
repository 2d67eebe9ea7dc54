"""Results tables of the capacity model (``zentrack bench capacity --json``): the fitted coefficients with their
residuals, the prediction for one deployment, and a namespace run's measured figures beside the prediction.
The bench scale JSON the model is fitted on renders with bench scale's own table."""
from __future__ import annotations

from typing import Any

from results_runtime import Renderer, scale_sizes
from results_tables import Column, ResultsError, get, num, render_table, text

#: what each fit's coefficient is, in the page's words
COEFFICIENTS = {
    ("tracker", "const"): "tracker: a (ms per step)", ("tracker", "messages_in"): "tracker: b (ms per message in)",
    ("tracker", "messages_out"): "tracker: c (ms per message out)",
    ("router", "const"): "router: r0 (ms per step)", ("router", "messages_routed"): "router: r1 (ms per message routed)",
    ("truth", "const"): "truth: t0 (ms per step)", ("truth", "nodes"): "truth: t1 (ms per tracker)",
    ("recorder", "const"): "recorder: q0 (ms per step)", ("recorder", "nodes"): "recorder: q1 (ms per tracker)",
    ("bytes", "bytes_meas"): "bytes per measurement", ("bytes", "bytes_prior"): "bytes per prior",
    ("bytes", "bytes_est"): "bytes per estimate",
    ("bytes", "const_tracker_up"): "bytes per step, tracker → router link, constant",
    ("bytes", "const_tracker_down"): "bytes per step, router → tracker link, constant",
    ("bytes", "const_truth_up"): "bytes per step, truth → router link, constant",
    ("bytes", "const_recorder_down"): "bytes per step, router → recorder link, constant",
}


def capacity_fit(data: dict[str, Any], where: str) -> str:
    model, rows = get(data, "model", where), []
    for (fit, name), label in COEFFICIENTS.items():
        value = get(model, f"{fit}.coef", where).get(name, "absent")
        if value == "absent":
            raise ResultsError(f"{where}: no coefficient {fit}.{name}")
        f = model[fit]
        rows.append({"what": label, "value": "not identified" if value is None else f"{value:.4g}",
                     "rms": f["residual_rms"], "max": f["residual_max_abs"], "n": f["observations"]})
    runs = ", ".join(f"N {r['nodes']} d {r['degree']}" for r in get(data, "fit_runs", where))
    return (f"Fitted on {len(get(data, 'fit_runs', where))} runs ({runs}); the residuals are those of the whole "
            "fit the coefficient belongs to (ms per step, or bytes per step per link direction).\n\n"
            + render_table(rows, [Column("coefficient", "what"), Column("value", "value"),
                                  Column("residual RMS", "rms", num(3)), Column("residual max", "max", num(3)),
                                  Column("observations", "n", text)], where))


def figures(block: dict[str, Any], where: str) -> dict[str, float]:
    """CPU per step and bytes per second of a prediction or a measurement, one name each (as the CLI prints)."""
    cpu = get(block, "cpu_ms_per_step", where)
    out = {f"{k} CPU (ms/step)": get(cpu, k, where) for k in ("tracker", "truth", "recorder")}
    out |= {f"router-{h} CPU (ms/step)": v for h, v in enumerate(get(cpu, "router", where))}
    out |= {f"{k} (bytes/s)": v for k, v in get(block, "bytes_per_s", where).items()}
    return out


def capacity_check(data: dict[str, Any], where: str) -> str:
    check = get(data, "check", where)
    want, got = figures(get(check, "prediction", where), where), figures(get(check, "measured", where), where)
    rows = [{"what": k, "p": p, "m": got.get(k), "ratio": got[k] / p if k in got and p else None}
            for k, p in want.items()]
    meas = check["measured"]
    run = meas.get("run", {})
    head = (f"{get(meas, 'nodes', where)} trackers over {get(meas, 'hosts', where)} hosts (namespaces), a router "
            f"each, {get(meas, 'duration_s', where):.0f} s realtime at {1 / get(meas, 'ts', where):.0f} Hz, measured "
            f"over {get(meas, 'seconds', where):.1f} s of steady state"
            + (f"; the run: {run['deadline_misses']} deadline misses, {run['estimates']}/{run['expected_estimates']} "
               f"estimates, {run['estimates_lost']} lost" if run else "") + ".")
    return head + "\n\n" + render_table(rows, [Column("figure", "what"), Column("predicted", "p", num(1)),
                                               Column("measured", "m", num(1), optional=True),
                                               Column("measured / predicted", "ratio", num(2), optional=True)], where)


def capacity_prediction(data: dict[str, Any], where: str) -> str:
    pred = get(data, "prediction", where)
    cap = get(pred, "capacity", where)
    rows = [{"what": "tracker CPU (ms per step)", "v": f"{get(pred, 'cpu_ms_per_step.tracker', where):.2f}"},
            {"what": "trackers per host, trackers alone", "v": f"{get(cap, 'trackers_only', where):.0f}"},
            {"what": "trackers per host, beside the router serving them", "v": f"{get(cap, 'with_router', where):.0f}"},
            {"what": f"trackers one router serves on {get(pred, 'router_cores', where):g} core",
             "v": f"{get(cap, 'trackers_per_router', where):.0f}"},
            {"what": f"routers for {get(pred, 'nodes', where)} trackers", "v": str(get(cap, 'routers_per_mesh', where))}]
    return (f"N = {get(pred, 'nodes', where)}, degree {get(pred, 'degree', where)}, {get(pred, 'rate_hz', where):g} "
            f"Hz, hosts of {get(pred, 'cores', where):g} cores at a budget of {get(pred, 'budget', where):g}:\n\n"
            + render_table(rows, [Column("prediction", "what"), Column("value", "v")], where))


RENDERERS: dict[tuple[str, str], Renderer] = {
    ("capacity", "fit"): capacity_fit,
    ("capacity", "check"): capacity_check,
    ("capacity", "prediction"): capacity_prediction,
    ("capacity_24", "check"): capacity_check,
    ("capacity_scale", "sizes"): scale_sizes,
}
