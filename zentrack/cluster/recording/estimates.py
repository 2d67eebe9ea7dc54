"""The recorder's single-target part: every node's posterior from ``est/*``, scored into ``summary.json``.

It keeps one posterior per (node, step) with what only estimates carry (the pairs fused, each fusion round's
time, the deadline misses the nodes noted), and summarises per node: RMSE against the truth (the true states
come from the scenario the run replays), ANEES, step latency (measurement published -> posterior published),
deadline misses, coasting, warm starts, gaps (steps without a posterior, e.g. while a node was dead), outages
(stretches cut off, then back: ``common/outages.py``) and message counters summed over the node's restarts.

Trackers on their own clocks (sensors of their own, ``at_validity``): a tracker's estimate of step k is valid at
``t0 + k ts`` on *its* clock (its ``t`` after t0). One whose clock is ``o`` ahead of the truth's made it ``o``
earlier, so it is judged against the truth at ``k ts - o`` on the truth's clock, ``o`` as the recorder estimated
it from the tracker's estimates when each came (the core's; the recorder shares the truth's host and clock), and
reported per node (``clock_offset_seen_s``). Within the estimator's dead band (10 ms) a tracker is judged at its
step, as in a synchronous run.
The session, the refusals, the step times and flags and the counters are the core's (:mod:`.core`).
"""
from __future__ import annotations

import numpy as np

from zentrack.cluster.recording.core import Recorder, Refusal, percentiles, refused_counts
from zentrack.common.outages import node_outages
from zentrack.config.run_setup import RunSetup
from zentrack.fusion.consistency import anees_band
from zentrack.transport.codec import MAX_ROUNDS, WireError
from zentrack.transport.messages import EstimateMessage
from zentrack.truth.simulation.scenario import ScenarioData, state_groups
from zentrack.truth.simulation.sensor_stream import state_at

#: the recorder keeps the first this many miss notes of a run
MAX_NOTES = 1000


