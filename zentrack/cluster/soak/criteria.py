"""The soak's criteria: the faulty run judged against the fault-free reference (``evaluate``), and the lines
that say what each criterion measured (``verdict_lines``): a failed criterion names the node, the figures and
the limit, e.g. ``FAIL  publishing_after_fault: after restart node-3 at 45.2 s: node 3 published again after
58 steps (limit 20)``.

Criteria (keys of ``report.json``'s ``criteria``):

- ``no_crash_no_nan``: surviving trackers never crash (exit status 0) or publish a NaN covariance;
- ``rmse_vs_reference``: every tracker's position RMSE <= 1.25x its fault-free RMSE;
- ``restarted_error_near_median``: once a restarted tracker publishes again, its position error is within 2x
  the network's median error in <= 20 steps (how well it rejoins; how soon it publishes is the next one);
- ``publishing_after_fault``: after every fault ends (restart, thaw, heal, resume), every live tracker
  publishes estimates again within 20 steps (a tracker under another fault is judged when that one ends);
- ``accuracy_per_fault``: in a window from each fault's start to 40 steps after its undo, the affected
  trackers' RMSE and the network median's, each against the reference at the same steps, within its fault
  kind's limits, the affected one times the window's bound ratio (``zentrack.cluster.soak.accuracy``, ``.reach``);
- ``rss_growth``: the RSS of every long-lived process grows < 10 % between minute 2 (or mid-run) and the end;
- ``outputs_complete``: the summary holds estimates for more than half of the steps x trackers, and the
  recording exists;
- ``nothing_left_running``: no process (or container, network, volume) of either run is left;
- ``drains_applied`` (``--drain-every`` only): at least one node drain moved trackers (``drains_applied``);
- ``sensor_clocks_followed`` (``--clock-jump-every`` only): every tracker that takes a sensor whose clock was
  stepped back followed it (``zentrack.cluster.soak.sensor_counts``).
"""
from __future__ import annotations

import numpy as np

from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.soak.accuracy import accuracy_per_fault, window_lines
from zentrack.cluster.soak.fault_kinds import (
    blinds_all,
    brings_back,
    fault_actions,
    fault_of,
    service_name,
    undo_actions,
)
from zentrack.cluster.soak.faults import fault_windows
from zentrack.cluster.soak.reach import ReachBound
from zentrack.cluster.soak.sensor_counts import followed_lines
from zentrack.common.procs import processes_of_runs

#: steps a tracker has to publish again after a fault ends, and a restarted one to come near the median
RECOVERY_STEPS = 20
#: a restarted tracker has rejoined when its error is below this many times the others' median error
NEAR_MEDIAN = 2.0
RMSE_RATIO_LIMIT = 1.25
RSS_GROWTH_LIMIT = 0.10
#: seconds between two RSS samples of every process (the soak's sampler)
RSS_SAMPLE_S = 10.0
#: the RSS is measured from minute 2, or from mid-run in a shorter soak
RSS_FROM_S = 120.0
#: the shortest soak with two RSS samples after mid-run (at 20 s and 30 s of a 40 s soak, say)
RSS_LEAST_S = 4 * RSS_SAMPLE_S


def position_errors(rec: Recorder) -> np.ndarray:
    """(steps, nodes) error of every tracker (NaN: no estimate): the distance of its position estimate from the
    truth; in a many-target run the GOSPA of its confirmed tracks against the targets present."""
    return rec.step_errors()


