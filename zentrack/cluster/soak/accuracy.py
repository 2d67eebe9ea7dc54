"""Whether a soak measures accuracy, and its accuracy per fault (issue 36).

- The sensors' field (:func:`field_exit`): a soak compares two runs' errors, which only means something while the
  sensors see the target. The field is the horizontal disc about the sensors' centroid out to the farthest sensor
  (exp2's ring: the 400 m circle), grown by :data:`FIELD_MARGIN`. Before anything starts, the soak simulates the
  run's truth (same scenario, seed and steps) and refuses a scenario whose target leaves the field before the end,
  unless told to run it anyway; then :func:`error_growth` says how far the fault-free run's error grows.
- Accuracy per fault (:func:`accuracy_per_fault`, criterion ``accuracy_per_fault``): each fault's window runs
  from its start to :data:`WINDOW_AFTER_STEPS` after its undo. In it, the affected trackers' position RMSE (the
  tracker hit; a sensor's trackers; every tracker for a truth or router fault) and the network's (RMS over the window of the median
  error over the trackers) are each divided by the fault-free reference run's at the same steps and trackers
  (the reference's errors taken only where the faulty run has an estimate, so that a tracker's absence is not
  counted as a change of accuracy). A
  ratio above its kind's limits (its entry in the fault registry, :mod:`zentrack.cluster.soak.fault_kinds`, which
  says where each kind's limits come from) fails the criterion; a tracker fault's affected limit is its kind's
  times the window's bound ratio (:mod:`zentrack.cluster.soak.reach`: how far the faults overlapping it raised the
  Cramér-Rao bound of the sensors its tracker could still reach; 1 unless they split the network around it), so
  that a window is judged against what its tracker could know. When other tracker faults overlap a
  tracker fault's window, their trackers are set aside from its network figure (:func:`set_aside`): it measures
  what this fault costs the trackers it did not hit (a sensor fault counts as a fault of the trackers that take
  it, here and below). Those trackers still miss the set-aside ones as neighbours, so
  the network limit of such a window is the product of its own kind's and each overlapping tracker fault's
  (:func:`network_limit`: every fault may cost the rest of the network its kind's factor). A tracker fault inside a truth or router fault's window is
  judged by that window (every tracker coasts then).
"""
from __future__ import annotations

import warnings

import numpy as np

from zentrack.cluster.soak.fault_kinds import blinds_all, fault_of, hit_trackers, sensor_of, window_limits
from zentrack.cluster.soak.reach import ReachBound
from zentrack.truth.simulation.multitarget import MultiTargetData

#: the field's radius is the farthest sensor's horizontal distance from the sensors' centroid times this
FIELD_MARGIN = 1.0
#: a fault's window ends this many steps after its undo (the recovery criteria's 20 steps, and as many again)
WINDOW_AFTER_STEPS = 40


def fault_kind(kind: str, target: int | str) -> str:
    """The kind a window is judged as (its registry entry's name): ``kill``, ``freeze`` or ``cut`` of a tracker,
    ``truth-stall``, ``truth-kill`` or ``router-kill``; ``kind`` is the action that started it."""
    return fault_of(kind, target).name


def field_exit(truth: np.ndarray, sensors: np.ndarray, margin: float = FIELD_MARGIN) -> dict:
    """Where the target ``truth`` ``(K, >=3)`` (positions first) is against the field of fixed ``sensors``
    ``(M, 3)``: ``{"radius_m", "centre", "max_distance_m", "first_step_out"}`` (None: it stays in)."""
    centre = np.asarray(sensors, dtype=float)[:, :2].mean(axis=0)
    radius = margin * float(np.max(np.hypot(*(sensors[:, :2] - centre).T)))
    dist = np.hypot(*(np.asarray(truth, dtype=float)[:, :2] - centre).T)
    out = np.flatnonzero(dist > radius)
    return {"radius_m": radius, "centre": centre.tolist(), "max_distance_m": float(dist.max()),
            "first_step_out": int(out[0]) if out.size else None}


def check_field(scn: object, unobserved: bool) -> dict | None:
    """The soak's check before anything starts: where one target's simulated run ``scn`` (a ScenarioData: its
    ``truth`` ``(R, K, n)`` and fixed ``sensors``) is against the field (:func:`field_exit`); ValueError with
    :func:`leaves_field_line` when it leaves and ``unobserved`` is false. None for many targets (``scn`` a
    MultiTargetData: targets come and go, and the soak judges the GOSPA of those present) or moving sensors
    (nothing to check)."""
    truth, sensors = getattr(scn, "truth", None), getattr(scn, "sensors", None)
    if isinstance(scn, MultiTargetData) or truth is None or sensors is None or np.ndim(truth) != 3:
        return None
    if getattr(scn, "sensor_track", None) is not None:
        return None
    where = field_exit(truth[0], np.asarray(sensors, dtype=float))
    if where["first_step_out"] is not None and not unobserved:
        raise ValueError(leaves_field_line(str(getattr(scn, "name", "?")), where, truth.shape[1],
                                           float(getattr(scn, "ts", 1.0))))
    return where


