"""A soak with sensors of their own (issue 52): what each tracker did with its sensors' detections, and the lines
the soak prints about its sensor faults.

:func:`tracker_counts` gives, per tracker of one run, the detections it kept (``det_rx``), dropped as older than
its lag (``too_old``) and took out of order, each refusal of hostile time by reason (``stale``, ``future``,
``rate``, ``duplicate``, ...: ``node/detections.py``) summed over the tracker's restarts, and the clock offset it
applied to each sensor at its exit. :func:`sensor_report` puts both runs' side by side with what the sensor
faults did (each sensor's clock steps in all, its kills) for ``report.json``'s ``sensors``; :func:`sensor_lines`
says it in one line per tracker a sensor fault hit. A clock step of more than ``STALE_S`` is refused ``stale``
until the tracker's offset estimate follows: :data:`~zentrack.cluster.soak.fault_kinds.FOLLOW_DETECTIONS` less
one per step (60), fewer when its window was not full (a tracker or sensor started shortly before)."""
from __future__ import annotations

from zentrack.cluster.soak.fault_kinds import FOLLOW_DETECTIONS, fault_actions, fault_of, sensor_of

#: the refusals of a detection (``node/detections.py``; ``nonfinite`` and ``range`` from decoding), reported
#: whenever a tracker counted one
REASONS = ("stale", "future", "rate", "duplicate", "sender_mismatch", "nonfinite", "range")


def tracker_counts(rec, reports: dict[int, dict]) -> dict[int, dict]:
    """Per tracker of a run (its recorder ``rec``, its trackers' final reports ``reports``): ``det_rx``,
    ``too_old``, ``out_of_order``, ``refused`` (reason -> count, the reasons counted) and ``sensor_offsets_s``
    (sensor -> the offset applied at its exit, s; None without a final report)."""
    out = {}
    for i in range(rec.scn.nodes):
        total = rec.counters.summed(i, reports.get(i))
        det, rejected = total.get("detections") or {}, total.get("rejected") or {}
        out[i] = {"det_rx": int(det.get("det_rx", 0)), "too_old": int(det.get("too_old", 0)),
                  "out_of_order": int(det.get("out_of_order", 0)),
                  "refused": {r: int(rejected[r]) for r in REASONS if rejected.get(r)},
                  "sensor_offsets_s": (reports.get(i) or {}).get("sensor_offsets_s")}
    return out


def sensor_report(faults: list[dict], faulty: dict[int, dict], reference: dict[int, dict],
                  takers: dict[int, list[int]], configured: dict[int, float], clock_jump_s: float) -> dict:
    """``report.json``'s ``sensors``: each sensor's configured clock offset, the trackers that take it, its kills
    and clock steps in the faulty run (and how far back its clock ended), and both runs' :func:`tracker_counts`."""
    starts = fault_actions()
    per_sensor = {}
    for s, trackers in takers.items():
        mine = [f for f in faults if sensor_of(f["node"]) == s and f["action"] in starts]
        jumps = [f["t"] for f in mine if fault_of(f["action"], f["node"]).name == "clock-jump"]
        per_sensor[str(s)] = {"trackers": trackers, "configured_offset_s": configured.get(s), "clock_jumps_at_s": jumps,
                              "kills_at_s": [f["t"] for f in mine if fault_of(f["action"], f["node"]).name == "sensor-kill"],
                              "clock_back_s": len(jumps) * clock_jump_s}
    return {"clock_jump_s": clock_jump_s, "follow_detections": FOLLOW_DETECTIONS, "sensors": per_sensor,
            "trackers": {"faulty": {str(i): c for i, c in faulty.items()},
                         "reference": {str(i): c for i, c in reference.items()}}}


