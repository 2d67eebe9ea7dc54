"""``zentrack bench split``: the soak hour's split of step 10800 in memory, against the bound (issue 54 item 2).

The faults the hour met at step 10800 (node 0 cut off and node 3 frozen for 51 steps, node 2 killed and restarted
21 steps later) leave node 2, once back, with node 1 alone: two bearing sensors of eight. They are applied to an
8-tracker ``patrol`` ring in memory (:mod:`zentrack.bench.split_ring`: the node schedule and wire codec of a tracker
process, no Zenoh) from each ``--starts`` step of one seeded run, with the neighbours exchanging estimates (the
scenario's CI diffusion) or bearings as well (``share_scans``), each beside the same ring without faults. Per start
and variant, over node 2's steps from its restart to 40 steps after the heal: its RMSE and the reference's, their
ratio, the bound ratio of the soak's rule (:mod:`zentrack.cluster.soak.reach`), each RMSE over the root of its
bound (the reach's under the faults, the network's without), node 2's first estimate after its restart, how many
steps more until its error is within twice node 1's, and its largest NEES.
"""
from __future__ import annotations

import argparse

import numpy as np

from zentrack.bench.split_ring import SplitRing, run_split, split_windows
from zentrack.cluster.soak.accuracy import WINDOW_AFTER_STEPS
from zentrack.cluster.soak.reach import ReachBound
from zentrack.common.argtypes import positive_int
from zentrack.common.plots import COLORS, legend_outside, new_figure, save_png_svg, style_axes
from zentrack.common.progress import outputs_line
from zentrack.common.report import figure_path, table, write_json

#: the hour's steps from the faults to node 2's restart, and to the heal and thaw
RESTART, HEAL = 21, 51
#: how the neighbours share: the scenario's CI diffusion of estimates, or bearings as well
VARIANTS = {"estimates": None, "bearings": {"share_scans": True}}
#: steps of the run before the first start (the filters settle)
SETTLE = 150


def int_list(text: str) -> list[int]:
    """An argparse type: comma-separated steps, each at least :data:`SETTLE`."""
    try:
        values = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated steps, got {text!r}") from None
    if not values or min(values) < SETTLE:
        raise argparse.ArgumentTypeError(f"every start must be a step >= {SETTLE}, got {text!r}")
    return values


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--starts", type=int_list, default=[375, 450, 525, 600, 750, 825], metavar="K,K",
                   help="steps the faults start at, along the target's 86 s lap (default 375,450,525,600,750,825)")
    p.add_argument("--seed", type=int, default=0, help="seed of the patrol run (default 0)")
    p.add_argument("--nodes", type=positive_int, default=8, help="trackers on the ring (default 8, as the hour)")
    p.add_argument("--json", metavar="PATH", help="write the figures as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="node 2's error beside its bound per start (default: beside --json)")


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.asarray(values) ** 2)))


