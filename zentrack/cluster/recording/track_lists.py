"""The recorder's many-target part: every node's track list from ``tracks/*``, scored into ``summary.json``.

It keeps one list per (node, step) (the targets come from the run the truth replays), and summarises per node:
GOSPA (alpha = 2, the run's cut-off ``data.gospa_cutoff``, order 2) of its confirmed tracks against the targets
present, with its localisation, missed and false parts, identity switches and fragmentations; deadline misses
(a list past its deadline); steps without a list (gaps, e.g. while a node was dead), latency (measurement
published -> list published), the local tracker's time per scan, and the node's counters (refused messages by
reason, takeovers). After a restart (a gap), ``recovery_steps`` is how many steps the node took to hold confirmed
tracks on as many targets (within the cut-off) as before its gap: the warm start from its neighbours' lists.
Trackers on their own clocks (sensors of their own, ``at_validity``): a tracker's list of step k is valid at
``t0 + k ts`` on *its* clock, so it is judged against the targets at ``k ts - o`` on the truth's clock, ``o`` its
clock less the recorder's as estimated when the list came (the core's), as the single-target part judges an
estimate (:mod:`.estimates`); within the estimator's dead band, at its step.
The session, the refusals, the step times and flags and the counters are the core's (:mod:`.core`).
"""
from __future__ import annotations

import numpy as np

from zentrack.cluster.recording.core import Recorder, Refusal, percentiles, refused_counts
from zentrack.common.outages import runs_of
from zentrack.config.run_setup import RunSetup
from zentrack.fusion.multitarget.metrics import gospa, summarize_run
from zentrack.transport.track_messages import TrackList
from zentrack.truth.simulation.multitarget import MultiTargetData
from zentrack.truth.simulation.sensor_stream import multitarget_truth_at

#: a node "has its tracks back" after a gap once it covers this fraction of what it covered before
RECOVERED_FRACTION = 0.9


