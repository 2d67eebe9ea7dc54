"""``zentrack bench paper003``: seed 003's comparison (SecKF, EKF, UKF, pure linearisation) at the paper's scale.

For R Monte Carlo runs (default the paper's 100,000, batched: every run steps in the same numpy calls) of
``deploy/scenarios/seckf-power.toml`` (scenario 2, constant power with drag) and, with ``--scenarios``, of
``seckf-turn.toml`` (scenario 1): each filter tracks the ship from the video satellite's angles, and the mean
position error (over runs) at each of the 20 observations is reported and plotted (PNG, like the paper's
figure). Beside the paper: SecKF's error reduction over the EKF at the 20th observation (paper: 12.5 %; its
abstract: 28.6 %), whether the UKF is best, and each filter's time per step when run single-step (a batch of
one, as on board), as ratios beside the paper's Table 6 (SecKF/EKF about 3.1, UKF/SecKF about 10.4).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from zentrack.cluster.report import fmt_num, table, write_json
from zentrack.common.argtypes import positive_int
from zentrack.config.scenario_config import load_scenario_config
from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext
from zentrack.fusion.linalg import GaussianState
from zentrack.fusion.scenario import ScenarioData, simulate
from zentrack.fusion.simulator import run_centralized

FILTERS = ("lin", "ekf", "ukf", "seckf")
PAPER_REDUCTION = {"table": 0.125, "abstract": 0.286}
#: the paper's Table 6, seconds per step on its PC
PAPER_TIMES = {"lin": 2.578e-6, "ukf": 7.675e-4, "ekf": 2.405e-5, "seckf": 7.367e-5}
COLORS = {"lin": (120, 120, 120), "ekf": (30, 90, 200), "ukf": (30, 150, 60), "seckf": (200, 30, 30)}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=100_000, help="Monte Carlo runs (default 100000)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--scenarios", default="seckf-power", help="comma-separated scenario names or paths")
    p.add_argument("--single-steps", type=positive_int, default=300, help="steps timed per filter single-step")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="position error per observation (default: beside --json)")


def progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def position_errors(scn: ScenarioData, name: str) -> tuple[np.ndarray, float, int, bool]:
    """Mean position error over runs at each observation ``(K,)``, the wall time, diverged runs, and whether
    every covariance of every run and step is symmetric positive definite."""
    filt = FILTER_REGISTRY.create(name, {}, FilterContext.from_scenario(scn))
    t0 = time.perf_counter()
    res = run_centralized(scn, filt)
    wall = time.perf_counter() - t0
    err = np.linalg.norm(res.mean[:, :, 0, :3] - scn.truth[:, :, :3], axis=-1)
    cov = res.cov[:, :, 0]
    spd = bool(np.all(np.isfinite(cov)) and np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-9, atol=1e-12)
               and np.linalg.eigvalsh(cov).min() > 0)
    return np.nanmean(err, axis=0), wall, int(np.sum(res.diverged_at >= 0)), spd


def single_step_seconds(scn: ScenarioData, steps: int, rounds: int = 3) -> dict[str, float]:
    """Seconds per predict + update of each filter on a batch of one (median of ``rounds``, filters alternated
    within each round so machine noise hits all of them)."""
    one = scn.run(0)
    filters = {n: FILTER_REGISTRY.create(n, {}, FilterContext.from_scenario(one)) for n in FILTERS}
    sensors = one.sensors_at(0)[None]
    z = one.measurements[0, 0, :, :].reshape(1, -1)
    noise = one.noise_cov[0][None]
    times: dict[str, list[float]] = {n: [] for n in FILTERS}
    for _ in range(rounds):
        for name, filt in filters.items():
            state: GaussianState = filt.initial_state(one.x0_estimate, one.p0)
            t0 = time.perf_counter()
            for _ in range(steps):
                state = filt.update(filt.predict(state), z, sensors, noise)
            times[name].append((time.perf_counter() - t0) / steps)
    return {n: float(np.median(v)) for n, v in times.items()}


def plot(curves: dict[str, dict[str, list[float]]], path: Path) -> None:
    """One panel per scenario: each filter's mean position error against the observation number."""
    from PIL import Image, ImageDraw

    w, pad, panel_h = 1000, 70, 380
    img = Image.new("RGB", (w, pad + panel_h * len(curves)), "white")
    d = ImageDraw.Draw(img)
    for j, (scenario, per_filter) in enumerate(curves.items()):
        top, bottom = pad + j * panel_h, pad + j * panel_h + panel_h - 60
        hi = max(max(v) for v in per_filter.values()) * 1.1
        k = len(next(iter(per_filter.values())))
        d.rectangle([pad, top, w - pad, bottom], outline="black")
        d.text((pad, top - 18), f"{scenario}: mean position error (m) per observation", fill="black")
        d.text((8, top), f"{hi:.3g}", fill="black")
        for name, values in per_filter.items():
            pts = [(pad + (w - 2 * pad) * i / max(k - 1, 1), bottom - (bottom - top) * v / hi) for i, v in enumerate(values)]
            d.line(pts, fill=COLORS[name], width=3)
        for i, name in enumerate(per_filter):
            d.text((w - pad - 80, top + 8 + 14 * i), name, fill=COLORS[name])
    img.save(path)


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    out: dict = {"command": "bench paper003", "runs": args.runs, "seed": args.seed, "scenarios": {},
                 "paper": {"reduction_at_20": PAPER_REDUCTION, "table6_s": PAPER_TIMES}}
    curves: dict[str, dict[str, list[float]]] = {}
    for name in args.scenarios.split(","):
        cfg = load_scenario_config(name)
        t0 = time.perf_counter()
        scn = simulate(cfg.spec, runs=args.runs, seed=args.seed, ts=cfg.ts)
        progress(f"[paper003] {cfg.source}: {args.runs} runs x {scn.steps} observations simulated in "
                 f"{time.perf_counter() - t0:.1f} s")
        rows, walls = {}, {}
        for filt in FILTERS:
            err, wall, diverged, spd = position_errors(scn, filt)
            rows[filt] = {"error_per_observation": err.tolist(), "error_at_20": float(err[-1]), "all_spd": spd,
                          "mean_error": float(err.mean()), "diverged_runs": diverged, "wall_s": wall,
                          "us_per_run_step_batched": 1e6 * wall / (args.runs * scn.steps)}
            walls[filt] = wall
            progress(f"    {filt}: {wall:.1f} s, error at observation {scn.steps}: {err[-1]:.3f} m")
        reduction = 1.0 - rows["seckf"]["error_at_20"] / rows["ekf"]["error_at_20"]
        best = min(FILTERS, key=lambda f: rows[f]["error_at_20"])
        single = single_step_seconds(scn, args.single_steps)
        ratios = {"seckf/ekf": single["seckf"] / single["ekf"], "ukf/seckf": single["ukf"] / single["seckf"],
                  "paper seckf/ekf": PAPER_TIMES["seckf"] / PAPER_TIMES["ekf"],
                  "paper ukf/seckf": PAPER_TIMES["ukf"] / PAPER_TIMES["seckf"]}
        lines = [[f, fmt_num(rows[f]["error_at_20"], 3), fmt_num(rows[f]["mean_error"], 3), rows[f]["diverged_runs"],
                  "yes" if rows[f]["all_spd"] else "NO",
                  fmt_num(rows[f]["us_per_run_step_batched"], 2), fmt_num(single[f] * 1e6, 1),
                  fmt_num(PAPER_TIMES[f] * 1e6, 1)] for f in FILTERS]
        print(f"\nseed 003, {cfg.source}: {args.runs} runs, {scn.steps} observations of {scn.ts:g} s")
        print(table(["filter", f"error at obs {scn.steps} (m)", "mean error (m)", "diverged", "all SPD", "µs/run-step batched",
                     "µs/step single", "paper µs/step"], lines))
        print(f"SecKF error reduction over EKF at observation {scn.steps}: {100 * reduction:.2f} % "
              f"(paper {100 * PAPER_REDUCTION['table']:.1f} %, abstract {100 * PAPER_REDUCTION['abstract']:.1f} %); "
              f"best: {best} (paper: ukf)")
        print(f"single-step time ratios: SecKF/EKF {ratios['seckf/ekf']:.2f} (paper {ratios['paper seckf/ekf']:.2f}), "
              f"UKF/SecKF {ratios['ukf/seckf']:.2f} (paper {ratios['paper ukf/seckf']:.2f})")
        out["scenarios"][scn.name] = {"source": cfg.source, "filters": rows, "reduction_at_last": reduction,
                                      "best": best, "single_step_s": single, "ratios": ratios,
                                      "batched_wall_s": sum(walls.values())}
        curves[scn.name] = {f: rows[f]["error_per_observation"] for f in FILTERS}
    out["wall_s"] = time.perf_counter() - t_start
    print(f"wall time {out['wall_s']:.0f} s")
    plot_path = Path(args.plot) if args.plot else (Path(args.json).with_suffix(".png") if args.json else None)
    if plot_path is not None:
        plot(curves, plot_path)
        print(f"plot: {plot_path}")
    if args.json:
        write_json(args.json, out)
    return 0
