"""``zentrack bench paper3``: paper 3's comparison (SecKF, EKF, UKF, pure linearisation) at the paper's scale.

For R Monte Carlo runs (default the paper's 100,000, batched: every run steps in the same numpy calls) of
``deploy/scenarios/seckf-power.toml`` (scenario 2, constant power with drag) and ``seckf-turn.toml``
(scenario 1), or the ``--scenarios`` given: each filter tracks the ship from the video satellite's angles, and the mean
position error (over runs) at each of the 20 observations is reported and plotted (PNG and SVG, like the paper's
figure). Beside the paper: SecKF's error reduction over the EKF at the 20th observation (paper: 12.5 %; its
abstract: 28.6 %), whether the UKF is best, and each filter's time per step when run single-step (a batch of
one, as on board), as ratios beside the paper's Table 6 (SecKF/EKF about 3.1, UKF/SecKF about 10.4).  As a diagnostic, the
largest relative change SecKF's secant correction made to the Jacobians over all runs and steps (where it is
tiny, SecKF is the EKF). Against the limit: position RMSE / sqrt(PCRLB) (each run's bound along its own
trajectory, the ship's dynamics linearised along it) at the last observation, over all, and per run.  The four filters run in ``--jobs`` forked workers; the single-step timings run
alone afterwards.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import positive_int
from zentrack.common.plots import COLORS as PALETTE
from zentrack.common.plots import log_scale, new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, note, outputs_line
from zentrack.common.report import figure_path, fmt_num, fmt_stats, stats, table, write_json
from zentrack.config import catalogue
from zentrack.config.scenario_config import load_scenario_config
from zentrack.fusion.consistency import anees_band, nees
from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext
from zentrack.fusion.linalg import GaussianState
from zentrack.fusion.measurement import wrap_angle
from zentrack.study.pcrlb import scenario_bound
from zentrack.study.simulator import run_centralized
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.simulate import simulate

FILTERS = ("lin", "ekf", "ukf", "seckf")
PAPER_REDUCTION = {"table": 0.125, "abstract": 0.286}
#: the paper's Table 6, seconds per step on its PC
PAPER_TIMES = {"lin": 2.578e-6, "ukf": 7.675e-4, "ekf": 2.405e-5, "seckf": 7.367e-5}
#: each filter's colour and name in the figure
COLORS = {"lin": PALETTE[7], "ekf": PALETTE[0], "ukf": PALETTE[2], "seckf": PALETTE[1]}
LABELS = {"lin": "pure linearisation", "ekf": "EKF", "ukf": "UKF", "seckf": "SecKF"}
MARKERS = {"lin": "s-", "ekf": "o-", "ukf": "^--", "seckf": "x:"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=100_000, help="Monte Carlo runs (default 100000)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--scenarios", default="seckf-power,seckf-turn", type=catalogue.scenario_list,
                   help="comma-separated scenario names or paths (default: scenario 2, then scenario 1)")
    p.add_argument("--single-steps", type=positive_int, default=300, help="steps timed per filter single-step")
    p.add_argument("--jobs", type=positive_int, default=min(os.cpu_count() or 1, len(FILTERS)),
                   help="filters run in parallel worker processes (default: the CPU count, at most 4); the "
                        "single-step timings always run alone, after them")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="position error per observation (default: beside --json)")


def all_spd(cov: np.ndarray) -> bool:
    """Whether every matrix of the stack is finite, symmetric and positive definite (one batched Cholesky)."""
    if not (np.all(np.isfinite(cov)) and np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-9, atol=1e-12)):
        return False
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return False
    return True


def position_floor(scn: ScenarioData) -> np.ndarray:
    """``(R, K)``: the trace of the position block of each run's PCRLB (the truth moves by the ship's ``f``
    plus Gaussian noise: :func:`~zentrack.study.pcrlb.scenario_bound` uses ``f``'s Jacobian along the run)."""
    bound = scenario_bound(scn)
    return np.trace(bound[:, :, :3, :3], axis1=2, axis2=3)


def bound_figures(sq_err: np.ndarray, floor: np.ndarray) -> dict:
    """RMSE / sqrt(bound) of the position from squared errors and the bound's trace ``(R, K)``: over the runs
    at the last observation and over every observation, and per run (median and IQR; with 20 correlated
    errors per run a run's figure scatters widely around the ensemble one)."""
    per_run = np.sqrt(np.mean(sq_err, axis=1) / np.mean(floor, axis=1))
    return {"at_last": float(np.sqrt(np.mean(sq_err[:, -1]) / np.mean(floor[:, -1]))),
            "all_observations": float(np.sqrt(np.mean(sq_err) / np.mean(floor))),
            "per_run": stats(per_run)}


