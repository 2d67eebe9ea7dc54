"""``zentrack bench capacity``: the capacity model of :mod:`zentrack.study.capacity`, fitted from ``zentrack bench
scale --json`` files, and what it predicts for N trackers of degree d at a rate over H hosts; with
``--check-hosts H``, one realtime run of H hosts in network namespaces (:mod:`zentrack.bench.capacity_check`,
root) measured beside the prediction for it.

Prints every fit's coefficients with the residuals' RMS and largest magnitude, then the predictions (and the
check's measured figures side by side); ``--json`` writes them all.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

from zentrack.bench.scale_graph import check_degree
from zentrack.common.argtypes import positive_float, positive_int
from zentrack.common.report import fmt_num, table, write_json
from zentrack.study.capacity import CapacityModel, fit_model, observations


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fit", action="append", default=[], metavar="SCALE.json",
                   help="a `zentrack bench scale --router --json` file to fit on (repeat for more)")
    p.add_argument("--nodes", type=positive_int, default=16, help="trackers in all (default 16)")
    p.add_argument("--degree", type=positive_int, default=2, help="neighbours per tracker (default 2, the ring)")
    p.add_argument("--hosts", type=positive_int, default=1, help="hosts, a router each (default 1)")
    p.add_argument("--rate", type=positive_float, metavar="HZ", help="steps per second (default: the fit files')")
    p.add_argument("--cores", type=positive_float, default=2.0, help="cores per host (default 2)")
    p.add_argument("--budget", type=positive_float, default=0.7,
                   help="share of the cores the cluster may use, 0-1 (default 0.7)")
    p.add_argument("--check-hosts", type=positive_int, metavar="H",
                   help="also run --nodes trackers over H hosts in network namespaces (root; the scenario's ring, "
                        "its rate) and set the measured figures beside the prediction")
    p.add_argument("--duration", type=positive_float, default=40.0, help="seconds of the check's run (default 40)")
    p.add_argument("--check-dir", metavar="DIR", help="keep the check's folder (logs, compose file) here")
    p.add_argument("--json", metavar="PATH", help="write coefficients, predictions and the check as JSON")


def load_fit(paths: list[str]) -> tuple[CapacityModel, list[dict], float]:
    """The model from the files, their runs, and their step period (one for all of them)."""
    obs, periods = [], set()
    for path in paths:
        try:
            doc = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"--fit {path}: cannot read JSON ({exc})") from None
        runs = observations(doc, f"--fit {path}")
        if not runs:
            raise ValueError(f"--fit {path}: no run through a router with its links measured (bench scale --router)")
        obs += runs
        periods |= {o["ts"] for o in runs}
    if len(periods) > 1:
        raise ValueError(f"--fit: the files' step periods differ ({sorted(periods)}); fit one rate at a time")
    return fit_model(obs), obs, periods.pop()


def coefficient_rows(model: CapacityModel) -> list[list[str]]:
    rows = []
    for name, f in model.to_json().items():
        coef = ", ".join(f"{k} {'not identified' if v is None else fmt_num(v, 4)}" for k, v in f["coef"].items())
        rows.append([name, coef, fmt_num(f["residual_rms"], 4), fmt_num(f["residual_max_abs"], 4),
                     str(f["observations"])])
    return rows


def flat(pred: dict) -> dict[str, float]:
    """The predicted (or measured) CPU per step and bytes per second under one name each."""
    cpu = pred["cpu_ms_per_step"]
    out = {f"{k} CPU ms/step": cpu[k] for k in ("tracker", "truth", "recorder")}
    out |= {f"router-{h} CPU ms/step": v for h, v in enumerate(cpu["router"])}
    out |= {f"{k} bytes/s": v for k, v in pred["bytes_per_s"].items()}
    return out


def side_by_side(pred: dict, meas: dict) -> list[list[str]]:
    p, m = flat(pred), flat(meas)
    return [[k, fmt_num(p[k], 2), fmt_num(m.get(k, math.nan), 2),
             fmt_num(m[k] / p[k], 2) if k in m and p[k] else "-"] for k in p]


def run(args: argparse.Namespace) -> int:
    if not args.fit:
        raise ValueError("--fit: give at least one `zentrack bench scale --router --json` file to fit on")
    check_degree(args.nodes, args.degree)
    if not 0 < args.budget <= 1:
        raise ValueError(f"--budget must be in (0, 1], got {args.budget}")
    if args.hosts > args.nodes or (args.check_hosts or 0) > args.nodes:
        raise ValueError(f"--hosts and --check-hosts must be at most --nodes ({args.nodes})")
    if args.check_hosts:
        if args.degree != 2:
            raise ValueError("--check-hosts runs the scenario's ring: --degree must be 2")
        if os.geteuid() != 0:
            raise ValueError("--check-hosts needs root (network namespaces)")
    model, obs, ts = load_fit(args.fit)
    rate = args.rate or 1.0 / ts
    print(f"fitted on {len(obs)} runs: " + ", ".join(f"N {o['nodes']} d {o['degree']}" for o in obs))
    print(table(["fit", "coefficients (ms per step; bytes per step)", "resid RMS", "resid max", "runs/rows"],
                coefficient_rows(model)))
    pred = model.predict(args.nodes, args.degree, args.hosts, rate, args.cores, args.budget)
    cap = pred["capacity"]
    print(f"\nN {args.nodes}, degree {args.degree}, {args.hosts} host(s), {rate:g} Hz: tracker "
          f"{fmt_num(pred['cpu_ms_per_step']['tracker'], 2)} ms/step, routers "
          + ", ".join(fmt_num(v, 2) for v in pred["cpu_ms_per_step"]["router"]) + " ms/step")
    print(f"per host of {args.cores:g} cores at {args.budget:g}: {cap['trackers_only']:.0f} trackers alone, "
          f"{cap['with_router']:.0f} beside their router; a router of one core serves "
          f"{cap['trackers_per_router']:.0f}; routers for {args.nodes}: {cap['routers_per_mesh']}")
    print(table(["link", "bytes/s"], [[k, fmt_num(v, 0)] for k, v in pred["bytes_per_s"].items()]))
    out = {"command": "bench capacity", "fit_files": [Path(p).name for p in args.fit], "fit_runs":
           [{"nodes": o["nodes"], "degree": o["degree"]} for o in obs], "model": model.to_json(), "prediction": pred}
    if args.check_hosts:
        from zentrack.bench.capacity_check import run_check

        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(args.check_dir) if args.check_dir else Path(tmp)
            try:
                meas = run_check(args.nodes, args.check_hosts, args.duration, ts, folder)
            except RuntimeError as exc:  # the run itself failed (a service did not start): not bad input
                print(f"zentrack bench capacity: check failed: {exc}", file=sys.stderr)
                return 1
        want = model.predict(args.nodes, 2, args.check_hosts, 1.0 / ts, args.cores, args.budget)
        print(f"\ncheck: {args.nodes} trackers over {args.check_hosts} hosts, {args.duration:g} s, measured over "
              f"{meas['seconds']:.1f} s" + (f"; run: {meas['run']}" if "run" in meas else ""))
        print(table(["figure", "predicted", "measured", "measured/predicted"], side_by_side(want, meas)))
        out["check"] = {"prediction": want, "measured": meas}
    if args.json:
        write_json(args.json, out)
    return 0
