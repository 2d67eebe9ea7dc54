"""``zentrack bench paper1``: paper 1's figures (per-step RMSE of local filters and the fused estimate in
clutter) beside the posterior Cramér–Rao lower bound, on ``deploy/scenarios/fpf-clutter.toml``.

For R Monte Carlo runs (batched, fixed seeds) of the scenario:

- every local filter (``pda-fpf``, ``pda-pf``, ``pdaf-ekf``, ``nn-ekf``) runs on each sensor alone, as in the
  paper (no feedback to the local filters), and the paper's fusion centre combines the three local estimates
  by their covariances (``covariance_weighted_fusion``, errors assumed independent);
- zentrack's own architecture runs beside it: the same PDA-FPF with CI diffusion and feedback (each cloud moved
  onto its fused prior every step);
- the PCRLB of the scenario (information reduction factor for P_D and the clutter density in the gate, the
  sensors' information summed) gives the floor; RMSE / sqrt(bound) is reported per filter over the second
  half of the run, with ANEES and its 95 % band.

The paper's figures are curves without tables: fused velocity RMSE settling near 1 m/s, local sensors 1.5-2.5
m/s, fused position below every local sensor. Its parameters were lost, so the scenario is zentrack's
(stated in the TOML file); the comparison is of shape, not of numbers. Writes a figure (PNG and SVG, ``--plot``) and JSON.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from zentrack.common.argtypes import positive_int
from zentrack.common.plots import COLORS as PALETTE
from zentrack.common.plots import legend_outside, new_figure, save_png_svg, style_axes
from zentrack.common.progress import Progress, note, outputs_line
from zentrack.common.report import figure_path, fmt_num, fmt_stats, stats, table, write_json
from zentrack.config import catalogue
from zentrack.config.scenario_config import load_scenario_config
from zentrack.fusion.consistency import anees_band
from zentrack.fusion.feedforward import covariance_weighted_fusion
from zentrack.fusion.filters import FILTER_REGISTRY, FilterContext
from zentrack.fusion.filters.pda_common import ParticleClutterFilter
from zentrack.fusion.gate import expected_gate_clutter
from zentrack.study.pcrlb import bound_ratio, bound_rmse, information_reduction_factor, pcrlb, pcrlb_per_run
from zentrack.study.simulator import run_distributed
from zentrack.truth.simulation.scenario import ScenarioData
from zentrack.truth.simulation.simulate import simulate

LOCAL_FILTERS = ("pda-fpf", "pda-pf", "pdaf-ekf", "nn-ekf")
#: the paper's reported shape (Figs. 5-6): fused velocity RMSE near 1 m/s, the locals 1.5-2.5 m/s
PAPER_FUSED_V_MPS = 1.0
PAPER_LOCAL_V_MPS = (1.5, 2.5)
PAPER_SHAPE = {"fused_velocity_rmse_mps": PAPER_FUSED_V_MPS, "local_velocity_rmse_mps": PAPER_LOCAL_V_MPS}
POSITION, VELOCITY = [0, 1, 2], [3, 4, 5]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=positive_int, default=50, help="Monte Carlo runs (default 50)")
    p.add_argument("--seed", type=int, default=0, help="base seed (run r uses child r of this seed)")
    p.add_argument("--steps", type=positive_int, help="override the scenario's length (quick looks only)")
    p.add_argument("--scenario", default="fpf-clutter", type=catalogue.scenario_arg, help="scenario name or TOML path (default fpf-clutter)")
    p.add_argument("--json", metavar="PATH", help="write all figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="write the per-step RMSE plot (default: beside --json)")


def per_step_rmse(err: np.ndarray, idx: list[int]) -> np.ndarray:
    """RMSE over runs per step ``(K,)`` of the components ``idx`` of errors ``(R, K, n)``."""
    return np.sqrt(np.mean(np.sum(err[..., idx] ** 2, axis=-1), axis=0))


def anees(err: np.ndarray, cov: np.ndarray) -> float:
    """Average NEES over runs and steps of ``err`` ``(R, K, n)`` with covariances ``(R, K, n, n)``."""
    nees = np.einsum("rki,rki->rk", err, np.linalg.solve(cov, err[..., None])[..., 0])
    return float(nees.mean())


def run_benchmark(scn: ScenarioData, filter_params: dict, seed: int, run_bound: np.ndarray | None = None) -> dict:
    """Every filter on ``scn``: per-step RMSE curves, summary figures and timings; with each run's bound
    ``run_bound`` ``(R, K, n, n)`` the fused RMSE / sqrt(bound) per run over the second half (median, IQR)."""
    r, k_steps, m = scn.runs, scn.steps, scn.nodes
    alone = np.eye(m)  # the paper's locals: no fusion feeds back
    curves: dict[str, dict] = {}
    rows: dict[str, dict] = {}
    timing: dict[str, dict[str, float]] = {}
    for name in LOCAL_FILTERS + ("pda-fpf+ci",):
        kind, feedback = name.removesuffix("+ci"), name.endswith("+ci")
        params = {k: v for k, v in filter_params.items() if k in {"gate", "detection_prob", "clutter_density"}}
        if kind == "pda-fpf":
            params.update({k: v for k, v in filter_params.items() if k in {"particles", "flow_substeps"}})
        rng = np.random.default_rng(np.random.SeedSequence([seed, len(timing)]))
        filt = FILTER_REGISTRY.create(kind, params, FilterContext.from_scenario(scn, rng))
        t0 = time.perf_counter()
        res = run_distributed(scn, filt, "ci", weights=None if feedback else alone)
        seconds = time.perf_counter() - t0
        node_steps = r * k_steps * m
        timing[name] = {"ms_per_node_step": 1e3 * seconds / node_steps, "seconds": seconds}
        if isinstance(filt, ParticleClutterFilter):
            timing[name]["us_per_particle_step"] = 1e6 * seconds / (node_steps * filt.count)
        fused = covariance_weighted_fusion(res.mean, res.cov)  # the fusion centre over the sensor axis
        err_local = res.mean - scn.truth[:, :, None, :]
        err_fused = fused.mean - scn.truth
        curves[name] = {
            "local_p": [per_step_rmse(err_local[:, :, i], POSITION).tolist() for i in range(m)],
            "local_v": [per_step_rmse(err_local[:, :, i], VELOCITY).tolist() for i in range(m)],
            "fused_p": per_step_rmse(err_fused, POSITION).tolist(),
            "fused_v": per_step_rmse(err_fused, VELOCITY).tolist(),
        }
        half = slice(k_steps // 2, None)
        rows[name] = {
            "local_rmse_p": [float(np.sqrt(np.mean(np.sum(err_local[:, half, i][..., POSITION] ** 2, -1)))) for i in range(m)],
            "local_rmse_v": [float(np.sqrt(np.mean(np.sum(err_local[:, half, i][..., VELOCITY] ** 2, -1)))) for i in range(m)],
            "fused_rmse_p": float(np.sqrt(np.mean(np.sum(err_fused[:, half][..., POSITION] ** 2, -1)))),
            "fused_rmse_v": float(np.sqrt(np.mean(np.sum(err_fused[:, half][..., VELOCITY] ** 2, -1)))),
            "local_anees": [anees(err_local[:, half, i], res.cov[:, half, i]) for i in range(m)],
            "fused_anees": anees(err_fused[:, half], fused.cov[:, half]),
            "diverged_runs": int(np.sum(res.diverged_at >= 0)),
        }
        if run_bound is not None:
            for g, idx in (("p", POSITION), ("v", VELOCITY)):
                ratio = bound_ratio(err_fused[:, half][:, :, None], run_bound[:, half], idx)
                rows[name][f"fused_rmse_{g}_over_sqrt_bound_per_run"] = stats(ratio)
        note(f"  {name}: {seconds:.1f} s ({timing[name]['ms_per_node_step']:.2f} ms per node-step)", done=1)
    return {"curves": curves, "rows": rows, "timing": timing}


def bound_figures(scn: ScenarioData, clutter, gate: float) -> tuple[np.ndarray, np.ndarray, list[float], list[float]]:
    """The PCRLB ``(K, n, n)`` with its information reduction factor, each run's own ``(R, K, n, n)``, and
    lambda V_gate per sensor."""
    motion = scn.motion_model()
    noise = scn.noise_cov[0]
    density = clutter.clutter_density(scn.nodes)
    q2 = np.array([information_reduction_factor(clutter.p_d, float(d), noise, gate) for d in density])
    bound = pcrlb(scn.truth, scn.sensors, motion.A, motion.Q, scn.p0, scn.noise_cov, q2)
    run_bound = pcrlb_per_run(scn.truth, scn.sensors, motion.A, motion.Q, scn.p0, scn.noise_cov, q2=q2)
    innov = 2.0 * noise  # S = R + H P H^T, with the filters' steady-state H P H^T about R
    gate_clutter = [float(expected_gate_clutter(innov, gate, float(d))) for d in density]
    return bound, run_bound, q2.tolist(), gate_clutter


#: each filter's colour in the figure
COLORS = {"pda-fpf": PALETTE[1], "pda-pf": PALETTE[0], "pdaf-ekf": PALETTE[2], "nn-ekf": PALETTE[5],
          "pda-fpf+ci": PALETTE[3]}


def plot(curves: dict, bound_p: np.ndarray, bound_v: np.ndarray, ts: float, path: Path) -> list[Path]:
    """Two panels (position, velocity RMSE over time): each filter's fused curve, PDA-FPF's local sensors (thin),
    sqrt(PCRLB) (black); the first tenth of the run (prior, transient) is left out of the y range. PNG and SVG."""
    fig, axes = new_figure(2, 1, width=11.0, height=7.5, sharex=True)
    steps = len(bound_p)
    t = np.arange(steps) * ts
    skip = steps // 10
    for ax, key, bound, label, unit in ((axes[0], "p", bound_p, "position RMSE", "m"),
                                        (axes[1], "v", bound_v, "velocity RMSE", "m/s")):
        shown = []
        for i, local in enumerate(curves["pda-fpf"][f"local_{key}"]):
            ax.plot(t, local, color=COLORS["pda-fpf"], alpha=0.35, linewidth=0.7,
                    label="PDA-FPF, each sensor alone" if i == 0 else None)
            shown.append(np.asarray(local)[skip:])
        for name, c in curves.items():
            ax.plot(t, c[f"fused_{key}"], color=COLORS[name], linewidth=1.8, label=f"{name}, fused")
            shown.append(np.asarray(c[f"fused_{key}"])[skip:])
        ax.plot(t, bound, color="black", linewidth=1.4, linestyle="--", label="sqrt(PCRLB)")
        top = float(np.nanmax(np.concatenate(shown))) * 1.1
        ax.set_ylim(0.0, top)
        style_axes(ax, f"{label} over {steps} scans of {ts:g} s ({len(curves['pda-fpf'][f'local_{key}'])} sensors)",
                   "time (s)" if key == "v" else "", f"{label} ({unit})")
        legend_outside(ax)
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    cfg = load_scenario_config(args.scenario)
    if cfg.spec.clutter is None:
        raise ValueError(f"{cfg.source}: bench paper1 needs a scenario with a [clutter] table")
    if args.steps:
        cfg.spec.steps = args.steps
    gate = float(cfg.filter_params.get("gate", 16.0))
    t0 = time.perf_counter()
    scn = simulate(cfg.spec, runs=args.runs, seed=args.seed, ts=cfg.ts)
    note(f"[paper1] {cfg.source}: {args.runs} runs x {scn.steps} scans x {scn.nodes} sensors simulated "
             f"in {time.perf_counter() - t0:.1f} s")
    bound, run_bound, q2, gate_clutter = bound_figures(scn, cfg.spec.clutter, gate)
    with Progress(len(LOCAL_FILTERS) + 1, "filters", label="bench paper1"):
        figs = run_benchmark(scn, dict(cfg.filter_params), args.seed, run_bound)
    half = slice(scn.steps // 2, None)
    floor_p = float(np.sqrt(np.mean(bound_rmse(bound, POSITION)[half] ** 2)))
    floor_v = float(np.sqrt(np.mean(bound_rmse(bound, VELOCITY)[half] ** 2)))
    lo, hi = anees_band(6, args.runs * (scn.steps - scn.steps // 2))
    rows = []
    for name, row in figs["rows"].items():
        row["fused_rmse_p_over_sqrt_bound"] = row["fused_rmse_p"] / floor_p
        row["fused_rmse_v_over_sqrt_bound"] = row["fused_rmse_v"] / floor_v
        row["fused_beats_every_local"] = bool(row["fused_rmse_p"] < min(row["local_rmse_p"])
                                              and row["fused_rmse_v"] < min(row["local_rmse_v"]))
        rows.append([name, " / ".join(fmt_num(v, 2) for v in row["local_rmse_v"]), fmt_num(row["fused_rmse_v"], 2),
                     fmt_num(row["fused_rmse_p"], 2), fmt_num(row["fused_rmse_p_over_sqrt_bound"], 2),
                     fmt_num(row["fused_rmse_v_over_sqrt_bound"], 2),
                     fmt_stats(row["fused_rmse_p_over_sqrt_bound_per_run"], 2), fmt_num(row["fused_anees"], 2),
                     "yes" if row["fused_beats_every_local"] else "no", row["diverged_runs"],
                     fmt_num(figs["timing"][name]["ms_per_node_step"], 3)])
    print(f"\npaper 1 on {cfg.source}: {args.runs} runs, {scn.steps} scans; figures over scans {scn.steps // 2}-"
          f"{scn.steps - 1}. Clutter {cfg.spec.clutter.count} returns/scan/sensor, lambda*V_gate "
          f"{', '.join(f'{v:.2f}' for v in gate_clutter)}; IRF q2 {', '.join(f'{v:.3f}' for v in q2)}; "
          f"sqrt(PCRLB) position {floor_p:.2f} m, velocity {floor_v:.3f} m/s")
    print(table(["filter", "local v RMSE (m/s)", "fused v", "fused p (m)", "p/sqrt(B)", "v/sqrt(B)",
                 "p/sqrt(B) per run", f"fused ANEES [{lo:.2f}, {hi:.2f}]", "fused < locals", "diverged", "ms/node-step"], rows))
    print(f"paper (shape only, its parameters were lost): fused velocity RMSE near "
          f"{PAPER_FUSED_V_MPS} m/s, locals {PAPER_LOCAL_V_MPS[0]}-{PAPER_LOCAL_V_MPS[1]} m/s, fused position below "
          "every local")
    timing = figs["timing"]
    for name in ("pda-fpf", "pda-pf"):
        print(f"{name}: {timing[name]['us_per_particle_step']:.2f} us per particle-step, "
              f"{timing[name]['ms_per_node_step']:.2f} ms per node-step (batched over {args.runs * scn.nodes})")
    plot_path = figure_path(args.plot, args.json)
    figures = None
    if plot_path is not None:
        figures = plot(figs["curves"], bound_rmse(bound, POSITION), bound_rmse(bound, VELOCITY), scn.ts, plot_path)
    if args.json:
        write_json(args.json, {
            "command": "bench paper1", "scenario": cfg.source, "runs": args.runs, "seed": args.seed,
            "steps": scn.steps, "window": [scn.steps // 2, scn.steps - 1], "clutter_per_scan": cfg.spec.clutter.count,
            "lambda_v_gate": gate_clutter, "information_reduction_factor": q2, "gate": gate,
            "sqrt_pcrlb_position_m": floor_p, "sqrt_pcrlb_velocity_mps": floor_v,
            "sqrt_pcrlb_per_step": {"p": bound_rmse(bound, POSITION).tolist(), "v": bound_rmse(bound, VELOCITY).tolist()},
            "anees_band": [lo, hi], "filters": figs["rows"], "timing": timing, "curves": figs["curves"],
            "paper_shape": PAPER_SHAPE, "wall_s": time.perf_counter() - t0,
        })
    print(outputs_line("bench paper1 done", json=args.json, plot=figures))
    return 0