def evaluate(faulty: dict, reference: dict, duration: float, run_names: list[str],
             engine_leftovers: list[str] | None = None) -> dict:
    """Judge the faulty run against the reference by the criteria in the module docstring. ``engine_leftovers``:
    containers, networks or volumes a container engine still holds after the runs (each one fails
    ``nothing_left_running``)."""
    rec, ref = faulty["recorder"], reference["recorder"]
    summary, ref_summary = rec.summary(), ref.summary()
    err, ref_err = position_errors(rec), position_errors(ref)
    starts = fault_actions()
    killed = {service_name(f["node"]) for f in faulty["faults"]
              if f["action"] in starts and fault_of(f["action"], f["node"]).exits}
    crit = {}
    crashed = {n: code for n, code in faulty["exit_codes"].items() if code not in (0, None)
               and not (n.startswith(("node-", "sensor-")) and n in killed)}
    have = rec.have()
    no_nan = rec.nan_free()
    crit["no_crash_no_nan"] = {"pass": not crashed and no_nan, "exit_codes": faulty["exit_codes"], "crashed": crashed,
                               "nan_free": no_nan}
    ratios = []
    for i in range(rec.scn.nodes):
        a = np.sqrt(np.nanmean(err[:, i] ** 2)) if np.isfinite(err[:, i]).any() else np.inf
        b = np.sqrt(np.nanmean(ref_err[:, i] ** 2))
        ratios.append(float(a / b))
    crit["rmse_vs_reference"] = {"pass": bool(max(ratios) <= RMSE_RATIO_LIMIT), "ratio_per_node": ratios,
                                 "limit": RMSE_RATIO_LIMIT}
    crit["restarted_error_near_median"] = restarted_error_near_median(faulty["faults"], have, err, rec.scn.steps)
    crit["publishing_after_fault"] = publishing_after_fault(faulty["faults"], have, rec.scn.steps)
    crit["accuracy_per_fault"] = accuracy_per_fault(fault_windows(faulty["faults"], rec.scn.steps - 1), err, ref_err,
                                                    bound=ReachBound.of(rec.scn))
    crit["rss_growth"] = rss_growth(faulty["rss"], duration)
    needed = 0.5 * rec.scn.steps * rec.scn.nodes
    estimates = summary["network"]["estimates"]
    crit["outputs_complete"] = {"pass": estimates > needed, "estimates": estimates, "needed_more_than": needed}
    left = processes_of_runs(run_names, exclude="soak") + list(engine_leftovers or [])
    crit["nothing_left_running"] = {"pass": not left, "processes": left}
    return {"criteria": crit, "summary": summary, "reference_summary": ref_summary}


def rss_growth(rss: dict[str, list[tuple[float, float, int]]], duration: float) -> dict:
    """``rss_growth``: each long-lived process's RSS growth from :data:`RSS_FROM_S` (or mid-run) to the end;
    not judged (``pass`` None, and why) when no process has two samples in that window: the soak is too short."""
    start_t = min(RSS_FROM_S, duration / 2)
    growth = {}
    for name, samples in rss.items():
        if len({s[2] for s in samples}) != 1:
            continue  # restarted during the run: not long-lived
        base = [v for t, v, _ in samples if t >= start_t]
        if len(base) >= 2:
            growth[name] = base[-1] / base[0] - 1.0
    out = {"pass": bool(growth) and max(growth.values()) < RSS_GROWTH_LIMIT, "growth_per_process": growth,
           "from_s": start_t, "limit": RSS_GROWTH_LIMIT}
    if not growth:
        out.update({"pass": None, "not_judged": f"no long-lived process had two RSS samples (one every "
                    f"{RSS_SAMPLE_S:g} s) after {start_t:g} s; a soak of at least {RSS_LEAST_S:g} s measures it"})
    return out


def passed(criteria: dict) -> bool:
    """The verdict: every criterion that was judged passed (a criterion not judged, ``pass`` None, says why
    and counts neither way; ``no_crash_no_nan`` and the others are always judged)."""
    return all(c["pass"] is not False for c in criteria.values()) and any(c["pass"] for c in criteria.values())


def failed(criteria: dict) -> list[str]:
    """The criteria that were judged and failed."""
    return [name for name, c in criteria.items() if c["pass"] is False]