def leaves_field_line(name: str, where: dict, steps: int, ts: float) -> str:
    """The one line that refuses a scenario whose target leaves the field."""
    k = where["first_step_out"]
    return (f"scenario {name}: its target leaves the sensors' field (within {where['radius_m']:.0f} m of the sensors' "
            f"centre) at step {k} ({k * ts:.1f} s) of {steps} and reaches {where['max_distance_m']:.0f} m, so the soak "
            "would compare errors of a target no sensor sees well: choose a scenario that stays (patrol, the default), "
            "a shorter --duration, or pass --unobserved to run it and report how far its error grows without faults")


def _median_over_nodes(err: np.ndarray) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a step no tracker published: NaN
        return np.nanmedian(err, axis=1)


def _rms(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


def error_growth(ref_err: np.ndarray, ts: float) -> dict:
    """How far the fault-free run's network median error grows: its RMS over the first and the last tenth of
    the run (at least 10 steps each), and their ratio."""
    median = _median_over_nodes(ref_err)
    n = max(10, median.size // 10)
    first, last = _rms(median[:n]), _rms(median[-n:])
    return {"first_m": first, "last_m": last, "growth": last / first if first > 0 else float("inf"),
            "window_s": n * ts}


def set_aside(windows: list[dict], spans: list[tuple[int, int]], n: int, nodes: int) -> list[int]:
    """The trackers hit by another tracker (or sensor) fault whose span (``spans``: start to
    :data:`WINDOW_AFTER_STEPS` after the undo) overlaps fault ``n``'s: left out of ``n``'s network figure, so
    that it measures what fault ``n`` costs the rest of the network (several trackers down at once would otherwise
    move the median by their own errors, whatever fault ``n`` did)."""
    own = set(hit_trackers(windows[n], nodes))
    return sorted({i for m in overlapping(windows, spans, n) for i in hit_trackers(windows[m], nodes)} - own)


def overlapping(windows: list[dict], spans: list[tuple[int, int]], n: int) -> list[int]:
    """The other tracker (or sensor) faults (indices into ``windows``) whose spans overlap fault ``n``'s."""
    lo, hi = spans[n]
    return [m for m, v in enumerate(windows) if m != n and not blinds_all(v["node"])
            and spans[m][0] <= hi and lo <= spans[m][1]]


def network_limit(windows: list[dict], spans: list[tuple[int, int]], n: int) -> float:
    """The network ratio's limit of fault ``n``'s window: its kind's times that of each other tracker (or
    sensor) fault overlapping it (a truth or router fault's window: its kind's alone)."""
    limit = fault_of(windows[n]["kind"], windows[n]["node"]).limits[1]
    if blinds_all(windows[n]["node"]):
        return limit
    for m in overlapping(windows, spans, n):
        limit *= fault_of(windows[m]["kind"], windows[m]["node"]).limits[1]
    return limit


def accuracy_per_fault(windows: list[dict], err: np.ndarray, ref_err: np.ndarray,
                       after: int = WINDOW_AFTER_STEPS, bound: ReachBound | None = None) -> dict:
    """The criterion over ``windows`` (:func:`zentrack.cluster.soak.faults.fault_windows`): one entry per fault
    with its window (steps), affected trackers, both RMSEs and ratios, its bound ratio, its limits and pass
    (module docstring). ``bound``: the run's geometry for the bound ratios (None: a many-target run, or a run
    without a bound: every ratio 1)."""
    steps, nodes = err.shape
    scales, no_bound = [1.0] * len(windows), None
    if bound is not None:
        try:
            scales = bound.ratios(windows, np.isfinite(err), after)
        except (np.linalg.LinAlgError, ValueError) as exc:  # judged by the kinds' limits alone, and said so
            no_bound = f"no bound ratios ({type(exc).__name__}: {exc}): every window judged by its kind's limits"
    # like with like: the reference where the faulty run has an estimate (a killed tracker's absence alone moves a
    # median over 4 trackers by a quarter of the spread)
    ref_err = np.where(np.isfinite(err), ref_err[:steps], np.nan)
    rows = []
    spans = [(w["start"], min(steps - 1, w["end"] + after)) for w in windows]
    for n, w in enumerate(windows):
        fault = fault_of(w["kind"], w["node"])
        kind = fault.name
        lo, hi = w["start"], min(steps, w["end"] + after + 1)
        hit = hit_trackers(w, nodes)
        mine, theirs = _rms(err[lo:hi, hit]), _rms(ref_err[lo:hi, hit])
        aside = [] if blinds_all(w["node"]) else set_aside(windows, spans, n, nodes)
        keep = [i for i in range(nodes) if i not in aside]
        net = _rms(_median_over_nodes(err[lo:hi, keep]))
        ref_net = _rms(_median_over_nodes(ref_err[lo:hi, keep]))
        limit_hit, limit_net = fault.limits[0] * scales[n], network_limit(windows, spans, n)
        ratio_hit = mine / theirs if theirs > 0 else float("inf")
        ratio_net = net / ref_net if ref_net > 0 else float("inf")
        blind = [fault_kind(v["kind"], v["node"]) for m, v in enumerate(windows) if m != n and not blinds_all(w["node"])
                 and blinds_all(v["node"]) and spans[m][0] <= hi - 1 and lo <= spans[m][1]]
        ok = bool(ratio_hit <= limit_hit and ratio_net <= limit_net)
        rows.append({"kind": kind, "node": w["node"], "start": lo, "end": hi - 1, "affected": hit,
                     "rmse_affected_m": mine, "reference_affected_m": theirs, "ratio_affected": ratio_hit,
                     "rmse_network_m": net, "reference_network_m": ref_net, "ratio_network": ratio_net,
                     "bound_ratio": scales[n], "limits": [limit_hit, limit_net], "judged": not blind, "overlaps": blind, "set_aside": aside,
                     "pass": ok or bool(blind)})
    judged = [r for r in rows if r["judged"]]
    worst = {k: [max(r["ratio_affected"] for r in judged if r["kind"] == k),
                 max(r["ratio_network"] for r in judged if r["kind"] == k)] for k in sorted({r["kind"] for r in judged})}
    out = {"pass": all(r["pass"] for r in rows), "windows": rows, "worst_per_kind": worst,
           "limits": {k: list(v) for k, v in window_limits().items()}, "after_steps": after}
    if no_bound is not None:
        out["no_bound"] = no_bound
    return out


def window_lines(c: dict) -> list[str]:
    """What ``accuracy_per_fault`` measured: the worst ratios per fault kind on a pass, every window over its
    limit on a failure (and that no bound ratio could be computed, when so)."""
    return [*_window_lines(c), *([c["no_bound"]] if "no_bound" in c else [])]


def _window_lines(c: dict) -> list[str]:
    if c["pass"]:
        if not c["windows"]:
            return ["no fault windows"]
        parts = [f"{k} {a:.2f}x{_worst_bound(c, k, a)} / {n:.2f}x (limits {c['limits'][k][0]:g} / "
                 f"{c['limits'][k][1]:g} alone)" for k, (a, n) in c["worst_per_kind"].items()]
        apart = sum(not r["judged"] for r in c["windows"])
        return [f"{len(c['windows'])} fault windows ({apart} inside a truth or router fault's, judged by it), worst "
                "affected / network RMSE vs reference: " + ", ".join(parts)]
    return [f"{r['kind']} {r['node']} at steps {r['start']}-{r['end']}: affected {r['rmse_affected_m']:.1f} m = "
            f"{r['ratio_affected']:.2f}x, network {r['rmse_network_m']:.1f} m = {r['ratio_network']:.2f}x its reference "
            f"(limits {r['limits'][0]:.3g}x / {r['limits'][1]:.3g}x{bound_note(r)})" for r in c["windows"] if not r["pass"]]


def _worst_bound(c: dict, kind: str, worst: float) -> str:
    """`` (bound 2.93x, limit 7.33x)`` when the window of ``kind``'s worst affected ratio was judged beside a raised
    bound, else nothing."""
    rows = [r for r in c["windows"] if r["judged"] and r["kind"] == kind and r["ratio_affected"] == worst]
    if not rows or rows[0].get("bound_ratio", 1.0) < 1.005:
        return ""
    return f" (bound {rows[0]['bound_ratio']:.2f}x, limit {rows[0]['limits'][0]:.3g}x)"


def bound_note(row: dict) -> str:
    """``, bound 2.93x`` when the window's faults raised its tracker's bound (its limit is the kind's times that),
    else nothing."""
    return f", bound {row['bound_ratio']:.2f}x" if row.get("bound_ratio", 1.0) >= 1.005 else ""


def window_table(c: dict) -> list[str]:
    """The per-fault table (Markdown) of ``accuracy_per_fault``."""
    rows = ["| fault | hit | steps | affected m (ref) | ratio | bound ratio | network m (ref) | ratio | limits | |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for r in c["windows"]:
        verdict = ("pass" if r["pass"] else "FAIL") if r["judged"] else f"in {', '.join(r['overlaps'])}"
        hit = f"node-{r['node']}" if isinstance(r["node"], int) else r["node"]
        if sensor_of(r["node"]) is not None:  # a sensor: the trackers that take it
            hit += f" ({', '.join(f'node-{i}' for i in r['affected'])})"
        if r.get("set_aside"):
            hit += f" (network without {', '.join(f'node-{i}' for i in r['set_aside'])})"
        bound = f"{r['bound_ratio']:.2f}" if "bound_ratio" in r else "–"  # a report judged before bound ratios
        rows.append(f"| {r['kind']} | {hit} | {r['start']}-{r['end']} | {r['rmse_affected_m']:.2f} "
                    f"({r['reference_affected_m']:.2f}) | {r['ratio_affected']:.2f} | {bound} | "
                    f"{r['rmse_network_m']:.2f} ({r['reference_network_m']:.2f}) | {r['ratio_network']:.2f} | "
                    f"{r['limits'][0]:.3g} / {r['limits'][1]:.3g} | {verdict} |")
    return rows
