"""The ``zentrack`` command line: one entry point with a subcommand per job."""
from __future__ import annotations

import argparse
import sys

from . import __version__


def build_parser() -> argparse.ArgumentParser:
    from zentrack.bench import paper000, speed

    from . import sim_command

    parser = argparse.ArgumentParser(prog="zentrack", description=__doc__)
    parser.add_argument("--version", action="version", version=f"zentrack {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("sim", help="batched in-process simulation of a scenario with one or more filters")
    sim_command.add_arguments(p)
    p.set_defaults(func=sim_command.run)

    from zentrack.node import process as node_process
    from zentrack.truth import process as truth_process

    from . import orchestrator, router

    p = sub.add_parser("run", help="start truth and N tracker processes, wait, write summary.json")
    orchestrator.add_arguments(p)
    p.set_defaults(func=orchestrator.run)
    p = sub.add_parser("truth", help="the truth process: publishes measurements and true states")
    truth_process.add_arguments(p)
    p.set_defaults(func=truth_process.run)
    p = sub.add_parser("node", help="one tracker process")
    node_process.add_arguments(p)
    p.set_defaults(func=node_process.run)
    from zentrack.viewer import options as viewer_options

    def run_viewer(args: argparse.Namespace) -> int:
        from zentrack.viewer import process as viewer_process  # imports Rerun only when a viewer runs

        return viewer_process.run(args)

    p = sub.add_parser("viewer", help="stream a run to Rerun: .rrd file, web viewer or native viewer")
    viewer_options.add_arguments(p)
    p.set_defaults(func=run_viewer)
    p = sub.add_parser("router", help="a Zenoh router for star and multi-host topologies")
    router.add_arguments(p)
    p.set_defaults(func=router.run)

    from . import compose, netns, soak, status

    p = sub.add_parser("status", help="list the live processes of a run (Zenoh liveliness)")
    status.add_status_arguments(p)
    p.set_defaults(func=status.status)
    p = sub.add_parser("health", help="exit 0 if a process's liveliness token is present (container HEALTHCHECK)")
    status.add_health_arguments(p)
    p.set_defaults(func=status.health)
    p = sub.add_parser("netns", help="run a compose file's services in network namespaces on a bridge (root)")
    netns.add_arguments(p)
    p.set_defaults(func=netns.run)
    p = sub.add_parser("soak", help="a realtime cluster under injected faults, judged against a fault-free run")
    soak.add_arguments(p)
    p.set_defaults(func=soak.run)
    p = sub.add_parser("compose", help="write the docker-compose file for N trackers")
    compose.add_arguments(p)
    p.set_defaults(func=compose.run)

    bench = sub.add_parser("bench", help="benchmarks (print figures and write JSON)")
    bsub = bench.add_subparsers(dest="bench", required=True)
    b = bsub.add_parser("paper000", help="seed 000 Tables 2 and 3 beside this project's Monte Carlo figures")
    paper000.add_arguments(b)
    b.set_defaults(func=paper000.run)
    from zentrack.bench import latency, scale, viewer_load

    b = bsub.add_parser("latency", help="step latency of a realtime cluster beside the raw Zenoh round trip")
    latency.add_arguments(b)
    b.set_defaults(func=latency.run)
    b = bsub.add_parser("scale", help="largest N for which a realtime cluster runs with zero deadline misses")
    scale.add_arguments(b)
    b.set_defaults(func=scale.run)
    b = bsub.add_parser("viewer", help="viewer CPU per step and memory over a long realtime run")
    viewer_load.add_arguments(b)
    b.set_defaults(func=viewer_load.run)
    b = bsub.add_parser("speed", help="microseconds per node-step for every filter, and FilterPy for reference")
    speed.add_arguments(b)
    b.set_defaults(func=speed.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("zentrack: interrupted", file=sys.stderr)
        return 130
    except ValueError as exc:  # bad values found after parsing (files, combinations): one clear line
        print(f"zentrack {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
