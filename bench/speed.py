"""``zentrack bench speed``: microseconds per node-step, batched and single-node, beside FilterPy.

Measured in one process on the paper 0 Experiment 2 model (3-D CV with a_nl, bearing measurements):

- *batched*: the in-process network simulator, every node of one run (R = 1) and of R runs at once, in
  microseconds per node-step (wall time / (R M K));
- *single node*: one node stepping alone (a batch of one), as a tracker process does: ``filter step`` =
  local update + prediction; ``node step`` adds the information export and CI fusion of three pairs;
- *FilterPy*: ``ExtendedKalmanFilter`` and ``UnscentedKalmanFilter`` on the same model, data and sigma
  points, update + prediction, timed in alternating rounds with ours so machine noise hits both;
- *centralized*: zentrack's EKF on every sensor's measurement stacked into one update (paper 0 eq. 15) beside
  FilterPy's EKF on the same stacked measurement, noise and model.

Figures are medians over rounds; ratios compare figures measured in the same run.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import numpy as np

from zentrack.common.argtypes import positive_int
from zentrack.common.report import fmt_num, table, write_json
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.covariance_intersection import ci_fuse
from zentrack.fusion.linalg import InformationPair, to_information
from zentrack.fusion.measurement import wrap_angle
from zentrack.study.simulator import build_filter, run_filter
from zentrack.truth.simulation.simulate import simulate

DISTRIBUTED = ("dteskf", "deskf", "dekf", "dukf", "dckf")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", type=positive_int, default=10, help="nodes in the batched runs (default 10)")
    p.add_argument("--steps", type=positive_int, default=1000, help="steps per batched run (default 1000)")
    p.add_argument("--runs", type=positive_int, default=20, help="runs batched together (default 20)")
    p.add_argument("--rounds", type=positive_int, default=5, help="timing rounds; the median is kept (default 5)")
    p.add_argument("--single-steps", type=positive_int, default=300, help="steps per single-node round")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")


def _median_us(times: list[float], count: int) -> float:
    return float(np.median(times)) / count * 1e6


def batched_figures(args: argparse.Namespace) -> dict:
    out = {}
    one = simulate(builtin_spec("exp2", args.nodes, args.steps), runs=1, seed=0)
    many = simulate(builtin_spec("exp2", args.nodes, args.steps), runs=args.runs, seed=0)
    for name in DISTRIBUTED:
        t1, tr = [], []
        for _ in range(args.rounds):
            t0 = time.perf_counter(); run_filter(one, name); t1.append(time.perf_counter() - t0)
            t0 = time.perf_counter(); run_filter(many, name); tr.append(time.perf_counter() - t0)
        out[name] = {
            "one_run_s": float(np.median(t1)),
            "us_per_node_step_R1": _median_us(t1, args.nodes * args.steps),
            f"us_per_node_step_R{args.runs}": _median_us(tr, args.runs * args.nodes * args.steps),
        }
        print(f"  batched {name}: {out[name]['us_per_node_step_R1']:.1f} us/node-step (R=1), "
              f"{out[name][f'us_per_node_step_R{args.runs}']:.1f} (R={args.runs})", file=sys.stderr)
    return out


class _SingleNode:
    """One node of the Experiment 2 network stepping alone (batch of one), optionally with CI fusion."""

    def __init__(self, scn, kind: str, fuse: bool):
        self.filt = build_filter(scn, kind)
        self.scn = scn
        self.fuse = fuse
        self.sensors = scn.sensors[0:1, None, :]
        self.noise = scn.noise_cov[0:1]
        self.z = scn.measurements[0, :, 0:1, :]
        self.w = np.array([[0.5, 0.25, 0.25]])

    def run(self, steps: int) -> float:
        f = self.filt
        state = f.initial_state(self.scn.x0_estimate[0:1], self.scn.p0, self.scn.lumped_var)
        t0 = time.perf_counter()
        for k in range(steps):
            post = f.update(state, self.z[k], self.sensors, self.noise)
            state = f.predict(post)
            if self.fuse:
                pair = to_information(state)
                # own pair and two neighbours' (here: copies of the own pair: the arithmetic is the same)
                three = InformationPair(np.repeat(pair.matrix[None], 3, axis=1), np.repeat(pair.vector[None], 3, axis=1))
                fused = ci_fuse(self.w, three)
                state = type(state)(fused.mean[0], fused.cov[0])
        return time.perf_counter() - t0


def filterpy_runners(scn):
    """FilterPy EKF and UKF on the same model; None when FilterPy is not installed."""
    try:
        from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter
    except ImportError:
        return None
    motion = scn.motion_model()
    meas = scn.measurement_model()
    s0 = scn.sensors[0:1, None, :]
    z = scn.measurements[0, :, 0, :]

    def hx(x):
        return meas.h(x[None, :], s0)[0]

    def h_jac(x):
        return meas.jacobian(x[None, :], s0)[0]

    def fx(x, dt):
        return motion.f(x[None, :])[0]

    def residual(a, b):
        return wrap_angle(a - b)

    def z_mean(sigmas, wm):
        ref = sigmas[0]
        return ref + wm @ wrap_angle(sigmas - ref)

    class NonlinearEKF(ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = fx(self.x, motion.ts)

    def run_ekf(steps: int) -> tuple[float, np.ndarray]:
        ekf = NonlinearEKF(dim_x=6, dim_z=2)
        ekf.x = scn.x0_estimate[0].copy(); ekf.P = scn.p0.copy(); ekf.Q = motion.Q.copy(); ekf.R = scn.noise_cov[0].copy()
        out = np.empty((steps, 6))
        t0 = time.perf_counter()
        for k in range(steps):
            ekf.update(z[k], h_jac, hx, residual=residual)
            out[k] = ekf.x
            ekf.F = motion.jacobian(ekf.x[None, :])[0]
            ekf.predict()
        return time.perf_counter() - t0, out

    def run_ukf(steps: int) -> tuple[float, np.ndarray]:
        pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=1.0)
        ukf = UnscentedKalmanFilter(6, 2, motion.ts, hx, fx, pts, residual_z=residual, z_mean_fn=z_mean)
        ukf.x = scn.x0_estimate[0].copy(); ukf.P = scn.p0.copy(); ukf.Q = motion.Q.copy(); ukf.R = scn.noise_cov[0].copy()
        ukf.sigmas_f = pts.sigma_points(ukf.x, ukf.P)  # FilterPy updates with the points of the last predict
        out = np.empty((steps, 6))
        t0 = time.perf_counter()
        for k in range(steps):
            ukf.update(z[k])
            out[k] = ukf.x
            ukf.predict()
        return time.perf_counter() - t0, out

    return run_ekf, run_ukf


def centralized_runners(scn) -> tuple[Callable[[int], tuple[float, np.ndarray]], Callable | None]:
    """zentrack's stacked centralized EKF (every sensor's measurement in one update) and FilterPy's EKF on the
    same stacked measurement (None without FilterPy): each ``run(steps) -> (seconds, estimates)``."""
    motion, meas, m = scn.motion_model(), scn.measurement_model(), scn.sensors.shape[0]
    sensors = scn.sensors[None, :, :]  # (1, M, 3)
    noise = np.zeros((2 * m, 2 * m))
    for i in range(m):
        noise[2 * i:2 * i + 2, 2 * i:2 * i + 2] = scn.noise_cov[i]
    z_all = scn.measurements[0].reshape(scn.measurements.shape[1], 2 * m)  # az_1, el_1, az_2, ...
    ekf = build_filter(scn, "ekf")

    def ours(steps: int) -> tuple[float, np.ndarray]:
        state = ekf.initial_state(scn.x0_estimate[0:1], scn.p0)
        out = np.empty((steps, 6))
        t0 = time.perf_counter()
        for k in range(steps):
            state = ekf.update(state, z_all[k][None], sensors, noise[None])
            out[k] = state.mean[0]
            state = ekf.predict(state)
        return time.perf_counter() - t0, out

    try:
        from filterpy.kalman import ExtendedKalmanFilter
    except ImportError:
        return ours, None

    class NonlinearEKF(ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = motion.f(self.x[None, :])[0]

    def theirs(steps: int) -> tuple[float, np.ndarray]:
        f = NonlinearEKF(dim_x=6, dim_z=2 * m)
        f.x = scn.x0_estimate[0].copy(); f.P = scn.p0.copy(); f.Q = motion.Q.copy(); f.R = noise.copy()
        out = np.empty((steps, 6))
        t0 = time.perf_counter()
        for k in range(steps):
            f.update(z_all[k], lambda x: meas.jacobian(x[None, :], sensors)[0], lambda x: meas.h(x[None, :], sensors)[0],
                     residual=lambda a, b: wrap_angle(a - b))
            out[k] = f.x
            f.F = motion.jacobian(f.x[None, :])[0]
            f.predict()
        return time.perf_counter() - t0, out

    return ours, theirs


def ours_estimates(scn, kind: str, steps: int) -> np.ndarray:
    f = build_filter(scn, kind)
    state = f.initial_state(scn.x0_estimate[0:1], scn.p0)
    out = np.empty((steps, 6))
    for k in range(steps):
        post = f.update(state, scn.measurements[0, k, 0:1], scn.sensors[0:1, None, :], scn.noise_cov[0:1])
        out[k] = post.mean[0, :6]
        state = f.predict(post)
    return out


def single_node_figures(args: argparse.Namespace) -> dict:
    scn = simulate(builtin_spec("exp2", args.nodes, args.single_steps), runs=1, seed=0)
    steps = args.single_steps
    runners: dict[str, Callable[[int], float]] = {}
    for name in DISTRIBUTED:
        runners[f"{name[1:]} filter step"] = _SingleNode(scn, name[1:], fuse=False).run
        runners[f"{name} node step"] = _SingleNode(scn, name[1:], fuse=True).run
    fp = filterpy_runners(scn)
    central, central_fp = centralized_runners(scn)
    runners[f"centralized EKF step ({scn.sensors.shape[0]} sensors stacked)"] = lambda s: central(s)[0]
    if fp is not None:
        runners["filterpy EKF"] = lambda s: fp[0](s)[0]
        runners["filterpy UKF"] = lambda s: fp[1](s)[0]
    if central_fp is not None:
        runners["filterpy EKF, stacked"] = lambda s: central_fp(s)[0]
    times: dict[str, list[float]] = {k: [] for k in runners}
    for _ in range(args.rounds):  # alternate everything each round
        for key, fn in runners.items():
            times[key].append(fn(steps))
    out = {key: _median_us(t, steps) for key, t in times.items()}
    agreement = {}
    if fp is not None:
        agreement["ekf_vs_filterpy_max_abs"] = float(np.abs(fp[0](steps)[1] - ours_estimates(scn, "ekf", steps)).max())
        agreement["ukf_vs_filterpy_max_abs"] = float(np.abs(fp[1](steps)[1] - ours_estimates(scn, "ukf", steps)).max())
    if central_fp is not None:
        agreement["centralized_ekf_vs_filterpy_max_abs"] = float(np.abs(central(steps)[1] - central_fp(steps)[1]).max())
    return {"us_per_step": out, "agreement": agreement, "filterpy": fp is not None}


def run(args: argparse.Namespace) -> int:
    print(f"batched simulator: Experiment 2, {args.nodes} nodes, {args.steps} steps", file=sys.stderr)
    batched = batched_figures(args)
    print("single-node stepping (batch of one) and FilterPy, alternating rounds", file=sys.stderr)
    single = single_node_figures(args)
    rk = f"us_per_node_step_R{args.runs}"
    print(f"\nBatched simulator, Experiment 2, {args.nodes} nodes x {args.steps} steps (median of rounds)")
    print(table(["filter", "us/node-step R=1", f"us/node-step R={args.runs}", "one run s"],
                [[n, fmt_num(b["us_per_node_step_R1"], 1), fmt_num(b[rk], 1), fmt_num(b["one_run_s"], 3)]
                 for n, b in batched.items()]))
    us = single["us_per_step"]
    print("\nSingle node (batch of one): microseconds per step")
    print(table(["what", "us/step"], [[k, fmt_num(v, 1)] for k, v in us.items()]))
    ratios = {}
    if single["filterpy"]:
        ratios = {
            "teskf_filter_step / filterpy_ekf": us["teskf filter step"] / us["filterpy EKF"],
            "ekf_filter_step / filterpy_ekf": us["ekf filter step"] / us["filterpy EKF"],
            "ukf_filter_step / filterpy_ukf": us["ukf filter step"] / us["filterpy UKF"],
            "dteskf_node_step / filterpy_ekf": us["dteskf node step"] / us["filterpy EKF"],
            "dukf_node_step / filterpy_ukf": us["dukf node step"] / us["filterpy UKF"],
            "centralized_ekf_step / filterpy_stacked_ekf": us[next(k for k in us if k.startswith("centralized EKF"))]
            / us["filterpy EKF, stacked"],
        }
        print("\nRatios (same run; < 1 means zentrack is faster)")
        print(table(["ratio", "value"], [[k, f"{v:.2f}"] for k, v in ratios.items()]))
        print(f"\nAgreement with FilterPy on the same data (max |x diff|): EKF "
              f"{single['agreement']['ekf_vs_filterpy_max_abs']:.2e}, UKF {single['agreement']['ukf_vs_filterpy_max_abs']:.2e}, "
              f"stacked EKF {single['agreement']['centralized_ekf_vs_filterpy_max_abs']:.2e}")
    else:
        print("\nFilterPy is not installed (pip install 'zentrack[bench]'): no reference figures")
    if args.json:
        write_json(args.json, {"command": "bench speed", "nodes": args.nodes, "steps": args.steps,
                               "runs": args.runs, "rounds": args.rounds, "batched": batched,
                               "single_node": single, "ratios": ratios})
    return 0