def position_errors(scn: ScenarioData, name: str, floor: np.ndarray | None = None) -> dict:
    """One filter over every run: the mean position error over runs at each observation, the wall time, the
    diverged runs, whether every covariance of every run and step is SPD, (SecKF) how far its secant
    matrices moved from the Jacobians, and with the bound's ``floor`` (:func:`position_floor`) RMSE / sqrt(bound)."""
    filt = FILTER_REGISTRY.create(name, {}, FilterContext.from_scenario(scn))
    if hasattr(filt, "track_deviation"):
        filt.track_deviation()
    t0 = time.perf_counter()
    res = run_centralized(scn, filt)
    wall = time.perf_counter() - t0
    diff = res.mean[:, :, 0] - scn.truth
    diff[..., 4] = wrap_angle(diff[..., 4])  # heading
    err = np.nanmean(np.linalg.norm(diff[..., :3], axis=-1), axis=0)
    anees = np.nanmean(nees(diff, res.cov[:, :, 0]), axis=0)  # (K,) full 5-state NEES, mean over runs
    out = {"error_per_observation": err.tolist(), "error_at_20": float(err[-1]), "mean_error": float(err.mean()),
           "anees_per_observation": anees.tolist(), "anees_at_20": float(anees[-1]),
           "diverged_runs": int(np.sum(res.diverged_at >= 0)), "all_spd": all_spd(res.cov[:, :, 0]),
           "wall_s": wall, "us_per_run_step_batched": 1e6 * wall / (scn.runs * scn.steps)}
    if floor is not None:
        out["rmse_over_sqrt_bound"] = bound_figures(np.sum(diff[..., :3] ** 2, axis=-1), floor)
    deviation = getattr(filt, "deviation", None)
    if deviation is not None:
        out["secant_vs_jacobian_max_relative"] = {k: max(v, default=0.0) for k, v in deviation.items()}
    return out


_SHARED: dict = {}


def _job(name: str) -> tuple[str, dict]:
    return name, position_errors(_SHARED["scn"], name, _SHARED["floor"])


def run_filters(scn: ScenarioData, jobs: int) -> dict[str, dict]:
    """:func:`position_errors` of every filter; with ``jobs > 1`` in forked workers that share the simulated
    scenario (copy-on-write), the slowest filters first."""
    order = sorted(FILTERS, key=lambda f: -PAPER_TIMES[f]) if jobs > 1 else list(FILTERS)
    floor = position_floor(scn)
    done: dict[str, dict] = {}
    if jobs <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        for f in FILTERS:
            done[f] = position_errors(scn, f, floor)
            note(f"    {f} done", done=1)
        return done
    _SHARED["scn"], _SHARED["floor"] = scn, floor
    try:
        with multiprocessing.get_context("fork").Pool(jobs) as pool:
            for name, row in pool.imap_unordered(_job, order):
                done[name] = row
                note(f"    {name} done", done=1)
    finally:
        _SHARED.clear()
    return {f: done[f] for f in FILTERS}


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