def sensor_lines(sensors: dict) -> list[str]:
    """One line per tracker that takes a sensor a fault hit: the faults, the detections it kept, too old and
    refused by reason against the reference run, and the offset it applied to that sensor at its exit against
    the configured one less the steps."""
    lines = []
    runs = sensors["trackers"]
    for s, entry in sensors["sensors"].items():
        jumps, kills = entry["clock_jumps_at_s"], entry["kills_at_s"]
        if not jumps and not kills:
            continue
        what = ", ".join(part for part in (
            f"{len(jumps)} clock jump(s) of {sensors['clock_jump_s']:g} s back at {', '.join(f'{t:.1f}' for t in jumps)} s"
            if jumps else "", f"killed at {', '.join(f'{t:.1f}' for t in kills)} s" if kills else "") if part)
        for i in entry["trackers"]:
            mine, ref = runs["faulty"].get(str(i), {}), runs["reference"].get(str(i), {})
            refused = ", ".join(f"{n} {r} (reference {ref.get('refused', {}).get(r, 0)})"
                                for r, n in sorted(mine.get("refused", {}).items())) or "none refused"
            offset = (mine.get("sensor_offsets_s") or {}).get(s)
            expected = None if entry["configured_offset_s"] is None else entry["configured_offset_s"] - entry["clock_back_s"]
            clock = "" if offset is None or expected is None else \
                f"; offset at its exit {offset:+.3f} s (configured less the steps {expected:+.3f} s)"
            lines.append(f"sensor-{s} ({what}): node {i} kept {mine.get('det_rx', 0)} detections (reference "
                         f"{ref.get('det_rx', 0)}), {mine.get('too_old', 0)} too old (reference {ref.get('too_old', 0)}), "
                         f"{refused}{clock}")
    return lines


#: refusals a step may cost beyond :data:`FOLLOW_DETECTIONS` less one: a detection measured before the step and
#: delivered a period late is one more old sample for the estimate's window to lose (exp2-async's reordered tenth)
FOLLOW_SLACK = 3
#: how far a tracker's offset for a stepped sensor may lie from the reference run's less the steps at its exit (s):
#: both are the configured offset less the estimator's bias (a low quantile of the latency above the least, tens of
#: ms, the same in both runs), so their difference is the steps, to a late delivery's few ms
FOLLOW_OFFSET_TOL_S = 0.05


def clocks_followed(sensors: dict) -> dict:
    """``sensor_clocks_followed`` (with ``--clock-jump-every`` only): every tracker that takes a sensor whose clock
    the soak stepped back followed it. Its offset for that sensor at its exit is the reference run's less the
    steps (to :data:`FOLLOW_OFFSET_TOL_S`), and it refused (``stale``) no more of its detections than its estimate
    needs to follow each step (:data:`FOLLOW_DETECTIONS` less one, and :data:`FOLLOW_SLACK`) beyond the
    reference's. A tracker that never followed would refuse every later detection as stale and keep its offset:
    its accuracy window alone would hardly tell (it fuses its neighbours' estimates meanwhile)."""
    rows = []
    runs = sensors["trackers"]
    for s, entry in sensors["sensors"].items():
        steps = len(entry["clock_jumps_at_s"])
        if not steps:
            continue
        for i in entry["trackers"]:
            mine, ref = runs["faulty"].get(str(i), {}), runs["reference"].get(str(i), {})
            offset, ref_offset = ((m.get("sensor_offsets_s") or {}).get(s) for m in (mine, ref))
            moved = None if offset is None or ref_offset is None else ref_offset - offset
            stale = mine.get("refused", {}).get("stale", 0) - ref.get("refused", {}).get("stale", 0)
            limit = steps * (FOLLOW_DETECTIONS - 1 + FOLLOW_SLACK)
            ok = moved is not None and abs(moved - entry["clock_back_s"]) <= FOLLOW_OFFSET_TOL_S and stale <= limit
            rows.append({"sensor": int(s), "node": i, "steps": steps, "clock_back_s": entry["clock_back_s"],
                         "offset_moved_s": moved, "stale": stale, "stale_limit": limit, "pass": ok})
    return {"pass": all(r["pass"] for r in rows), "trackers": rows, "offset_tolerance_s": FOLLOW_OFFSET_TOL_S}


def followed_lines(c: dict) -> list[str]:
    """What ``sensor_clocks_followed`` measured: one line per tracker on a failure, a summary on a pass."""
    def line(r: dict) -> str:
        moved = "no offset at its exit" if r["offset_moved_s"] is None else \
            f"its offset moved {r['offset_moved_s']:.3f} s"
        return (f"node {r['node']} (sensor-{r['sensor']}, {r['steps']} step(s), {r['clock_back_s']:g} s back): {moved}, "
                f"{r['stale']} stale (limit {r['stale_limit']})")

    if c["pass"]:
        rows = c["trackers"]
        worst = max((abs(r["offset_moved_s"] - r["clock_back_s"]) for r in rows), default=0.0)
        return [f"{len(rows)} tracker(s) followed their sensor's stepped clock: {', '.join(str(r['stale']) for r in rows)} "
                f"stale, offsets within {1e3 * worst:.0f} ms of the steps (limit {1e3 * c['offset_tolerance_s']:g} ms)"]
    return [line(r) for r in c["trackers"] if not r["pass"]]