def restarted_error_near_median(faults: list[dict], have: np.ndarray, err: np.ndarray, steps: int,
                                limit: int = RECOVERY_STEPS) -> dict:
    """For every restart of a tracker: the steps until it publishes again (``steps_to_publish``, judged by
    ``publishing_after_fault``) and, from its first estimate, the steps until its error is below
    ``NEAR_MEDIAN`` x the other trackers' median (``steps_to_2x_median``: None when not within ``limit``)."""
    restarts = []
    nodes = have.shape[1]
    for f in faults:
        if not isinstance(f["node"], int) or not brings_back(f["action"], f["node"]):
            continue
        i, after = f["node"], f["step"]
        back = next((k for k in range(after, steps) if have[k, i]), None)
        steps_needed = None
        if back is not None:
            others = [j for j in range(nodes) if j != i]
            for k in range(back, min(back + limit + 1, steps)):
                if have[k, i] and err[k, i] < NEAR_MEDIAN * np.nanmedian(err[k, others]):
                    steps_needed = k - back
                    break
        restarts.append({"node": i, "t": f["t"], "first_step_back": back, "steps_to_2x_median": steps_needed,
                         "steps_to_publish": None if back is None else back - after})
    return {"pass": all(r["steps_to_2x_median"] is not None for r in restarts), "restarts": restarts,
            "limit_steps": limit}


def publishing_after_fault(faults: list[dict], have: np.ndarray, steps: int, limit: int = RECOVERY_STEPS) -> dict:
    """After each fault ends (restart, thaw, heal, resume), the steps until every live tracker publishes an
    estimate again. A tracker still under another fault at that moment (its own, or a truth or router fault,
    which hits every tracker), or hit by one that begins before it is back (a kill at the step of another
    tracker's thaw), is left out of that event: the end of that other fault judges it."""
    nodes = have.shape[1]
    active: dict[int | str, set[str]] = {}  # target -> the faults it is under
    starts: dict[int | str, list[int]] = {}  # target -> the steps its faults begin at
    begins, undoes = fault_actions(), undo_actions()
    for f in faults:
        if f["action"] in begins:
            starts.setdefault(f["node"], []).append(f["step"])
    service_starts = [s for target, steps_at in starts.items() if blinds_all(target) for s in steps_at]
    events = []
    for f in faults:
        target, action = f["node"], f["action"]
        if action in begins:
            active.setdefault(target, set()).add(action)
            continue
        kind = undoes[action]
        active.get(target, set()).discard(kind)
        services_down = any(v for k, v in active.items() if blinds_all(k))
        end = f["step"]
        per_node = {}
        for i in range(nodes):
            if active.get(i) or services_down:
                continue
            back = next((k for k in range(end, steps) if have[k, i]), None)
            if any(end <= s <= (steps if back is None else back) for s in starts.get(i, []) + service_starts):
                continue  # a fault that begins before it is back: that fault's end judges it
            per_node[i] = None if back is None else back - end
        worst = None if any(v is None for v in per_node.values()) else max((v for v in per_node.values() if v is not None), default=0)
        events.append({"t": f["t"], "after": f"{action} {service_name(target)}", "step": end,
                       "steps_to_all_estimating": worst, "per_node": per_node,
                       "pass": worst is not None and worst <= limit})
    ends = [e for e in events if e["steps_to_all_estimating"] is not None]
    return {"pass": all(e["pass"] for e in events), "limit_steps": limit, "events": events,
            "worst_steps": max((e["steps_to_all_estimating"] for e in ends), default=None)}


def drains_applied(drains: list[dict]) -> dict:
    """``drains_applied`` (``--drain-every`` only): at least one node drain moved trackers. A drain is skipped
    when every worker holds a tracker that another fault hits near it (a tracker is never under two at once:
    :func:`zentrack.cluster.soak.faults.trackers_faulted_near`); a soak that asked for drains and made none
    did not do its job."""
    done = [d for d in drains if not d.get("skipped")]
    return {"pass": bool(done), "applied": len(done), "skipped": [d["skipped"] for d in drains if d.get("skipped")],
            "moved": sum(len(d["trackers"]) for d in done)}