def plot(curves: dict[str, dict[str, list[float]]], runs: int, path: Path) -> list[Path]:
    """Per scenario, left: each filter's mean position error (over ``runs`` runs) against the observation
    number, as the paper's figure (a log scale when the errors span more than 10x); right: the UKF's and SecKF's
    error minus the EKF's, which the left panel cannot resolve when they nearly coincide. PNG and SVG."""
    fig, axes = new_figure(len(curves), 2, width=12.0, height=3.8 * len(curves))
    for row, (scenario, per_filter) in enumerate(curves.items()):
        ax, diff_ax = axes[2 * row], axes[2 * row + 1]
        values = np.concatenate([np.asarray(v, dtype=float) for v in per_filter.values()])
        values = values[np.isfinite(values) & (values > 0)]
        obs = np.arange(1, len(next(iter(per_filter.values()))) + 1)
        for name, errors in per_filter.items():
            ax.plot(obs, errors, MARKERS[name], color=COLORS[name], markersize=4, linewidth=1.4,
                    label=LABELS.get(name, name), fillstyle="none")
        if values.size and values.max() / values.min() > 10:
            log_scale(ax)
        if "ekf" in per_filter:
            ekf = np.asarray(per_filter["ekf"], dtype=float)
            for name in ("ukf", "seckf"):
                if name in per_filter:
                    diff_ax.plot(obs, np.asarray(per_filter[name]) - ekf, MARKERS[name], color=COLORS[name],
                                 markersize=4, linewidth=1.4, label=f"{LABELS[name]} - EKF", fillstyle="none")
            diff_ax.axhline(0.0, color="black", linewidth=0.8)
            diff_ax.legend(fontsize=8)
        for a in (ax, diff_ax):
            a.set_xticks(obs[::2] if obs.size > 12 else obs)
        style_axes(ax, f"{scenario}: mean position error over {runs} runs", "observation", "mean position error (m)")
        style_axes(diff_ax, f"{scenario}: difference from the EKF", "observation", "error minus the EKF's (m)")
        ax.legend(fontsize=8)
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    out: dict = {"command": "bench paper3", "runs": args.runs, "seed": args.seed, "scenarios": {},
                 "paper": {"reduction_at_20": PAPER_REDUCTION, "table6_s": PAPER_TIMES}}
    curves: dict[str, dict[str, list[float]]] = {}
    names = args.scenarios.split(",")
    bar = Progress(len(names) * len(FILTERS), "filters", label="bench paper3")
    with bar:
        for name in names:
            cfg = load_scenario_config(name)
            t0 = time.perf_counter()
            scn = simulate(cfg.spec, runs=args.runs, seed=args.seed, ts=cfg.ts)
            note(f"[paper3] {cfg.source}: {args.runs} runs x {scn.steps} observations simulated in "
                     f"{time.perf_counter() - t0:.1f} s")
            rows = run_filters(scn, args.jobs)
            for filt in FILTERS:
                note(f"    {filt}: {rows[filt]['wall_s']:.1f} s, error at observation {scn.steps}: "
                         f"{rows[filt]['error_at_20']:.3f} m")
            reduction = 1.0 - rows["seckf"]["error_at_20"] / rows["ekf"]["error_at_20"]
            best = min(FILTERS, key=lambda f: rows[f]["error_at_20"])
            single = single_step_seconds(scn, args.single_steps)
            ratios = {"seckf/ekf": single["seckf"] / single["ekf"], "ukf/seckf": single["ukf"] / single["seckf"],
                      "paper seckf/ekf": PAPER_TIMES["seckf"] / PAPER_TIMES["ekf"],
                      "paper ukf/seckf": PAPER_TIMES["ukf"] / PAPER_TIMES["seckf"]}
            band = anees_band(scn.truth.shape[-1], scn.runs)
            lines = [[f, fmt_num(rows[f]["error_at_20"], 3), fmt_num(rows[f]["mean_error"], 3),
                      fmt_num(rows[f]["anees_at_20"], 2), rows[f]["diverged_runs"],
                      "yes" if rows[f]["all_spd"] else "NO",
                      fmt_num(rows[f]["us_per_run_step_batched"], 2), fmt_num(single[f] * 1e6, 1),
                      fmt_num(PAPER_TIMES[f] * 1e6, 1), fmt_num(rows[f]["rmse_over_sqrt_bound"]["at_last"], 3),
                      fmt_num(rows[f]["rmse_over_sqrt_bound"]["all_observations"], 3),
                      fmt_stats(rows[f]["rmse_over_sqrt_bound"]["per_run"], 2)] for f in FILTERS]
            print(f"\npaper 3, {cfg.source}: {args.runs} runs, {scn.steps} observations of {scn.ts:g} s")
            print(table(["filter", f"error at obs {scn.steps} (m)", "mean error (m)",
                         f"ANEES at obs {scn.steps} (band {band[0]:.2f}-{band[1]:.2f})", "diverged", "all SPD", "µs/run-step batched",
                         "µs/step single", "paper µs/step", f"RMSE/sqrt(B) obs {scn.steps}", "all obs",
                         "per run"], lines))
            print(f"SecKF error reduction over EKF at observation {scn.steps}: {100 * reduction:.2f} % "
                  f"(paper {100 * PAPER_REDUCTION['table']:.1f} %, abstract {100 * PAPER_REDUCTION['abstract']:.1f} %); "
                  f"best: {best} (paper: ukf)")
            dev = rows["seckf"].get("secant_vs_jacobian_max_relative", {})
            if dev:
                print(f"SecKF's secant matrices differ from the Jacobians by at most {dev['measurement']:.2e} (H) and "
                      f"{dev['state']:.2e} (F), relative, over all runs and steps")
            print(f"single-step time ratios: SecKF/EKF {ratios['seckf/ekf']:.2f} (paper {ratios['paper seckf/ekf']:.2f}), "
                  f"UKF/SecKF {ratios['ukf/seckf']:.2f} (paper {ratios['paper ukf/seckf']:.2f})")
            out["scenarios"][scn.name] = {"source": cfg.source, "filters": rows, "reduction_at_last": reduction,
                                          "anees_band_95": band,
                                          "best": best, "single_step_s": single, "ratios": ratios,
                                          "batched_wall_s": sum(r["wall_s"] for r in rows.values()),
                                          "jobs": args.jobs}
            curves[scn.name] = {f: rows[f]["error_per_observation"] for f in FILTERS}
    out["wall_s"] = time.perf_counter() - t_start
    print(f"wall time {out['wall_s']:.0f} s")
    plot_path = figure_path(args.plot, args.json)
    figures = plot(curves, args.runs, plot_path) if plot_path is not None else None
    if args.json:
        write_json(args.json, out)
    print(outputs_line("bench paper3 done", json=args.json, plot=figures))
    return 0