def measure(start: int, variant: str, seed: int, nodes: int) -> dict:
    """One start and variant: the faulty ring, the fault-free one and the bounds (module docstring)."""
    params = VARIANTS[variant]
    fusion = None if params is None else "ci"
    faulty = run_split(start, after=HEAL + WINDOW_AFTER_STEPS + 1, seed=seed, nodes=nodes, fusion=fusion,
                       fusion_params=params)
    clean = SplitRing(nodes, start + HEAL + WINDOW_AFTER_STEPS + 1, seed, fusion=fusion, fusion_params=params)
    clean.start()
    for k in range(clean.scn.steps):
        clean.step(k)
    geometry = ReachBound.of(faulty.scn)
    bound = None if geometry is None else geometry.traces(split_windows(start), WINDOW_AFTER_STEPS, faulty.scn.steps)[1]
    if bound is None:
        raise RuntimeError("patrol has no bound: its plant lost its linear part")
    back = start + RESTART
    seen = np.isfinite(faulty.err[back:, 2])
    first = back + int(np.flatnonzero(seen)[0]) if seen.any() else None
    lo, hi = back, bound.hi  # the soak's window of the kill: to 40 steps after the restart
    mask = np.isfinite(faulty.err[lo:hi, 2])
    mine, ref = faulty.err[lo:hi, 2][mask], clean.err[lo:hi, 2][mask]
    near = None
    if first is not None:
        close = np.flatnonzero(faulty.err[first:hi, 2] <= 2.0 * faulty.err[first:hi, 1])
        near = int(close[0]) if len(close) else None
    split_b = float(np.sqrt(bound.split[lo - bound.lo:hi - bound.lo][mask].mean()))
    net_b = float(np.sqrt(bound.network[lo - bound.lo:hi - bound.lo][mask].mean()))
    end = start + HEAL + WINDOW_AFTER_STEPS + 1
    return {"start": start, "variant": variant, "steps": [lo, hi - 1], "rmse_m": rms(mine), "reference_m": rms(ref),
            "ratio": rms(mine) / rms(ref), "bound_ratio": split_b / net_b,
            "bound_m": split_b, "network_bound_m": net_b, "over_bound": rms(mine) / split_b,
            "reference_over_bound": rms(ref) / net_b,
            "first_estimate_after_restart": None if first is None else first - back,
            "steps_to_2x_node1": near, "max_nees": float(np.nanmax(faulty.nees[lo:hi, 2])),
            "reference_run_m": rms(clean.err[SETTLE:]),
            "error_m": [round(float(v), 2) for v in faulty.err[start:end, 2]],
            "node1_error_m": [round(float(v), 2) for v in faulty.err[start:end, 1]],
            "bound_trace_m": [round(float(np.sqrt(v)), 2) for v in bound.split]}


def print_table(rows: list[dict]) -> None:
    heads = ["start", "shared", "node 2 m (ref)", "ratio", "bound ratio", "/bound (ref /bound)", "1st est.",
             "to 2x node 1", "max NEES"]
    print(table(heads, [[str(r["start"]), r["variant"], f"{r['rmse_m']:.1f} ({r['reference_m']:.1f})",
                         f"{r['ratio']:.2f}", f"{r['bound_ratio']:.2f}",
                         f"{r['over_bound']:.2f} ({r['reference_over_bound']:.2f})",
                         str(r["first_estimate_after_restart"]), str(r["steps_to_2x_node1"]), f"{r['max_nees']:.1f}"]
                        for r in rows]))
    print("node 2 from its restart to 40 steps after it (the soak's window of the kill); ratio: to the ring without faults; /bound: RMSE over "
          "the root of the bound of the sensors in its reach (ref: of every sensor); steps: after its restart, and "
          "after its first estimate; NEES: 6-D kinematic state")


def plot(rows: list[dict], path) -> list:
    """Per start: node 2's error (both variants), node 1's, and the root of node 2's reach bound, from the faults."""
    starts = sorted({r["start"] for r in rows})
    fig, axes = new_figure(len(starts), 1, width=10.0, height=2.6 * len(starts))
    for ax, start in zip(axes, starts, strict=True):
        for c, r in enumerate(r for r in rows if r["start"] == start):
            t = np.arange(len(r["error_m"])) * 0.1
            ax.plot(t, r["error_m"], color=COLORS[c], linewidth=1.3, label=f"node 2, {r['variant']} shared")
            if c == 0:
                ax.plot(t, r["node1_error_m"], color="#7f7f7f", linewidth=0.9, label="node 1")
                tb = (RESTART + np.arange(len(r["bound_trace_m"]) - RESTART)) * 0.1
                ax.plot(tb, r["bound_trace_m"][RESTART:], color="black", linestyle="--", linewidth=1.0,
                        label="root of node 2's reach bound")
        ax.axvspan(0.0, HEAL * 0.1, color="#eeeeee", zorder=0)
        style_axes(ax, f"faults from step {start}", "s after the faults start", "position error (m)")
    legend_outside(axes[0])
    return save_png_svg(fig, path)


def run(args: argparse.Namespace) -> int:
    rows = [measure(start, variant, args.seed, args.nodes) for start in args.starts for variant in VARIANTS]
    print_table(rows)
    outputs = {}
    if args.json:
        write_json(args.json, {"seed": args.seed, "nodes": args.nodes, "starts": args.starts, "rows": rows})
        outputs["json"] = args.json
    path = figure_path(args.plot, args.json)
    if path is not None:
        outputs["figure"] = plot(rows, path)
    print(outputs_line("bench split", **outputs))
    return 0
