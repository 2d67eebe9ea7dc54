"""``zentrack record``: the evaluator as a process of its own, for clusters that no orchestrator starts.

``zentrack run`` and ``zentrack soak`` record estimates inside the orchestrator. A cluster started by docker
compose (or by hand on several hosts) has none, so this process joins the run like any observer: it declares
``alive/recorder`` (truth waits for it with ``--wait-for recorder``), records every estimate until truth's
``ctl/stop`` (plus a grace for stragglers), and writes ``summary.json`` then ``estimates.npz`` to ``--out``,
judged as ``zentrack run`` judges its runs. It replays the run's scenario from the same flags as truth, since
scoring needs the true states.

Exit status: 0 when the run completed and every tracker did its job; 1 when truth never said stop within
``--timeout`` or a tracker published no estimate for more than ``--max-missing-frac`` of the steps (the summary
is written either way); 130 on SIGINT/SIGTERM (the summary covers the steps recorded so far).
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from zentrack.cluster.recording.core import Recorder
from zentrack.cluster.recording.estimates import Estimates
from zentrack.common.argtypes import float_in
from zentrack.common.procs import StopFlag, setup_logging
from zentrack.common.report import write_json
from zentrack.common.run_summary import ok_line, print_summary, run_failures
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.transport.codec import WireError
from zentrack.transport.messages import Stop
from zentrack.transport.zsession import Inbox, add_zenoh_arguments, open_session, zenoh_config

log = logging.getLogger("zentrack.record")

#: seconds to keep recording after ctl/stop, for estimates still in flight
STOP_GRACE_S = 1.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_arguments(p)
    add_zenoh_arguments(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder: summary.json, estimates.npz")
    p.add_argument("--timeout", type=float_in(1.0, 7 * 86400.0, "seconds"),
                   help="give up (exit 1) when truth has not said stop after this many seconds (default: twice "
                        "the run's length plus 5 minutes)")
    p.add_argument("--max-missing-frac", type=float_in(0.0, 1.0, "fraction"), default=0.1, metavar="F",
                   help="exit 1 when a tracker published no estimate for more than this fraction of the steps "
                        "(default 0.1)")


def is_stop_from_truth(payload: bytes) -> bool:
    """A well-formed ``ctl/stop`` sent by truth (anything else on that key is logged and ignored)."""
    try:
        Stop.decode(payload)
        return True
    except WireError as err:
        log.warning("record: ignored a message on ctl/stop (%s)", err)
        return False


def record_until_stop(recorder: Recorder, stopped: Inbox, stop: StopFlag, timeout: float) -> bool:
    """Record until truth's ``ctl/stop`` (then :data:`STOP_GRACE_S` more), a signal or ``timeout``;
    True when the stop came."""
    end = time.time() + timeout
    while not stop and time.time() < end:
        recorder.drain(0.1)
        msg = stopped.get(0.0)
        if msg is not None and is_stop_from_truth(msg.payload):
            grace = time.time() + STOP_GRACE_S
            while time.time() < grace:
                recorder.drain(0.05)
            return True
    return False


def run(args: argparse.Namespace) -> int:
    setup_logging()
    setup = resolve_setup(args)
    zenoh_config(args, "recorder")  # every flag checked before the session opens
    scn = setup.scenario
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timeout = args.timeout or 2 * scn.steps * scn.ts + 300
    stop = StopFlag()
    with open_session(args, "recorder") as (session, keys):
        stopped = Inbox()
        stop_sub = session.declare_subscriber(keys.stop, stopped.callback("stop"))
        recorder = Recorder(session, keys, Estimates.of(setup))
        log.info("record: run %s, %d trackers, %d steps; waiting for ctl/stop (at most %.0f s)",
                 keys.run, scn.nodes, scn.steps, timeout)
        try:
            completed = record_until_stop(recorder, stopped, stop, timeout)
        finally:
            recorder.close()
            stop_sub.undeclare()
    summary = recorder.summary(steps_run=recorder.steps_reached() if stop else None)  # interrupted: the steps recorded
    summary["run"] = {"name": args.run, "mode": setup.mode, "filter": setup.filter_kind, "fusion": setup.fusion,
                      "fusion_params": setup.fusion_params, "scenario": scn.name, "source": setup.source,
                      "ts": scn.ts, "deadline_frac": setup.deadline_frac, "recorded_by": "zentrack record"}
    write_json(out / "summary.json", summary)
    recorder.save_estimates(out / "estimates.npz")
    print_summary(summary)
    if stop:
        print("record interrupted: the summary covers the steps recorded so far")
        return 130
    problems = [] if completed else [f"truth did not say stop within {timeout:.0f} s"]
    problems += run_failures(summary, args.max_missing_frac)
    for line in problems:
        print(f"zentrack record: FAILED: {line}", file=sys.stderr)
    if problems:
        print(f"run FAILED ({len(problems)} problem(s)); summary in {out / 'summary.json'}")
        return 1
    print(ok_line(summary, out))  # names stretches cut off (a partition), refusals; else a bare "run OK"
    return 0
