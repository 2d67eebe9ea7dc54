"""The ``zentrack`` command line: one entry point with a subcommand per job."""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile

from zentrack import __version__
from zentrack.common.deprecation import deprecated
from zentrack.common.suggest import did_you_mean


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (exit status 2), naming the flag at fault; a
    mistyped flag, subcommand or choice gets a "did you mean" (every subcommand's parser is one of these)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        """Unknown words are refused by the subcommand's own parser, which knows its flags (argparse would
        leave them to the top-level parser and say only "unrecognized arguments"), a mistyped flag before a
        missing required one."""
        if self._subparsers is None:
            for word in sys.argv[1:] if args is None else args:
                if word == "--":
                    break
                flag = word.split("=", 1)[0]
                if flag.startswith("--") and not any(known.startswith(flag) for known in self.flags(hidden=True)):
                    self.error(f"unrecognized argument {flag}{did_you_mean(flag, self.flags())}")
        namespace, extras = super().parse_known_args(args, namespace)
        if extras and self._subparsers is None:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras

    def flags(self, hidden: bool = False) -> list[str]:
        """Every long flag this parser documents, in ``--help`` or ``--help-all`` (``hidden``: the deprecated
        ones too)."""
        return [s for a in self._actions if hidden or a.help is not argparse.SUPPRESS or hasattr(a, "full_help")
                for s in a.option_strings if s.startswith("--")]

    def _check_value(self, action: argparse.Action, value: object) -> None:
        """An invalid choice (a subcommand, ``--timing``) with the nearest valid one suggested."""
        choices = action.choices
        if choices is not None and value not in choices:
            listed = ", ".join(map(repr, choices))
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}{did_you_mean(str(value), map(str, choices))}"
                                                 f" (choose from {listed})")


def one_line(text: object) -> str:
    return " ".join(str(text).split())


#: flags a command's ``--help`` leaves to ``--help-all``: tuning and plumbing a first run does not need (the
#: scenario's own values, Zenoh's transport, process start-up and timeouts), so that ``--help`` fits a screen; a
#: command's module may name more of its own (:func:`advanced_of`)
ADVANCED = {
    "*": ("--scenario-file", "--rounds", "--fusion-param", "--qbar", "--theta", "--deadline-frac", "--period",
          "--gate", "--latency-budget-ms", "--listen", "--zenoh-config", "--lease-ms", "--zenoh-mode"),
    "run": ("--topology", "--timeout", "--max-missing-frac", "--node-prefix"),
    "truth": ("--wait-nodes", "--wait-timeout", "--start-delay", "--step-timeout", "--grace", "--resume-query-s"),
    "node": ("--reconnect-s", "--truth-timeout"),
    "sensor": ("--start-timeout", "--grace"),
    "viewer": ("--grpc-port", "--web-port", "--flush-s", "--linger", "--nice", "--bind"),
    "record": ("--timeout", "--max-missing-frac"),
    "soak": ("--fault-s", "--restart-after", "--drain-s", "--realtime-nice", "--image"),
}


def advanced_of(name: str, module: object) -> tuple[str, ...]:
    """The flags of command ``name`` (its ``module``) that ``--help`` leaves to ``--help-all``: its entry in
    :data:`ADVANCED`, and those its module's ``advanced_flags()`` names (the soak's service faults, from its
    fault registry)."""
    own = getattr(module, "advanced_flags", None)
    return (*ADVANCED.get(name, ()), *(own() if own is not None else ()))


class HelpAll(argparse.Action):
    """``--help-all``: the command's help with the flags ``--help`` leaves out."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        for action in parser._actions:
            if hasattr(action, "full_help"):
                action.help = action.full_help
        parser.epilog = None
        parser.print_help()
        parser.exit()


def tidy_help(p: argparse.ArgumentParser, advanced: tuple[str, ...]) -> None:
    """Keep a command's ``--help`` short: a one-line usage (``[options]`` and the required flags), and the
    flags in ``advanced`` shown by ``--help-all`` only (they still parse, and get a "did you mean")."""
    hidden = 0
    for action in p._actions:
        if set(action.option_strings) & set(advanced) and action.help is not argparse.SUPPRESS:
            action.full_help = action.help  # type: ignore[attr-defined]
            action.help = argparse.SUPPRESS
            hidden += 1
    required = [f"{a.option_strings[-1]} {a.metavar or a.dest.upper()}" for a in p._actions
                if a.required and a.option_strings]
    positionals = [str(a.metavar) if a.metavar else (f"{{{','.join(map(str, a.choices))}}}" if a.choices else a.dest) for a in p._actions
                   if not a.option_strings and not isinstance(a, argparse._SubParsersAction)]
    p.usage = " ".join([p.prog, "[options]", *required, *positionals])
    if hidden:
        p.add_argument("--help-all", action=HelpAll, help=f"show the {hidden} more options too")


