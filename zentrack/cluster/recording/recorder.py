"""The evaluator of a cluster run: records every node's posterior and computes ``summary.json``.

It subscribes to ``est/*`` like any observer (the true states come from the scenario the run replays), keeps
one entry per (node, step), and summarises per node: RMSE against the truth, ANEES, step latency
(measurement published -> posterior published), deadline misses, coasting, warm starts, gaps (steps without
a posterior, e.g. while a node was dead), outages (stretches cut off, then back: ``common/outages.py``) and
message counters summed over the node's restarts.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import zenoh

from zentrack.common.atomic import replace_atomically
from zentrack.common.outages import node_outages, runs_of
from zentrack.fusion.consistency import anees_band
from zentrack.transport.codec import MAX_ROUNDS, Message, WireError
from zentrack.transport.messages import EstimateMessage
from zentrack.transport.zsession import Inbox
from zentrack.truth.simulation.scenario import ScenarioData, state_groups

log = logging.getLogger("zentrack.recorder")
#: the recorder keeps the first this many miss notes of a run
MAX_NOTES = 1000


class Recorder:
    def __init__(self, session: zenoh.Session, keys, scn: ScenarioData) -> None:
        self.keys, self.scn = keys, scn
        self.inbox = Inbox(rate_per_key=1e9, max_queued=1_000_000)  # the recorder must not drop what it scores
        k, m, n = scn.steps, scn.nodes, scn.truth.shape[-1]
        self.mean = np.full((k, m, n), np.nan)
        self.cov = np.full((k, m, n, n), np.nan)
        self.latency = np.full((k, m), np.nan)
        self.flags = {name: np.zeros((k, m), dtype=bool) for name in ("coasted", "miss", "warm")}
        self.fused = np.zeros((k, m), dtype=int)
        self.update_us = np.full((k, m), np.nan)
        #: wall-clock times (s) of each step: truth published the measurement, the node received it, the node
        #: published its posterior (NaN where unknown): where a late step lost its time
        self.times = {name: np.full((k, m), np.nan) for name in ("t_meas_pub", "t_recv", "t_pub")}
        #: how long each fusion round of each step's prior took (ms), NaN where unknown: ``(K, M, MAX_ROUNDS)``
        self.round_ms = np.full((k, m, MAX_ROUNDS), np.nan)
        self.counters_total: list[dict] = [dict() for _ in range(m)]
        self.counters_last: list[dict] = [dict() for _ in range(m)]
        #: estimates received from each node since its last one carrying counters (of that incarnation)
        self.received_since_counters = np.zeros(m, dtype=int)
        self.restarts = np.zeros(m, dtype=int)
        self.bad_messages = 0
        #: the deadline misses the nodes noted (``MissNote.as_dict`` with ``node``), the first MAX_NOTES of them
        self.miss_notes: list[dict] = []
        self.sub = session.declare_subscriber(keys.est("*"), self.inbox.callback("est"))
        self.token = session.liveliness().declare_token(keys.alive("recorder"))

    def drain(self, timeout: float = 0.0) -> int:
        """Process queued estimates (waiting up to ``timeout`` for the first); returns how many."""
        return self.inbox.drain(self._record, timeout)

    def _record(self, msg: Message) -> None:
        node = self.keys.node_of(msg.key)
        try:
            if node is None or node >= self.scn.nodes:
                raise WireError("sender_mismatch", f"estimate on key {msg.key}")
            i = node
            e = EstimateMessage.decode(msg.payload, i)
            k = e.k
            if not k < self.scn.steps or e.x.shape[0] != self.mean.shape[-1]:
                raise WireError("shape", f"step {k} or dimension {e.x.shape[0]} out of range")
        except WireError as err:
            self.bad_messages += 1
            if self.bad_messages <= 3:
                log.warning("recorder: dropped an estimate (%s)", err)
            return
        self.mean[k, i], self.cov[k, i] = e.x, e.P
        if e.t_meas_pub is not None:
            self.latency[k, i] = e.t_pub - e.t_meas_pub
        for name, value in (("t_meas_pub", e.t_meas_pub), ("t_recv", e.t_recv), ("t_pub", e.t_pub)):
            if value is not None:
                self.times[name][k, i] = value
        self.flags["coasted"][k, i], self.flags["miss"][k, i], self.flags["warm"][k, i] = e.coasted, e.miss, e.warm
        self.fused[k, i] = e.fused
        self.miss_notes += [{"node": i, **n.as_dict()} for n in e.miss_notes[:MAX_NOTES - len(self.miss_notes)]]
        if e.round_ms is not None:
            self.round_ms[k, i, : e.round_ms.size] = e.round_ms
        self.update_us[k, i] = np.nan if e.update_us is None else e.update_us
        counters = e.counters
        if counters is None:  # carried every COUNTERS_EVERY_STEPS estimates, not by this one
            self.received_since_counters[i] += 1
            return
        last = self.counters_last[i]
        restarted = counters.get("incarnation", 0) != last.get("incarnation", 0) or counters.get("steps", 0) < last.get("steps", 0)
        if last and restarted:  # the node restarted: bank its predecessor's counts
            self.restarts[i] += 1
            _add_counters(self.counters_total[i], _with_received(last, int(self.received_since_counters[i])))
        self.counters_last[i] = counters
        self.received_since_counters[i] = 0

    def close(self) -> None:
        self.sub.undeclare()
        self.token.undeclare()

    def save_estimates(self, path: Path) -> None:
        """Write every posterior to ``path`` atomically: a full disk leaves no truncated file behind."""
        def write(tmp: Path) -> None:
            np.savez(tmp, mean=self.mean, cov=self.cov, latency=self.latency, truth=self.scn.truth[0],
                     fused=self.fused, round_ms=self.round_ms, **self.times, **{f"flag_{k}": v for k, v in self.flags.items()})  # type: ignore[arg-type]  # numpy stub: **kwds vs allow_pickle: bool

        replace_atomically(path, write, suffix=".tmp.npz")

    def have(self) -> np.ndarray:
        """(steps, nodes): whether each node's estimate of each step was recorded."""
        return np.isfinite(self.mean).all(axis=-1)

    def step_errors(self) -> np.ndarray:
        """(steps, nodes) distance of every node's position estimate from the truth (NaN: no estimate)."""
        return np.linalg.norm(self.mean[:, :, :3] - self.scn.truth[0][:, None, :3], axis=-1)

    def nan_free(self) -> bool:
        """Whether every recorded estimate's covariance is finite."""
        return bool(np.all(np.isfinite(self.cov[self.have()])))

    def steps_reached(self) -> int:
        """How many steps the run got through: one past the last step any node published an estimate for
        (0 before the first estimate)."""
        reached = np.flatnonzero(np.any(np.isfinite(self.mean[..., 0]), axis=1))
        return int(reached[-1]) + 1 if reached.size else 0

    def summary(self, reports: dict[int, dict] | None = None, steps_run: int | None = None) -> dict:
        """Per-node and network figures. ``reports``: each node's final ``node-<i>.json`` (its own counters at
        exit), which take precedence over the counters carried by its last estimate when they are larger
        (a node that stopped publishing estimates still counts its misses). ``steps_run``: an interrupted
        run's steps (:meth:`steps_reached`): the figures cover those, not the steps never reached."""
        reports = reports or {}
        scn = self.scn
        steps = scn.steps if steps_run is None else max(0, min(steps_run, scn.steps))
        truth = scn.truth[0][:steps]
        mean, cov, latency, fused = self.mean[:steps], self.cov[:steps], self.latency[:steps], self.fused[:steps]
        flags = {name: flag[:steps] for name, flag in self.flags.items()}
        update_us, round_ms = self.update_us[:steps], self.round_ms[:steps]
        err = mean - truth[:, None, :]
        have = np.all(np.isfinite(mean), axis=-1)
        groups = state_groups(scn)
        nodes = []
        for i in range(scn.nodes):
            ok = have[:, i]
            e = err[ok, i]
            entry: dict = {"node": i, "steps_estimated": int(ok.sum()), "steps_without_estimate": int((~ok).sum()),
                           "gaps": runs_of(~ok)}
            for g, idx in groups.items():
                entry[f"rmse_{g}"] = float(np.sqrt(np.mean(np.sum(e[:, idx] ** 2, axis=-1)))) if ok.any() else None
            if ok.any():
                c = cov[ok, i]
                nees = np.einsum("ki,ki->k", e, np.linalg.solve(c, e[..., None])[..., 0])
                entry["anees"] = float(nees.mean())
                entry["anees_band"] = list(anees_band(truth.shape[-1], int(ok.sum())))
                entry["nan_estimates"] = 0
            lat = latency[:, i][np.isfinite(latency[:, i])]
            entry["latency_ms"] = percentiles(lat * 1e3)
            entry["update_us_median"] = float(np.nanmedian(update_us[:, i])) if ok.any() else None
            entry["coasted_steps"] = int(flags["coasted"][:, i].sum())
            entry.update(node_outages(ok, flags["coasted"][:, i]))  # cut off, then back (common/outages.py)
            entry["warm_starts"] = int(flags["warm"][:, i].sum())
            entry["restarts_seen"] = int(self.restarts[i])
            total = _final_counters(self.counters_total[i], self.counters_last[i], reports.get(i),
                                    int(self.received_since_counters[i]))
            entry["final_report"] = i in reports
            entry["reported_misses"] = int(total.get("misses", 0))
            # a step without a posterior is a missed step, whatever the node managed to report
            entry["deadline_misses"] = max(entry["reported_misses"], entry["steps_without_estimate"])
            entry["estimates_published"] = int(total.get("steps", 0))  # as the node counted them
            # published but never received (transport drops, e.g. through a congested or restarting router)
            entry["estimates_lost"] = max(0, entry["estimates_published"] - entry["steps_estimated"])
            entry["reconnects"] = int(total.get("reconnects", 0))
            entry["warm_self"] = int(total.get("warm_self", 0))
            entry["cold_restarts"] = int(total.get("cold_restarts", 0))
            entry["messages"] = {
                "meas_received": int(total.get("meas_rx", 0)),
                "priors_received": int(total.get("prior_rx", 0)),
                "late": int(total.get("late", 0)),
                "partial_rounds": int(total.get("partial_rounds", 0)),
                "relays_received": int(total.get("relays_rx", 0)),
                # steps whose shared prior went without some live neighbour's relayed scans (relay_scans)
                "partial_relays": int(total.get("partial_relays", 0)),
                # relayed scans a hub left out to keep its relay within the message size cap
                "relay_left_out": int(total.get("relay_left_out", 0)),
                # local updates and fusions whose result was not finite and positive definite: the node kept
                # its own estimate (extreme but well-formed input, e.g. a forged pose of 1e150 m)
                "refused": {k: int(v) for k, v in (total.get("refused") or {}).items()},
                "gated": int(total.get("gated", 0)),  # neighbours' messages the gate kept out of fusion
                "conflicts": int(total.get("conflicts", 0)),  # copies left out: their (step, round) had another
                # rounds fused from neighbours that agreed with each other but not with this node's estimate
                "outvoted": int(total.get("outvoted", 0)),
                "gate_lifted": int(total.get("gate_lifted", 0)),  # after a streak of refusing every sender
                "rejected": total.get("rejected", {}),
                "dropped": total.get("dropped", {}),  # by the flood guard, before decoding
            }
            entry["mean_pairs_fused"] = float(fused[ok, i].mean()) if ok.any() else None
            nodes.append(entry)
        lat_all = latency[np.isfinite(latency)] * 1e3
        pos = [n[f"rmse_{next(iter(groups))}"] for n in nodes if n[f"rmse_{next(iter(groups))}"] is not None]
        n_dim = truth.shape[-1]
        samples = int(have.sum())
        return {
            "nodes": nodes,
            "network": {
                "steps": steps,
                "steps_planned": scn.steps,  # more than "steps" when the run was interrupted
                "nodes": scn.nodes,
                "estimates": samples,
                "median_rmse_" + next(iter(groups)): float(np.median(pos)) if pos else None,
                "latency_ms": percentiles(lat_all),
                # per fusion round: own message sent to fused (all rounds of all steps and nodes)
                "round_ms": percentiles(round_ms[np.isfinite(round_ms)]),
                "partial_rounds": int(sum(n["messages"]["partial_rounds"] for n in nodes)),
                "partial_relays": int(sum(n["messages"]["partial_relays"] for n in nodes)),
                "gated": int(sum(n["messages"]["gated"] for n in nodes)),
                "priors_received": int(sum(n["messages"]["priors_received"] for n in nodes)),
                "deadline_misses": int(sum(n["deadline_misses"] for n in nodes)),
                "steps_without_estimate": int(sum(n["steps_without_estimate"] for n in nodes)),
                "estimates_lost": int(sum(n["estimates_lost"] for n in nodes)),
                "anees_band_per_node": list(anees_band(n_dim, max(1, steps))),
                "finite": bool(np.all(np.isfinite(cov[have]))),
                "dropped_estimate_messages": self.bad_messages,
                "refused": refused_counts(nodes),
            },
            "miss_notes": list(self.miss_notes),  # each noted miss: node, step, kind, phase, how late
        }


