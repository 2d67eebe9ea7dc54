"""The evaluator of a many-target run: records every node's track lists and computes ``summary.json``.

It subscribes to ``tracks/*`` like any observer (the targets come from the run the truth replays), keeps one
list per (node, step), and summarises per node: GOSPA (alpha = 2, the run's cut-off ``data.gospa_cutoff``, order 2) of its
confirmed tracks against the targets present, with its localisation, missed and false parts, identity switches
and fragmentations; deadline misses (a list past its deadline, or none for a step the node was running);
steps without a list (gaps, e.g. while a node was dead), latency (measurement published -> list published),
the local tracker's time per scan, and the node's counters (refused messages by reason, takeovers). After a
restart (a gap), ``recovery_steps`` is how many steps the node took to hold confirmed tracks on as many targets
(within the cut-off) as before its gap: the warm start from its neighbours' lists.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import zenoh

from zentrack.cluster.recording.recorder import percentiles, refused_counts
from zentrack.common.atomic import replace_atomically
from zentrack.common.outages import runs_of
from zentrack.fusion.multitarget.metrics import gospa, summarize_run
from zentrack.transport.codec import Message, WireError
from zentrack.transport.track_messages import TrackList
from zentrack.transport.zsession import Inbox
from zentrack.truth.simulation.multitarget import MultiTargetData

log = logging.getLogger("zentrack.recorder")

#: a node "has its tracks back" after a gap once it covers this fraction of what it covered before
RECOVERED_FRACTION = 0.9


class MultiTargetRecorder:
    """Records the track lists of a many-target run (module docstring)."""

    def __init__(self, session: zenoh.Session, keys, data: MultiTargetData) -> None:
        self.keys, self.data = keys, data
        self.scn = data  # what the soak reads: steps, nodes, ts
        self.inbox = Inbox(rate_per_key=1e9, max_queued=1_000_000)
        k, m = data.steps, data.nodes
        #: (k, node) -> the list as received
        self.lists: dict[tuple[int, int], TrackList] = {}
        self.latency = np.full((k, m), np.nan)
        self.update_us = np.full((k, m), np.nan)
        self.flags = {name: np.zeros((k, m), dtype=bool) for name in ("coasted", "miss")}
        self.counters_last: list[dict] = [dict() for _ in range(m)]
        self.bad_messages = 0
        self.sub = session.declare_subscriber(keys.tracks("*"), self.inbox.callback("tracks"))
        self.token = session.liveliness().declare_token(keys.alive("recorder"))

    def drain(self, timeout: float = 0.0) -> int:
        """Process queued lists (waiting up to ``timeout`` for the first); returns how many."""
        return self.inbox.drain(self._record, timeout)

    def _record(self, msg: Message) -> None:
        node = self.keys.node_of(msg.key)
        try:
            if node is None or node >= self.data.nodes:
                raise WireError("sender_mismatch", f"tracks on {msg.key!r}")
            lst = TrackList.decode(msg.payload, node, 6, 0, self.data.steps - 1)
        except WireError as exc:
            self.bad_messages += 1
            if self.bad_messages == 1:
                log.warning("recorder: refused a track list (%s)", exc)
            return
        self.lists[(lst.k, node)] = lst
        if lst.t_meas_pub is not None:
            self.latency[lst.k, node] = (lst.t_pub - lst.t_meas_pub) * 1e3
        if lst.update_us is not None:
            self.update_us[lst.k, node] = lst.update_us
        self.flags["coasted"][lst.k, node], self.flags["miss"][lst.k, node] = lst.coasted, lst.miss
        if lst.counters is not None:
            self.counters_last[node] = lst.counters

    def close(self) -> None:
        self.sub.undeclare()
        self.token.undeclare()

    def steps_reached(self) -> int:
        """One past the last step any node published a list for."""
        return 1 + max((k for k, _ in self.lists), default=-1)

    def have(self) -> np.ndarray:
        """(steps, nodes): whether each node's list of each step was recorded."""
        out = np.zeros((self.data.steps, self.data.nodes), dtype=bool)
        for k, node in self.lists:
            out[k, node] = True
        return out

    def step_errors(self) -> np.ndarray:
        """(steps, nodes) GOSPA of every node's confirmed tracks against the targets present (NaN: no list)."""
        out = np.full((self.data.steps, self.data.nodes), np.nan)
        for k, node in self.lists:
            out[k, node] = gospa(self.confirmed_at(k, node)[1], self.truth(k)[1], self.data.gospa_cutoff).total
        return out

    def nan_free(self) -> bool:
        """Always: a list with a non-finite value is refused on decoding and never recorded."""
        return True

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
        ids, states = self.data.truth_at(k)
        return [int(i) for i in ids], states[:, :3]

    def covered(self, k: int, node: int) -> int:
        """How many targets node ``node``'s confirmed tracks at step k hold (GOSPA's assigned pairs)."""
        got = self.confirmed(k, node)
        if got is None:
            return 0
        return gospa(got[1], self.truth(k)[1], self.data.gospa_cutoff).n_assigned

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

    def summary(self, reports: dict[int, dict] | None = None, steps_run: int | None = None) -> dict:
        """The run's figures per node and for the network (module docstring)."""
        reports = reports or {}
        steps = self.data.steps if steps_run is None else max(1, min(steps_run, self.data.steps))
        truth_steps = [self.truth(k) for k in range(steps)]
        nodes = []
        for i in range(self.data.nodes):
            present = np.array([(k, i) in self.lists for k in range(self.data.steps)])
            recorded = [k for k in range(steps) if present[k]]
            entry: dict = {"node": i, "steps_estimated": len(recorded), "steps_without_list": steps - len(recorded),
                           "gaps": [list(map(int, g)) for g in runs_of(~present[:steps])]}
            if recorded:
                run = summarize_run([self.confirmed_at(k, i) for k in recorded], [truth_steps[k] for k in recorded],
                                    self.data.gospa_cutoff)
                entry.update(gospa=run.gospa, localisation=run.localisation, missed=run.missed, false=run.false,
                             n_missed=run.n_missed, n_false=run.n_false, identity_switches=run.identity.switches,
                             fragmentations=run.identity.fragmentations,
                             confirmed_mean=float(np.mean([len(self.confirmed_at(k, i)[0]) for k in recorded])))
            lat = self.latency[:steps, i]
            counters = reports.get(i) or self.counters_last[i]
            entry.update(
                deadline_misses=int(self.flags["miss"][:steps, i].sum()), coasted=int(self.flags["coasted"][:steps, i].sum()),
                latency_ms=percentiles(lat[np.isfinite(lat)]),
                update_ms=percentiles(self.update_us[:steps, i][np.isfinite(self.update_us[:steps, i])] / 1e3),
                messages={"rejected": dict(counters.get("rejected", {})), "dropped": dict(counters.get("dropped", {})),
                          "conflicts": 0, "lists_received": int(counters.get("lists_rx", 0)),
                          "late": int(counters.get("late", 0))},
                takeovers=int(counters.get("takeovers", 0)), partial_fusions=int(counters.get("partial_fusions", 0)),
                recoveries=self.recovery(i, present, steps))
            nodes.append(entry)
        scored = [n for n in nodes if "gospa" in n]
        lat = self.latency[:steps][np.isfinite(self.latency[:steps])]
        network = {
            "steps": steps, "targets_mean": float(np.mean([len(t[0]) for t in truth_steps])),
            "targets_total": int(self.data.alive[:steps].any(axis=0).sum()),
            "gospa_mean": float(np.mean([n["gospa"] for n in scored])) if scored else float("nan"),
            "deadline_misses": int(sum(n["deadline_misses"] for n in nodes)), "estimates": len(self.lists),
            "latency_ms": percentiles(lat), "bad_messages": self.bad_messages,
            "gospa_cutoff_m": self.data.gospa_cutoff, "refused": refused_counts(nodes),
        }
        return {"kind": "multitarget", "nodes": nodes, "network": network}

    def save_estimates(self, path: Path) -> None:
        """Every recorded track (``tracks.npz``): step, node, id (born, node, serial), confirmed, state (6)."""
        rows = [(k, node, e.id.born, e.id.node, e.id.serial, e.status == "confirmed", e.mean)
                for (k, node), lst in sorted(self.lists.items()) for e in lst.tracks]
        cols = list(zip(*rows)) if rows else [[] for _ in range(7)]
        arrays = {name: np.asarray(cols[c], dtype=np.int64) for c, name in enumerate(
            ("step", "node", "born", "id_node", "serial"))}
        arrays["confirmed"] = np.asarray(cols[5], dtype=bool)
        arrays["state"] = np.asarray(cols[6], dtype=float).reshape(-1, 6)

        def write(tmp: Path) -> None:
            np.savez(tmp, **arrays)  # type: ignore[arg-type]

        replace_atomically(path, write, suffix=".tmp.npz")
