"""A partition on one side must not blind the other (issue 30, item 1).

Two hosts in network namespaces, a router each, the truth and the recorder on host 0. Host 1's router is cut
off (``zentrack netns cut router-1``: its link down) for 10 s, then healed, in one run:

- host 0's trackers, which still have the truth and each other, keep their schedule: no more coasted or
  missing steps while host 1 is cut off than in the same run's clean stretches (before: 49 coasted steps,
  error up to 108 m: the truth's BLOCK puts stalled router-0 on the dead link to router-1 for 5 s);
- host 1's trackers estimate from fresh measurements again soon after the heal (:data:`BACK_WITHIN`);
- the recorder service does not fail host 1's trackers, which came back, and its closing line names the
  stretch they were cut off instead of a bare "run OK".
"""
from __future__ import annotations

import json
import os
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from zentrack.bench.capacity_check import compose_without_viewer
from zentrack.cluster.deployment.compose import host_of
from zentrack.cluster.engines.netns import Harness, HarnessInUse
from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import loopback_config, open_retrying

#: alone among the slow tests (``alone``): its near side coasted no extra step in three runs alone and two beside a
#: busy loop, and 3 to 11 (outages of up to 1.1 s right at the cut, every near tracker at once) in three suites out
#: of nine, each time when another test's processes were starting beside it (docs/testing.md, run 51)
pytestmark = [pytest.mark.slow, pytest.mark.alone,
              pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root (CI runs as root)")]

NODES, HOSTS, STEPS = 6, 2, 300
CUT_AT_S, CUT_S = 8.0, 10.0  # seconds after the first measurement; how long router-1 is cut off
#: steps after the heal by which the far side must estimate from fresh measurements again (the issue asks for
#: 5). Measured here 2 in every run (a 10 s cut; before: 10-14, sometimes 28): a link that Zenoh closes on a
#: dead path blocks one of its receive threads for up to 10 s (SO_LINGER), and with Zenoh's 2 such threads the
#: cut router read and dialled nothing until ~1 s after the heal (zentrack/transport/zruntime.py).
BACK_WITHIN = 5
SETTLE = 10  # steps after a node's first good one and after the heal (the far side's return), not "clean"
#: bad steps a host-0 tracker may have in the fault's window beyond its clean stretches' rate: the odd deadline
#: the loaded 2-core host makes it miss (2 of ~110 in one run of 20); a near side the cut blinded (waiting for the
#: far neighbours every step) coasts the whole window
NEAR_EXTRA = 3


def scenario():
    from zentrack.config.scenario_config import builtin_spec, load_scenario_config
    from zentrack.truth.simulation.simulate import simulate

    cfg = load_scenario_config("exp2")
    return simulate(builtin_spec("exp2", nodes=NODES, steps=STEPS), runs=1, seed=cfg.seed, ts=cfg.ts)


def wait_free(harness: Harness, timeout: float = 180.0) -> None:
    """Another harness on this machine holds the namespaces' subnet: wait for it to finish (a shared host)."""
    end = time.time() + timeout
    while True:
        try:
            harness.check_free()
            return
        except HarnessInUse:
            if time.time() > end:
                raise
            time.sleep(1.0)


def back_after(good: np.ndarray, start: int, run: int = 10, slack: int = 1) -> int:
    """Steps from ``start`` to the first good step that begins ``run`` steps with at most ``slack`` bad ones
    (a node tracking again, one late measurement allowed); len - start when never."""
    for k in range(start, len(good) - run + 1):
        if good[k] and good[k:k + run].sum() >= run - slack:
            return k - start
    return len(good) - start


@dataclass
class Outcome:
    """What one harness run with a fault on router-1's side recorded."""

    rec: Recorder
    cut_step: int
    heal_step: int
    recorder_status: int
    log: str
    summary: dict


def run_with_fault(tmp_path: Path, start: Callable[[Harness], None], end: Callable[[Harness], None]) -> Outcome:
    """Run the two-host cluster; ``start(harness)`` CUT_AT_S after the first measurement, ``end(harness)``
    CUT_S later; the steps at which they happened from the run's schedule (step k published at t0 + k Ts)."""
    compose = tmp_path / "compose.yml"
    compose.write_text(compose_without_viewer(NODES, STEPS, HOSTS))
    scn = scenario()
    harness = Harness(tmp_path / "netns", tag="p")
    wait_free(harness)
    try:
        state = harness.up(compose, str(Path(sys.executable).with_name("zentrack")))
        session = open_retrying(loopback_config("client", connect=[f"tcp/{state['addrs']['router-0']}:7447"]), 30.0)
        try:
            rec = Recorder(session, Keys("compose"), Estimates(scn))
            cut = heal = None
            truth = harness.procs["truth"]
            deadline = time.time() + 180 + STEPS * scn.ts
            while time.time() < deadline and truth.poll() is None:
                rec.drain(0.05)
                started = rec.times["t_meas_pub"][np.isfinite(rec.times["t_meas_pub"])]
                if cut is None and started.size and time.time() > started.min() + CUT_AT_S:
                    start(harness)
                    cut = time.time()
                if cut is not None and heal is None and time.time() > cut + CUT_S:
                    end(harness)
                    heal = time.time()
            assert truth.poll() is not None, "truth still runs long after its last step"
            assert heal is not None, "the run ended before the fault ended"
            rec.drain(1.0)
            rec.close()
        finally:
            session.close()
        recorder_status = harness.procs["recorder"].wait(timeout=30)
        log = (tmp_path / "netns" / "logs" / "recorder.log").read_text()
        summary = json.loads((tmp_path / "netns" / "volumes" / "recordings" / "run" / "summary.json").read_text())
    finally:
        harness.down()
    t0 = float(np.nanmedian(rec.times["t_meas_pub"] - np.arange(STEPS)[:, None] * scn.ts))
    cut_step, heal_step = (int(np.ceil((t - t0) / scn.ts)) for t in (cut, heal))
    return Outcome(rec, cut_step, heal_step, recorder_status, log, summary)


def near_side_extra(rec: Recorder, cut_step: int, heal_step: int) -> dict[int, int]:
    """Per host-0 tracker: bad (coasted or missing) steps from the fault's start to SETTLE steps after its end,
    beyond what the same run's clean stretches give for as many steps."""
    good = np.all(np.isfinite(rec.part.mean), axis=-1) & ~rec.flags["coasted"]
    window = np.zeros(STEPS, dtype=bool)
    window[cut_step:heal_step + SETTLE] = True
    extra = {}
    for i in (i for i in range(NODES) if host_of(i, NODES, HOSTS) == 0):
        bad = ~good[:, i]
        clean = ~window
        clean[:np.argmax(good[:, i]) + SETTLE] = False  # from the node's first good step on
        expected = bad[clean].sum() * window.sum() / clean.sum()
        extra[i] = int(max(0, bad[window].sum() - round(expected)))
    return extra


def test_a_cut_host_does_not_blind_the_other_and_returns_at_the_heal(tmp_path):
    out = run_with_fault(tmp_path, lambda h: h.set_link("router-1", False), lambda h: h.set_link("router-1", True))
    rec, cut_step, heal_step, recorder_status, log, summary = (
        out.rec, out.cut_step, out.heal_step, out.recorder_status, out.log, out.summary)
    far = [i for i in range(NODES) if host_of(i, NODES, HOSTS) == 1]
    good = np.all(np.isfinite(rec.part.mean), axis=-1) & ~rec.flags["coasted"]
    extra = near_side_extra(rec, cut_step, heal_step)
    back = {i: back_after(good[:, i], heal_step) for i in far}
    status = [ln for ln in log.splitlines() if ln.startswith("run ")]
    print(f"cut at step {cut_step}, healed at step {heal_step}; host 0 extra coasted/missing steps {extra}; "
          f"host 1 back after {back} steps; recorder exit {recorder_status}: {status}")
    assert heal_step - cut_step >= 80, (cut_step, heal_step)  # the cut lasted (a loaded host may skip steps)
    assert all(v <= NEAR_EXTRA for v in extra.values()), extra
    assert max(back.values()) <= BACK_WITHIN, back
    # the recorder's verdict: host 1 came back, so no node failed; the closing line says what happened
    assert recorder_status == 0, log[-3000:]
    assert "FAILED" not in log, log[-3000:]
    assert status and status[-1].startswith("run OK, but ") and "came back" in status[-1], status
    named_out = {int(i) for group in re.findall(r"nodes? ([\d, ]+) sent no estimate", status[-1])
                 for i in group.split(",")}
    for n in summary["nodes"]:
        covered = sum(b - a + 1 for a, b in n["outages"] if a <= heal_step and b >= cut_step)
        if n["node"] in far:
            assert covered >= 0.8 * (heal_step - cut_step), n["outages"]  # the cut, seen as an outage
            assert n["node"] in named_out, (n["node"], status[-1])
        else:
            assert n["outages"] == [] and n["coasted_stretches"] == [], n