def _details(name: str, c: dict) -> list[str]:
    """What a criterion measured: its worst figures on a pass, every offender with its figures and the limit on
    a failure."""
    ok = c["pass"]
    if ok is None:
        return [c.get("not_judged", "not judged")]
    if name == "no_crash_no_nan":
        if ok:
            return ["no survivor crashed, no NaN covariance"]
        crashed = [f"{n} exited with status {code}" for n, code in c.get("crashed", {}).items()]
        return crashed + ([] if c["nan_free"] else ["a NaN in a published covariance"])
    if name == "rmse_vs_reference":
        ratios, limit = c["ratio_per_node"], c["limit"]
        if ok:
            worst = int(np.argmax(ratios))
            return [f"worst node {worst} at {ratios[worst]:.2f}x its fault-free RMSE (limit {limit:g}x)"]
        return [f"node {i}: position RMSE {r:.2f}x its fault-free RMSE (limit {limit:g}x)"
                for i, r in enumerate(ratios) if not r <= limit]
    if name == "restarted_error_near_median":
        limit, restarts = c["limit_steps"], c["restarts"]
        if ok:
            slowest = max((r["steps_to_2x_median"] for r in restarts), default=0)
            when = "at its first estimate" if not slowest else f"within {slowest} steps of its first estimate"
            return [f"{len(restarts)} restarts, each within {NEAR_MEDIAN:g}x the network median error {when} "
                    f"(limit {limit} steps)"]
        out = []
        for r in restarts:
            if r["steps_to_2x_median"] is not None:
                continue
            head = f"node {r['node']} restarted at {r['t']:.1f} s"
            if r["first_step_back"] is None:
                out.append(f"{head}: never published again")
            else:
                out.append(f"{head}: published after {r['steps_to_publish']} steps, but its error stayed above "
                           f"{NEAR_MEDIAN:g}x the network median for the {limit} steps after (limit {limit})")
        return out
    if name == "publishing_after_fault":
        limit = c["limit_steps"]
        if ok:
            return [f"{len(c['events'])} fault ends, every live tracker publishing again within "
                    f"{c['worst_steps'] if c['worst_steps'] is not None else 0} steps (limit {limit})"]
        out = []
        for e in c["events"]:
            if e["pass"]:
                continue
            late = [f"node {i} " + ("never published again" if s is None else f"published again after {s} steps")
                    for i, s in e["per_node"].items() if s is None or s > limit]
            out.append(f"after {e['after']} at {e['t']:.1f} s (step {e['step']}): {', '.join(late)} (limit {limit})")
        return out
    if name == "accuracy_per_fault":
        return window_lines(c)
    if name == "rss_growth":
        growth, limit = c["growth_per_process"], c["limit"]
        worst = max(growth, key=lambda n: growth[n])
        if ok:
            return [f"worst {worst} grew {100 * growth[worst]:.1f} % from {c['from_s']:g} s (limit {100 * limit:g} %)"]
        return [f"{n} grew {100 * g:.1f} % from {c['from_s']:g} s to the end (limit {100 * limit:g} %)"
                for n, g in growth.items() if not g < limit]
    if name == "outputs_complete":
        text = f"{c['estimates']} estimates (need more than {c.get('needed_more_than', 0):g})"
        if "recording_bytes" in c:
            text += f", recording {c['recording_bytes']} bytes" if c["recording_bytes"] else ", recording.rrd missing"
        return [text]
    if name == "sensor_clocks_followed":
        return followed_lines(c)
    if name == "drains_applied":
        skipped = f", {len(c['skipped'])} skipped ({c['skipped'][0]})" if c["skipped"] else ""
        return [f"{c['applied']} node drains moved {c['moved']} trackers{skipped}"]
    if name == "nothing_left_running":
        return ["nothing left"] if ok else [f"still there: {', '.join(map(str, c['processes']))}"]
    return []


def verdict_lines(criteria: dict) -> list[str]:
    """One line per criterion, ``PASS  name: what it measured``, ``FAIL  name: the offender, its figures,
    the limit`` (a criterion with several offenders: one indented line each) or ``NOT JUDGED  name: why``."""
    lines = []
    for name, c in criteria.items():
        details = _details(name, c) or [""]
        word = {True: "PASS", False: "FAIL", None: "NOT JUDGED"}[c["pass"]]
        if len(details) == 1:
            lines.append(f"{word}  {name}: {details[0]}".rstrip(": "))
        else:
            lines.append(f"{word}  {name}:")
            lines += [f"        {d}" for d in details]
    return lines