class Estimates:
    """The posteriors of a single-target run (module docstring): the payload part of a :class:`.core.Recorder`."""

    channel = "est"
    flag_names: tuple[str, ...] = ("coasted", "miss", "warm")
    refusal = Refusal("recorder: dropped an estimate (%s)", 3, "estimate on key {}")

    def __init__(self, scn: ScenarioData, at_validity: bool = False) -> None:
        self.scn = scn
        k, m, n = scn.steps, scn.nodes, scn.truth.shape[-1]
        #: trackers on their own clocks (sensors of their own): each estimate is judged at its time of validity
        #: on the truth's clock, not at its step's sample (module docstring)
        self.at_validity = at_validity
        #: (steps, nodes): each estimate's time of validity after t0 on its tracker's clock (its ``t``), and that
        #: tracker's clock less the recorder's when it came (0 unless ``at_validity``)
        self.valid_t = np.full((k, m), np.nan)
        self.clock_offset = np.zeros((k, m))
        self.mean = np.full((k, m, n), np.nan)
        self.cov = np.full((k, m, n, n), np.nan)
        self.fused = np.zeros((k, m), dtype=int)
        #: how long each fusion round of each step's prior took (ms), NaN where unknown: ``(K, M, MAX_ROUNDS)``
        self.round_ms = np.full((k, m, MAX_ROUNDS), np.nan)
        #: the deadline misses the nodes noted (``MissNote.as_dict`` with ``node``), the first MAX_NOTES of them
        self.miss_notes: list[dict] = []

    @classmethod
    def of(cls, setup: RunSetup) -> Estimates:
        """The part for a run's setup: trackers of sensors of their own are judged at their estimates' time of
        validity, on their own clocks."""
        return cls(setup.scenario, at_validity=setup.sensor_timing is not None)

    def decode(self, payload: bytes, node: int) -> EstimateMessage:
        """Node ``node``'s estimate of a step of the run, in the scenario's dimension (WireError: refused)."""
        e = EstimateMessage.decode(payload, node)
        if not e.k < self.scn.steps or e.x.shape[0] != self.mean.shape[-1]:
            raise WireError("shape", f"step {e.k} or dimension {e.x.shape[0]} out of range")
        return e

    def keep(self, e: EstimateMessage, i: int, clock_offset: float = 0.0) -> None:
        k = e.k
        self.valid_t[k, i] = e.t
        self.clock_offset[k, i] = clock_offset if self.at_validity else 0.0
        self.mean[k, i], self.cov[k, i] = e.x, e.P
        self.fused[k, i] = e.fused
        self.miss_notes += [{"node": i, **n.as_dict()} for n in e.miss_notes[:MAX_NOTES - len(self.miss_notes)]]
        if e.round_ms is not None:
            self.round_ms[k, i, : e.round_ms.size] = e.round_ms

    def have(self) -> np.ndarray:
        """(steps, nodes): whether each node's estimate of each step was recorded."""
        return np.isfinite(self.mean).all(axis=-1)

    def truth_judged(self, steps: int | None = None) -> np.ndarray:
        """``(steps, nodes, n)``: the true state each node's estimate of each step is judged against: the truth at
        the step, or (``at_validity``, a tracker whose clock is off the recorder's beyond the dead band) at the
        estimate's time of validity on the truth's clock, its ``t`` less the offset, between the truth's samples
        as a sensor samples it (:func:`~zentrack.truth.simulation.sensor_stream.state_at`)."""
        truth = self.scn.truth[0][:steps]
        out = np.repeat(truth[:, None, :], self.scn.nodes, axis=1)
        off = self.clock_offset[: truth.shape[0]]
        shifted = (off != 0.0) & np.isfinite(self.valid_t[: truth.shape[0]])
        if shifted.any():
            out[shifted] = state_at(self.scn, 0, self.valid_t[: truth.shape[0]][shifted] - off[shifted])
        return out

    def step_errors(self) -> np.ndarray:
        """(steps, nodes) distance of every node's position estimate from the truth (NaN: no estimate)."""
        return np.linalg.norm(self.mean[:, :, :3] - self.truth_judged()[:, :, :3], axis=-1)

    def nan_free(self) -> bool:
        """Whether every recorded estimate's covariance is finite."""
        return bool(np.all(np.isfinite(self.cov[self.have()])))

    def arrays(self, rec: Recorder) -> dict[str, np.ndarray]:
        """``estimates.npz``: every posterior, its latency, the truth, the pairs fused, the rounds' times, the
        step's wall-clock times and flags; trackers on their own clocks (``at_validity``) also each tracker's clock
        offset as the recorder estimated it when each estimate came (``clock_offset``, ``(steps, nodes)``) and the
        truth each estimate was judged against (``truth_judged``, ``(steps, nodes, n)``)."""
        own = dict(clock_offset=self.clock_offset, truth_judged=self.truth_judged()) if self.at_validity else {}
        return dict(mean=self.mean, cov=self.cov, latency=rec.latency, truth=self.scn.truth[0], fused=self.fused,
                    round_ms=self.round_ms, **rec.times, **{f"flag_{k}": v for k, v in rec.flags.items()}, **own)

    def summary(self, rec: Recorder, reports: dict[int, dict], steps_run: int | None) -> dict:
        """Per-node and network figures. ``reports``: each node's final ``node-<i>.json``, which take precedence
        over the counters carried by its last estimate when they are larger (a node that stopped publishing
        estimates still counts its misses)."""
        scn = self.scn
        steps = rec.steps_covered(steps_run)
        truth = scn.truth[0][:steps]
        mean, cov, fused = self.mean[:steps], self.cov[:steps], self.fused[:steps]
        flags = {name: flag[:steps] for name, flag in rec.flags.items()}
        update_us, round_ms = rec.update_us[:steps], self.round_ms[:steps]
        err = mean - self.truth_judged(steps)
        have = np.all(np.isfinite(mean), axis=-1)
        groups = state_groups(scn)
        nodes = []
        for i in range(scn.nodes):
            ok = have[:, i]
            e = err[ok, i]
            entry = rec.node_entry(i, ok, "steps_without_estimate")
            for g, idx in groups.items():
                entry[f"rmse_{g}"] = float(np.sqrt(np.mean(np.sum(e[:, idx] ** 2, axis=-1)))) if ok.any() else None
            if ok.any():
                c = cov[ok, i]
                nees = np.einsum("ki,ki->k", e, np.linalg.solve(c, e[..., None])[..., 0])
                entry["anees"] = float(nees.mean())
                entry["anees_band"] = list(anees_band(truth.shape[-1], int(ok.sum())))
                entry["nan_estimates"] = 0
            entry["latency_ms"] = rec.latency_ms(steps, i)
            entry["update_us_median"] = float(np.nanmedian(update_us[:, i])) if ok.any() else None
            entry["coasted_steps"] = int(flags["coasted"][:, i].sum())
            entry.update(node_outages(ok, flags["coasted"][:, i]))  # cut off, then back (common/outages.py)
            entry["warm_starts"] = int(flags["warm"][:, i].sum())
            entry["restarts_seen"] = int(rec.counters.restarts[i])
            entry.update(_counted(rec.counters.summed(i, reports.get(i)), i in reports, entry))
            entry["mean_pairs_fused"] = float(fused[ok, i].mean()) if ok.any() else None
            if self.at_validity:  # the tracker's clock as the recorder saw it, and judged it
                entry["clock_offset_seen_s"] = rec.node_clock(i)
            nodes.append(entry)
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
                "latency_ms": rec.latency_ms(steps),
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
                "dropped_estimate_messages": rec.bad_messages,
                "refused": refused_counts(nodes),
            },
            "miss_notes": list(self.miss_notes),  # each noted miss: node, step, kind, phase, how late
        }


def _counted(total: dict, reported: bool, entry: dict) -> dict:
    """A node's figures from its counters summed over its restarts (``total``), in summary order; ``reported``:
    whether it wrote a final report; ``entry``: its figures so far (the steps it has an estimate for)."""
    out: dict = {"final_report": reported, "reported_misses": int(total.get("misses", 0))}
    # a step without a posterior is a missed step, whatever the node managed to report
    out["deadline_misses"] = max(out["reported_misses"], entry["steps_without_estimate"])
    out["estimates_published"] = int(total.get("steps", 0))  # as the node counted them
    # published but never received (transport drops, e.g. through a congested or restarting router)
    out["estimates_lost"] = max(0, out["estimates_published"] - entry["steps_estimated"])
    out["reconnects"] = int(total.get("reconnects", 0))
    out["warm_self"] = int(total.get("warm_self", 0))
    out["cold_restarts"] = int(total.get("cold_restarts", 0))
    out["messages"] = {
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
    return out