class TrackLists:
    """The track lists of a many-target run (module docstring): the payload part of a :class:`.core.Recorder`."""

    channel = "tracks"
    flag_names: tuple[str, ...] = ("coasted", "miss")
    refusal = Refusal("recorder: refused a track list (%s)", 1, "tracks on {!r}")

    def __init__(self, data: MultiTargetData, at_validity: bool = False) -> None:
        self.scn = data  # the run: steps, nodes, ts, the targets present
        #: (k, node) -> the list as received
        self.lists: dict[tuple[int, int], TrackList] = {}
        #: trackers on their own clocks: each list judged at its time of validity (module docstring)
        self.at_validity = at_validity
        #: (k, node) -> that node's clock less the recorder's when the list came (only where not 0)
        self.clock_offset: dict[tuple[int, int], float] = {}

    @classmethod
    def of(cls, setup: RunSetup) -> TrackLists:
        """The part for a run's setup: trackers of sensors of their own are judged at their lists' time of
        validity, on their own clocks."""
        return cls(setup.multitarget_data, at_validity=setup.sensor_timing is not None)

    def decode(self, payload: bytes, node: int) -> TrackList:
        """Node ``node``'s list of a step of the run (WireError: refused)."""
        return TrackList.decode(payload, node, 6, 0, self.scn.steps - 1)

    def keep(self, lst: TrackList, node: int, clock_offset: float = 0.0) -> None:
        self.lists[(lst.k, node)] = lst
        if self.at_validity and clock_offset != 0.0:
            self.clock_offset[(lst.k, node)] = clock_offset
        else:
            self.clock_offset.pop((lst.k, node), None)

    def have(self) -> np.ndarray:
        """(steps, nodes): whether each node's list of each step was recorded."""
        out = np.zeros((self.scn.steps, self.scn.nodes), dtype=bool)
        for k, node in self.lists:
            out[k, node] = True
        return out

    def step_errors(self) -> np.ndarray:
        """(steps, nodes) GOSPA of every node's confirmed tracks against the targets present (NaN: no list)."""
        out = np.full((self.scn.steps, self.scn.nodes), np.nan)
        for k, node in self.lists:
            out[k, node] = gospa(self.confirmed_at(k, node)[1], self.judged(k, node)[1], self.scn.gospa_cutoff).total
        return out

    def nan_free(self) -> bool:
        """Always: a list with a non-finite value is refused on decoding and never recorded."""
        return True

    def arrays(self, rec: Recorder) -> dict[str, np.ndarray]:
        """Every recorded track (``tracks.npz``): step, node, id (born, node, serial), confirmed, state (6)."""
        rows = [(k, node, e.id.born, e.id.node, e.id.serial, e.status == "confirmed", e.mean)
                for (k, node), lst in sorted(self.lists.items()) for e in lst.tracks]
        cols = list(zip(*rows)) if rows else [[] for _ in range(7)]
        arrays = {name: np.asarray(cols[c], dtype=np.int64) for c, name in enumerate(
            ("step", "node", "born", "id_node", "serial"))}
        arrays["confirmed"] = np.asarray(cols[5], dtype=bool)
        arrays["state"] = np.asarray(cols[6], dtype=float).reshape(-1, 6)
        return arrays

    # ------------------------------------------------------------------ evaluation
    def confirmed_at(self, k: int, node: int) -> tuple[list, np.ndarray]:
        """:meth:`confirmed` of a step the node has a list for."""
        got = self.confirmed(k, node)
        assert got is not None, f"node {node} has no list for step {k}"
        return got

    def confirmed(self, k: int, node: int) -> tuple[list, np.ndarray] | None:
        """Node ``node``'s confirmed tracks at step k (ids, positions ``(n, 3)``); None without a list."""
        lst = self.lists.get((k, node))
        if lst is None:
            return None
        tracks = [e for e in lst.tracks if e.status == "confirmed"]
        return [e.id for e in tracks], np.array([e.mean[:3] for e in tracks]).reshape(-1, 3)

    def truth(self, k: int) -> tuple[list, np.ndarray]:
        """The targets present at step k: ids, positions ``(n, 3)``."""
        ids, states = self.scn.truth_at(k)
        return [int(i) for i in ids], states[:, :3]

    def judged(self, k: int, node: int) -> tuple[list, np.ndarray]:
        """The targets node ``node``'s list of step k is judged against: those present at step k, or (a tracker
        whose clock is off the recorder's) at the list's time of validity on the truth's clock."""
        off = self.clock_offset.get((k, node))
        if off is None:
            return self.truth(k)
        states, present = multitarget_truth_at(self.scn, np.array([self.lists[(k, node)].t - off]))
        ids = np.flatnonzero(present[0])
        return [int(i) for i in ids], states[0, ids, :3]

    def covered(self, k: int, node: int) -> int:
        """How many targets node ``node``'s confirmed tracks at step k hold (GOSPA's assigned pairs)."""
        got = self.confirmed(k, node)
        if got is None:
            return 0
        return gospa(got[1], self.judged(k, node)[1], self.scn.gospa_cutoff).n_assigned

    def recovery(self, node: int, present: np.ndarray, steps: int) -> list[dict]:
        """Per gap of node ``node`` that it came back from: the steps until it covered
        :data:`RECOVERED_FRACTION` of the targets it covered at its last step before the gap."""
        out = []
        for a, b in runs_of(~present[:steps]):
            if a == 0 or b + 1 >= steps:
                continue
            before = self.covered(a - 1, node)
            back = next((k - (b + 1) for k in range(b + 1, steps)
                         if self.covered(k, node) >= RECOVERED_FRACTION * before), None)
            out.append({"gap": [int(a), int(b)], "covered_before": before, "recovery_steps": back})
        return out

    def summary(self, rec: Recorder, reports: dict[int, dict], steps_run: int | None) -> dict:
        """The run's figures per node and for the network (module docstring). ``reports``: each node's final
        ``node-<i>.json``, which replaces the counters carried by its last list."""
        steps = rec.steps_covered(steps_run, least=1)
        truth_steps = [self.truth(k) for k in range(steps)]
        have = self.have()
        nodes = []
        for i in range(self.scn.nodes):
            present = have[:, i]
            recorded = [k for k in range(steps) if present[k]]
            entry = rec.node_entry(i, present[:steps], "steps_without_list")
            if recorded:
                run = summarize_run([self.confirmed_at(k, i) for k in recorded],
                                    [self.judged(k, i) if (k, i) in self.clock_offset else truth_steps[k]
                                     for k in recorded], self.scn.gospa_cutoff)
                entry.update(gospa=run.gospa, localisation=run.localisation, missed=run.missed, false=run.false,
                             n_missed=run.n_missed, n_false=run.n_false, identity_switches=run.identity.switches,
                             fragmentations=run.identity.fragmentations,
                             confirmed_mean=float(np.mean([len(self.confirmed_at(k, i)[0]) for k in recorded])))
            counters = rec.counters.latest(i, reports.get(i))
            update_us = rec.update_us[:steps, i]
            entry.update(
                deadline_misses=int(rec.flags["miss"][:steps, i].sum()), coasted=int(rec.flags["coasted"][:steps, i].sum()),
                latency_ms=rec.latency_ms(steps, i), update_ms=percentiles(update_us[np.isfinite(update_us)] / 1e3),
                messages={"rejected": dict(counters.get("rejected", {})), "dropped": dict(counters.get("dropped", {})),
                          "conflicts": 0, "lists_received": int(counters.get("lists_rx", 0)),
                          "late": int(counters.get("late", 0))},
                takeovers=int(counters.get("takeovers", 0)), partial_fusions=int(counters.get("partial_fusions", 0)),
                recoveries=self.recovery(i, present, steps))
            if self.at_validity:  # the tracker's clock as the recorder saw it, and judged it
                entry["clock_offset_seen_s"] = rec.node_clock(i)
            nodes.append(entry)
        scored = [n for n in nodes if "gospa" in n]
        network = {
            "steps": steps, "targets_mean": float(np.mean([len(t[0]) for t in truth_steps])),
            "targets_total": int(self.scn.alive[:steps].any(axis=0).sum()),
            "gospa_mean": float(np.mean([n["gospa"] for n in scored])) if scored else float("nan"),
            "deadline_misses": int(sum(n["deadline_misses"] for n in nodes)), "estimates": len(self.lists),
            "latency_ms": rec.latency_ms(steps), "bad_messages": rec.bad_messages,
            "gospa_cutoff_m": self.scn.gospa_cutoff, "refused": refused_counts(nodes),
        }
        return {"kind": "multitarget", "nodes": nodes, "network": network}
