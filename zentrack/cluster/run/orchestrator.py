"""``zentrack run``: its flags, and the run itself — start a :class:`~zentrack.cluster.run.cluster.Cluster`, wait for
it with a progress line, stop it, print the summary and the closing line, exit 0 only for a run that did its job.
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from zentrack.cluster.deployment.certs import add_secure_argument, certificate_folder, make_certificates, run_roles
from zentrack.cluster.run.cluster import Cluster, RunFailed
from zentrack.cluster.run.options import (
    LONE_TRACKER,
    PEER_MESH_LIMIT,
    TOPOLOGIES,
    node_prefix_arg,
    node_prefixes,
    uses_router,
)
from zentrack.common.argtypes import float_in
from zentrack.common.deprecation import DeprecatedFlag
from zentrack.common.procs import setup_logging
from zentrack.common.progress import Progress
from zentrack.common.run_summary import (
    interrupted_line,
    ok_line,
    print_summary,
    run_failures,
    transport_warnings,
)
from zentrack.config.node_config import MODES
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.transport.zsession import build_config

log = logging.getLogger("zentrack.run")


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_arguments(p)
    p.add_argument("--mode", dest="timing_mode", choices=MODES, action=DeprecatedFlag, use="--timing")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder: summary.json, estimates.npz, logs/")
    p.add_argument("--topology", choices=TOPOLOGIES, default="auto",
                   help=f"peers: a full Zenoh peer mesh; router: a Zenoh router, every process its client; auto "
                        f"(default): peers up to {PEER_MESH_LIMIT} trackers, a router above")
    p.add_argument("--router", action="store_true", help="the same as --topology router")
    add_secure_argument(p, "or without it made in <out>/certs")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 file for every process of the run, merged over zentrack's safe defaults "
                        "(loopback listen, no multicast scouting); the run's own endpoints override its")
    p.add_argument("--viewer", action="store_true", help="also run the Rerun viewer, recording to <out>/recording.rrd")
    p.add_argument("--viewer-serve", action="store_true",
                   help="--viewer, and serve it live to a browser on 127.0.0.1 (the run prints the address)")
    p.add_argument("--run", metavar="NAME", help="run name (key prefix zentrack/<run>); default unique")
    p.add_argument("--timeout", type=float_in(1.0, 7 * 86400.0, "seconds"), help="give up after this many seconds (default: generous for the run)")
    p.add_argument("--max-missing-frac", type=float_in(0.0, 1.0, "fraction"), default=0.1, metavar="F",
                   help="fail (exit 1) when a node published no estimate for more than this fraction of the steps "
                        "(default 0.1); estimates lost in transport beyond it are a warning")
    p.add_argument("--node-prefix", type=node_prefix_arg, action="append", default=[], metavar="I=COMMAND",
                   help="run tracker I under COMMAND (repeatable), e.g. 1='faketime -f +0.3s': a host clock that is off "
                        "(its monotonic clock is kept real: FAKETIME_DONT_FAKE_MONOTONIC=1, "
                        "FAKETIME_FORCE_MONOTONIC_FIX=0 unless set)")


def run(args: argparse.Namespace) -> int:
    setup_logging()
    setup = resolve_setup(args)
    out = Path(args.out)
    scn = setup.run_data  # one target's run, or many targets'
    timeout = args.timeout or (scn.steps * setup.wall_period * 2 + 120 if setup.mode == "realtime"
                               else scn.steps * 2.0 + 120)
    viewer = (["--serve"] if args.viewer_serve else []) if (args.viewer or args.viewer_serve) else None
    if args.viewer_serve:
        from zentrack.viewer.ports import GRPC_PORT, WEB_PORT, check_ports_free

        # zentrack run has no port flags: the message names no flag to change
        check_ports_free({WEB_PORT: None, GRPC_PORT: None})  # a stale Rerun server on the viewer's ports: one line, exit 2, nothing started
    if args.zenoh_config:
        build_config("peer", file=args.zenoh_config)  # a bad file is one line and exit 2, before anything starts
    sensors = len(setup.sensor_streams())  # sensors of their own: one certificate each
    roles = run_roles(scn.nodes, sensors, ("router", "truth", "recorder", *(["viewer"] if viewer is not None else [])))
    # a missing certificate: one line, exit 2, nothing started
    secure = certificate_folder(args.secure, out / "certs", roles)
    router = uses_router(args.topology, args.router, scn.nodes)
    cluster = Cluster(setup, out, run=args.run, router=router, viewer=viewer,
                      zenoh_config=str(Path(args.zenoh_config).resolve()) if args.zenoh_config else None, secure=secure,
                      node_prefix=node_prefixes(dict(getattr(args, "node_prefix", [])), scn.nodes))
    cluster.claim_out()  # another live run's --out: one line naming it, exit 2, nothing of it touched
    if secure is not None and args.secure == "":  # --secure without a folder: this run's own certificates
        make_certificates(secure, scn.nodes, sensors=sensors)
    if scn.nodes == 1:
        print(f"zentrack run: warning: {LONE_TRACKER}", file=sys.stderr)
    signal.signal(signal.SIGTERM, _interrupt)  # `kill` stops the cluster as cleanly as Ctrl-C
    code, problems, summary = 1, [], None
    try:
        log.info("starting %s run %s: %d trackers, %d steps, %s, out %s", setup.mode, cluster.run_name, scn.nodes,
                 scn.steps, "secure router" if secure else "through a router" if router else "peer mesh", out)
        cluster.start()
        if viewer is not None:  # where the recording goes and the live address, while the run goes
            from zentrack.viewer.hints import run_lines

            print("\n".join(run_lines(out / "recording.rrd", args.viewer_serve)), flush=True)
        with Progress(scn.steps, "steps", label=f"run {cluster.run_name}") as progress:  # quiet unless a terminal
            code = cluster.wait(timeout, progress)
        if code != 0:
            problems.append(f"the truth process exited with status {code}")
    except KeyboardInterrupt:
        log.warning("interrupted: stopping the cluster")
        code = 130
    except (TimeoutError, RunFailed) as exc:
        problems.append(str(exc))
    finally:
        cluster.stop()
        if cluster.recorder is not None:
            summary = cluster.write_results(interrupted=code == 130)
            print_summary(summary)
    if summary is None:
        problems.append("the cluster did not start")
    else:
        problems += [f"could not write {path}" for path in summary.get("write_errors", [])]
        if code != 130:
            problems += run_failures(summary, args.max_missing_frac)
    for line in transport_warnings(summary, args.max_missing_frac) if summary is not None else []:
        print(f"zentrack run: warning: {line}", file=sys.stderr)
    for line in problems:
        print(f"zentrack run: FAILED: {line}", file=sys.stderr)
    if viewer is not None and (out / "recording.rrd").exists():
        from zentrack.viewer.hints import recording_line

        print(recording_line(out / "recording.rrd"))
    if code == 130:
        print(interrupted_line(summary, out) if summary is not None else "run interrupted before it started")
        return 130
    if problems:
        wrote = not any(e.startswith(str(out / "summary.json")) for e in (summary or {}).get("write_errors", []))
        print(f"run FAILED ({len(problems)} problem(s)); " + (f"summary in {out / 'summary.json'}" if wrote and summary
                                                             else "no summary written"))
        return code if code not in (0, 130) else 1
    print(ok_line(summary, out))
    return 0