#: every subcommand: (name, help, module, its add-arguments function, its run function). A command line
#: imports only the module of the command it names (a tracker or a health check starts in a fraction of the
#: time the whole package takes to import); ``zentrack --help`` lists them all.
COMMANDS: tuple[tuple[str, str, str, str, str], ...] = (
    ("sim", "batched in-process simulation of a scenario with one or more filters", "zentrack.cli.sim",
     "add_arguments", "run"),
    ("run", "start truth and N tracker processes, wait, write summary.json", "zentrack.cluster.run.orchestrator",
     "add_arguments", "run"),
    ("scenarios", "list the scenario catalogue (deploy/scenarios/), a line each", "zentrack.cli.scenarios",
     "add_arguments", "run"),
    ("truth", "the truth process: publishes measurements and true states", "zentrack.truth.process",
     "add_arguments", "run"),
    ("node", "one tracker process", "zentrack.cli.node_command", "add_arguments", "run"),
    ("sensor", "one sensor of its own ([sensor_timing]): its detections at its own rate, clock and latency",
     "zentrack.truth.sensor", "add_arguments", "run"),
    ("viewer", "stream a run to Rerun: .rrd file, web viewer or native viewer", "zentrack.viewer.options",
     "add_arguments", "run_viewer"),
    ("view", "serve a saved recording (.rrd) to a browser on 127.0.0.1 until Ctrl-C", "zentrack.viewer.view",
     "add_arguments", "run"),
    ("router", "a Zenoh router for star and multi-host topologies", "zentrack.transport.router", "add_arguments", "run"),
    ("status", "list the live processes of a run (Zenoh liveliness)", "zentrack.cluster.run.status",
     "add_status_arguments", "status"),
    ("health", "exit 0 if a process's liveliness token is present (container HEALTHCHECK)",
     "zentrack.cluster.run.status", "add_health_arguments", "health"),
    ("netns", "run a compose file's services in network namespaces on a bridge (root)",
     "zentrack.cluster.engines.netns", "add_arguments", "run"),
    ("soak", "a realtime cluster under injected faults, judged against a fault-free run",
     "zentrack.cluster.soak.command", "add_arguments", "run"),
    ("record", "record a run's estimates and write summary.json (clusters without an orchestrator)",
     "zentrack.cluster.recording.record", "add_arguments", "run"),
    ("compose", "write the docker-compose file for N trackers (--stack: the Docker Swarm stack file)",
     "zentrack.cluster.deployment.stack", "add_arguments", "run"),
    ("certs", "make a CA and a key and certificate per role for secure mode", "zentrack.cluster.deployment.certs",
     "add_arguments", "run"),
)
BENCHMARKS: tuple[tuple[str, str, str, str, str], ...] = (
    ("paper0", "paper 0 Tables 2 and 3 beside this project's Monte Carlo figures", "zentrack.bench.paper0",
     "add_arguments", "run"),
    ("paper1", "paper 1 in clutter: per-step RMSE of local and fused estimates beside the PCRLB",
     "zentrack.bench.paper1", "add_arguments", "run"),
    ("paper2", "paper 2: DCE-ICI and its six comparators on both UAV scenarios, ranking and RMSE against L",
     "zentrack.bench.paper2", "add_arguments", "run"),
    ("paper3", "paper 3: SecKF, EKF, UKF and linearisation at the paper's 100,000 runs, time ratios",
     "zentrack.bench.paper3", "add_arguments", "run"),
    ("paper4", "paper 4: extended objects over a 20-node network: CEOT, CI and CM (L rounds), DEOT; GW/OSPA, ACEE, NEES",
     "zentrack.bench.paper4", "add_arguments", "run"),
    ("latency", "step latency of a realtime cluster beside the raw Zenoh round trip", "zentrack.bench.latency",
     "add_arguments", "run"),
    ("hops", "round trip through 0, 1 and 2 linked routers: what a router on the path costs", "zentrack.bench.hops",
     "add_arguments", "run"),
    ("scale", "largest N for which a realtime cluster runs with zero deadline misses", "zentrack.bench.scale",
     "add_arguments", "run"),
    ("floor", "CPU per step of null trackers (messaging only, no maths) at 16, 64, 128: the floor under N trackers",
     "zentrack.bench.floor", "add_arguments", "run"),
    ("capacity", "capacity model fitted from bench scale JSON: trackers per host, bytes per link; --check-hosts",
     "zentrack.bench.capacity", "add_arguments", "run"),
    ("viewer", "viewer CPU per step and memory over a long realtime run", "zentrack.bench.viewer_load",
     "add_arguments", "run"),
    ("speed", "microseconds per node-step for every filter, and FilterPy for reference", "zentrack.bench.speed",
     "add_arguments", "run"),
    ("step", "the Python a tracker's main thread runs per step, in microseconds, piece by piece",
     "zentrack.bench.step", "add_arguments", "run"),
    ("profile", "where a tracker's CPU goes: py-spy and per-thread CPU of live trackers, by part of a step",
     "zentrack.bench.profile", "add_arguments", "run"),
    ("gate", "how often the chi-square gate refuses an honest neighbour, over lockstep runs of ten configurations",
     "zentrack.bench.gate", "add_arguments", "run"),
    ("startup", "start-to-ready time and idle memory of each process type (tracker, truth, recorder, viewer, router)",
     "zentrack.bench.startup", "add_arguments", "run"),
    ("router-restart", "router killed and restarted N times: its start-up, the re-links, and the steps until every tracker "
     "publishes again", "zentrack.bench.router_restart", "add_arguments", "run"),
    ("accuracy", "every local filter with every single-round fusion rule: RMSE / sqrt(PCRLB), ANEES, bytes and us per node-step",
     "zentrack.bench.accuracy", "add_arguments", "run"),
    ("multitarget", "many targets: each node alone, the distributed network, a centralized tracker and Stone Soup; GOSPA",
     "zentrack.bench.multitarget", "add_arguments", "run"),
    ("isolated", "a bearing-only tracker cut off from both neighbours for 5 s and 30 s: error and NEES per update rule",
     "zentrack.bench.isolated", "add_arguments", "run"),
    ("split", "the soak hour's split of step 10800 in memory: a restarted tracker beside a frozen and a cut-off "
     "neighbour, against the bound of the sensors it reaches", "zentrack.bench.split", "add_arguments", "run"),
    ("async", "sensors of their own: late and reordered detections per method (drop, fixed lag, re-process, OOSM) "
     "and Stone Soup; RMSE / sqrt(PCRLB), ANEES, CPU per detection, estimate age", "zentrack.bench.async_bench",
     "add_arguments", "run"),
)


