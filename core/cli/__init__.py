"""The ``zentrack`` command line: one entry point with a subcommand per job."""
from __future__ import annotations

import argparse
import os
import sys

from zentrack import __version__


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (exit status 2), naming the flag at fault."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def one_line(text: object) -> str:
    return " ".join(str(text).split())


def build_parser() -> argparse.ArgumentParser:
    from zentrack.bench import paper000, paper001, speed
    from zentrack.cli import sim as sim_command

    parser = OneLineParser(prog="zentrack", description=__doc__)
    parser.add_argument("--version", action="version", version=f"zentrack {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("sim", help="batched in-process simulation of a scenario with one or more filters")
    sim_command.add_arguments(p)
    p.set_defaults(func=sim_command.run)

    from zentrack.cluster import orchestrator
    from zentrack.node import process as node_process
    from zentrack.transport import router
    from zentrack.truth import process as truth_process

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

    from zentrack.cluster import compose, netns, record, soak, status

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
    p = sub.add_parser("record", help="record a run's estimates and write summary.json (clusters without an orchestrator)")
    record.add_arguments(p)
    p.set_defaults(func=record.run)
    p = sub.add_parser("compose", help="write the docker-compose file for N trackers")
    compose.add_arguments(p)
    p.set_defaults(func=compose.run)

    bench = sub.add_parser("bench", help="benchmarks (print figures and write JSON)")
    bsub = bench.add_subparsers(dest="bench", required=True)
    b = bsub.add_parser("paper000", help="seed 000 Tables 2 and 3 beside this project's Monte Carlo figures")
    paper000.add_arguments(b)
    b.set_defaults(func=paper000.run)
    b = bsub.add_parser("paper001", help="seed 001 in clutter: per-step RMSE of local and fused estimates beside the PCRLB")
    paper001.add_arguments(b)
    b.set_defaults(func=paper001.run)
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


def _os_error(exc: OSError) -> str:
    """``<path>: <reason>`` for an OSError about a file the user named (an --out folder, a scenario file)."""
    reason = exc.strerror or str(exc)
    paths = [p for p in (exc.filename, exc.filename2) if p is not None]
    return f"{': '.join(map(str, paths))}: {reason}" if paths else reason


# flags that name a folder or a file to write: checked before a command starts, so a typo costs no run
OUTPUT_DIRS = {"out": "--out"}
OUTPUT_FILES = {"json": "--json", "save_scenario": "--save-scenario", "save_estimates": "--save-estimates",
                "save": "--save", "output": "--output"}


def check_writable(path: str, flag: str, folder: bool) -> None:
    """Raise ValueError naming ``flag`` when ``path`` (a folder, or a file's folder) cannot be created or written:
    the nearest existing ancestor must be a writable folder, and the path itself no file where a folder goes."""
    p = os.path.abspath(path)
    if folder and os.path.exists(p) and not os.path.isdir(p):
        raise ValueError(f"{flag} {path}: exists and is not a folder")
    if not folder and os.path.isdir(p):
        raise ValueError(f"{flag} {path}: is a folder, expected a file name")
    parent = p if folder else os.path.dirname(p)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise ValueError(f"{flag} {path}: cannot be created ({parent} is a file, not a folder)")
    target = p if os.path.isdir(p) else parent
    if not os.access(target, os.W_OK | os.X_OK):
        raise ValueError(f"{flag} {path}: {target} is not writable")


def check_outputs(args: argparse.Namespace) -> None:
    for dest, flag in OUTPUT_DIRS.items():
        if isinstance(getattr(args, dest, None), str):
            check_writable(getattr(args, dest), flag, folder=True)
    for dest, flag in OUTPUT_FILES.items():
        if isinstance(getattr(args, dest, None), str):
            check_writable(getattr(args, dest), flag, folder=False)


def build_health_parser() -> argparse.ArgumentParser:
    """Only ``zentrack health``: a container's HEALTHCHECK runs it every few seconds in every service, so it
    must not import the whole package (the full parser costs over a second of CPU; this one a tenth)."""
    from zentrack.cluster import status

    parser = OneLineParser(prog="zentrack", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("health", help="exit 0 if a process's liveliness token is present (container HEALTHCHECK)")
    status.add_health_arguments(p)
    p.set_defaults(func=status.health)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_health_parser() if argv[:1] == ["health"] else build_parser()
    args = parser.parse_args(argv)
    what = f"zentrack {args.command}" + (f" {args.bench}" if getattr(args, "bench", None) else "")
    try:
        check_outputs(args)
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("zentrack: interrupted", file=sys.stderr)
        return 130
    except ValueError as exc:  # bad values found after parsing (files, combinations): one clear line
        print(f"{what}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path the user gave cannot be read or written (unwritable --out, missing file)
        print(f"{what}: error: {one_line(_os_error(exc))}", file=sys.stderr)
        return 2
    except (MemoryError, OverflowError) as exc:  # bounds are checked up front; this is the last resort
        kind = "out of memory" if isinstance(exc, MemoryError) else f"a value is out of range ({exc})"
        print(f"{what}: error: {one_line(kind)}; use smaller values (fewer --steps, --nodes or --runs)",
              file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a Zenoh error that escaped a command's own handling
        if type(exc).__name__ != "ZError":
            raise
        from zentrack.transport.zsession import describe_source, zenoh_message

        source = (describe_source(getattr(args, "zenoh_config", None), getattr(args, "listen", None),
                                  getattr(args, "connect", None)) if hasattr(args, "zenoh_config") else "Zenoh")
        print(f"{what}: error: {source}: Zenoh failed ({one_line(zenoh_message(exc))})", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