def refused_counts(nodes: list[dict]) -> dict[str, int]:
    """What the nodes refused, summed per kind: each rejection reason (``early``, ``conflict``, ``undecodable``,
    ...), each flood-guard drop (``dropped <tag>/<reason>``) and the round messages left out in conflicts
    (``conflicts``); the gate's refusals are reported apart (``gated``: honest outliers too)."""
    out: dict[str, int] = {}
    for n in nodes:
        m = n["messages"]
        for name, count in [*m["rejected"].items(), *((f"dropped {k}", v) for k, v in m["dropped"].items()),
                            ("conflicts", m["conflicts"])]:
            if count:
                out[name] = out.get(name, 0) + int(count)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _final_counters(banked: dict, last: dict, report: dict | None, since: int = 0) -> dict:
    """Counters summed over a node's incarnations: ``banked`` (earlier ones, from their last estimates),
    then the current one from the larger of its last estimate's and its final report's counts. ``since``:
    estimates received after the last one carrying counters (published, so counted as such)."""
    total = dict(banked)
    last = _with_received(last, since)
    if report is None:
        _add_counters(total, last)
        return total
    if last and report.get("incarnation") != last.get("incarnation"):
        _add_counters(total, last)  # the reporting incarnation published no estimate at all
        _add_counters(total, report)
        return total
    merged = dict(last)
    for key, value in report.items():
        if isinstance(value, dict):
            merged[key] = {r: max(value.get(r, 0), (last.get(key) or {}).get(r, 0)) for r in {*value, *(last.get(key) or {})}}
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and key != "incarnation":
            merged[key] = max(value, last.get(key, 0) or 0)
    _add_counters(total, merged)
    return total


def _with_received(last: dict, since: int) -> dict:
    """An incarnation's last counters, with the ``since`` estimates received after them counted as published:
    counters ride on every COUNTERS_EVERY_STEPS-th estimate only, so a killed node's are up to 9 steps old
    (without this, those estimates would look lost)."""
    return {**last, "steps": last.get("steps", 0) + since} if last and since else last


def _add_counters(total: dict, add: dict) -> None:
    for key, value in add.items():
        if key == "incarnation" or isinstance(value, bool):
            continue
        if isinstance(value, dict):
            _add_counters(total.setdefault(key, {}), value)
        elif isinstance(value, (int, float)):
            total[key] = total.get(key, 0) + value


def percentiles(x: np.ndarray) -> dict:
    """The count, median, 90th and 99th percentile and maximum of ``x`` (the count only when empty)."""
    if x.size == 0:
        return {"count": 0}
    p50, p90, p99 = np.percentile(x, [50, 90, 99])
    return {"count": int(x.size), "p50": float(p50), "p90": float(p90), "p99": float(p99), "max": float(x.max())}