def _add(sub, entry: tuple[str, str, str, str, str], load: bool) -> argparse.ArgumentParser:
    """Add one subcommand; its module is imported (and its flags added) only when ``load``."""
    name, help_text, module, add_fn, run_fn = entry
    p = sub.add_parser(name, help=help_text)
    if load:
        mod = importlib.import_module(module)
        getattr(mod, add_fn)(p)
        p.set_defaults(func=getattr(mod, run_fn))
        tidy_help(p, (*ADVANCED["*"], *advanced_of(name, mod)))
    return p


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of ``zentrack``; with ``argv``, only the named command's module is imported."""
    words = [w for w in (argv or []) if not w.startswith("-")]
    only = words[0] if words and words[0] in {c[0] for c in COMMANDS} | {"bench"} else None
    only_bench = words[1] if only == "bench" and len(words) > 1 else None
    parser = OneLineParser(prog="zentrack", description=__doc__)
    parser.add_argument("--version", action="version", version=f"zentrack {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for entry in COMMANDS:
        _add(sub, entry, load=only is None or entry[0] == only)
    bench = sub.add_parser("bench", help="benchmarks (print figures and write JSON)")
    bsub = bench.add_subparsers(dest="bench", required=True)
    for entry in BENCHMARKS:
        _add(bsub, entry, load=only is None or (only == "bench" and only_bench in (None, entry[0])))
    return parser


def _os_error(exc: OSError) -> str:
    """``<path>: <reason>`` for an OSError about a file the user named (an --out folder, a scenario file)."""
    reason = exc.strerror or str(exc)
    paths = [p for p in (exc.filename, exc.filename2) if p is not None]
    return f"{': '.join(map(str, paths))}: {reason}" if paths else reason


# flags that name a folder or a file to write: checked before a command starts, so a typo costs no run
OUTPUT_DIRS = {"out": "--out"}
OUTPUT_FILES = {"json": "--json", "save_scenario": "--save-scenario", "save_estimates": "--save-estimates",
                "save": "--save", "output": "--out", "plot": "--plot", "screenshot": "--screenshot"}


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
    try:  # a file made and removed: os.access says yes to root even where nothing can be created (/proc)
        fd, probe = tempfile.mkstemp(prefix=".zentrack-probe-", dir=target)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ValueError(f"{flag} {path}: {target} is not writable ({exc.strerror or exc})") from None


def check_outputs(args: argparse.Namespace) -> None:
    for dest, flag in OUTPUT_DIRS.items():
        if isinstance(getattr(args, dest, None), str):
            check_writable(getattr(args, dest), flag, folder=True)
    for dest, flag in OUTPUT_FILES.items():
        if isinstance(getattr(args, dest, None), str):
            check_writable(getattr(args, dest), flag, folder=False)


#: retired bench names that still work for one release, with a warning: a paper is "paper N", its bench ``paperN``
RETIRED_BENCHES = {f"paper00{i}": f"paper{i}" for i in range(5)}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) > 1 and argv[0] == "bench" and argv[1] in RETIRED_BENCHES:
        deprecated(f"bench {argv[1]}", f"bench {RETIRED_BENCHES[argv[1]]}")
        argv[1] = RETIRED_BENCHES[argv[1]]
    parser = build_parser(argv)
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
