"""``zentrack soak``: a realtime cluster under a seeded schedule of faults, judged against a fault-free run.

Faults: SIGKILL of a tracker followed by a restart (``--kill-every``), a ``--fault-s`` long SIGSTOP freeze
(``--freeze-every``), a ``--fault-s`` long link cut (``--cut-every``; the cluster then runs in network
namespaces, one per service, see ``zentrack netns``), a truth stall (SIGSTOP of the truth process for a
seeded 0.5-3 s, ``--truth-stall-every``), a truth kill and restart (``--truth-kill-every``) and a router kill
and restart (``--router-every``; router mode: ``--router``, or namespaces, which always run a router); with
sensors of their own (``[sensor_timing]``, loopback only) a sensor's kill and restart (``--sensor-kill-every``) and
a step back of a sensor's clock that stays (``--clock-jump-every``, ``--clock-jump-s``; each tracker's detections
kept and refused: ``zentrack.cluster.soak.sensor_counts``). The same scenario and seed then run without faults. ``--engine compose`` runs both as docker compose projects on
a Docker engine instead (faults become ``docker kill``/``start``, ``pause``/``unpause`` and ``network
disconnect``/``connect``; see ``zentrack.cluster.soak.compose_backend``), judged by the same criteria;
``--engine stack`` as a Docker Swarm stack (``zentrack.cluster.soak.stack_backend``: swarm itself restarts a
killed task in its slot), where ``--drain-every`` drains the swarm worker holding the most trackers for
``--drain-s`` and swarm moves them (``zentrack.cluster.engines.swarm``; each moved tracker judged like a killed
one).
Outputs in ``--out``: ``report.json`` (figures and pass/fail per criterion), ``error.png`` and ``error.svg``
(position error of every tracker over time, every fault a span from its start to its undo:
``zentrack.cluster.soak.plot``), ``summary.json`` and ``recording.rrd`` of the faulty run, ``reference/`` for the
fault-free run. Each criterion is printed with its figures (a failure: which node, how many steps, the limit),
then a line naming the outputs; exit status 1 when a criterion fails.

The scenario (default ``patrol``: a target that stays inside the sensors' field for any duration) is simulated
first: a target that leaves the field before the end is refused in one line (``zentrack.cluster.soak.accuracy``;
``--unobserved`` runs it and reports how far the fault-free error grows).

Criteria (``zentrack.cluster.soak.criteria``): surviving trackers never crash or publish NaN; every tracker's
position RMSE <= 1.25x its fault-free RMSE; once a restarted tracker publishes again, its error is within 2x the
network median in <= 20 steps (``restarted_error_near_median``); after every fault ends, every live tracker
publishes estimates again within 20 steps (``publishing_after_fault``); in each fault's window the affected
trackers' and the network's error stay within the fault kind's limits of the reference's at the same steps
(``accuracy_per_fault``); RSS of every long-lived process grows
< 10 % between minute 2 (or mid-run for short soaks) and the end; summary and recording complete; nothing left
running. The report also explains every deadline miss of both runs (``zentrack.cluster.soak.misses``) and holds
the RSS and CPU of each process type per minute (``zentrack.cluster.soak.usage``). The fault schedule:
``zentrack.cluster.soak.faults``; where the cluster runs: ``zentrack.cluster.soak.backends``; each run driven to its
end, its faults applied: ``zentrack.cluster.soak.drive``. On a terminal a progress line counts each run's seconds.

A loaded host: ``--cpu-hog N`` runs both runs beside N busy loops (``zentrack.cluster.soak.cpu_hog``); the
trackers, the truth and the router run at ``--realtime-nice`` (``zentrack.cluster.soak.priority``) and every
process starts lean (``zentrack.cluster.soak.lean_start``), so that a restarted tracker gets the CPU to start
(docs/networks.md).
"""
from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

from zentrack.cluster.deployment.certs import add_secure_argument, certificate_folder, make_certificates, run_roles
from zentrack.cluster.engines.docker import check_image
from zentrack.cluster.engines.swarm import swarm_nodes_or_none
from zentrack.cluster.soak.accuracy import check_field, error_growth, window_table
from zentrack.cluster.soak.backends import LoopbackBackend, NetnsBackend, beside
from zentrack.cluster.soak.compose_backend import ComposeBackend
from zentrack.cluster.soak.cpu_hog import MAX_HOGS, CpuHog
from zentrack.cluster.soak.criteria import drains_applied, evaluate, failed, passed, position_errors, verdict_lines
from zentrack.cluster.soak.drive import run_one
from zentrack.cluster.soak.fault_kinds import (
    DRAIN_S,
    SENSOR,
    TRACKER,
    Fault,
    asked,
    has_verbs,
    registered,
    sensor_of,
    unsupported,
)
from zentrack.cluster.soak.faults import no_fault_message, plan_lines, schedule
from zentrack.cluster.soak.lean_start import prepare as prepare_lean_start
from zentrack.cluster.soak.misses import miss_lines, miss_report
from zentrack.cluster.soak.plot import write_error_plot
from zentrack.cluster.soak.priority import REALTIME_NICE, Prioritizer
from zentrack.cluster.soak.rejudge import rejudge
from zentrack.cluster.soak.sensor_counts import clocks_followed, sensor_lines, sensor_report, tracker_counts
from zentrack.cluster.soak.stack_backend import StackBackend
from zentrack.cluster.soak.summary import fault_lines, write_summary_figures
from zentrack.cluster.soak.usage import usage_by_type
from zentrack.common.argtypes import float_in, int_in, nodes_int, off_or_float_in, seed_int
from zentrack.common.procs import setup_logging
from zentrack.common.progress import outputs_line
from zentrack.common.report import write_json
from zentrack.config import catalogue
from zentrack.config.run_setup import RunSetup, scenario_setup
from zentrack.config.scenario_config import load_scenario_config
from zentrack.transport.zsession import build_config
from zentrack.truth.sensor import CLOCK_JUMP_S

log = logging.getLogger("zentrack.soak")

#: the longest soak run (s), and every fault period: 0 (off) or 1 s to that (a period of 1e-7 s or NaN would
#: never finish drawing the schedule)
MAX_SOAK_S = 86400.0
#: the soak's default scenario: a target that stays inside the sensors' field however long the run (issue 36)
SOAK_SCENARIO = "patrol"
fault_period = off_or_float_in(1.0, MAX_SOAK_S, "fault_period")
#: each ``--engine`` and its backend: the faults an engine can apply are those whose verbs its backend has
ENGINES: dict[str, type] = {b.ENGINE: b for b in (LoopbackBackend, NetnsBackend, ComposeBackend, StackBackend)}


def advanced_flags() -> tuple[str, ...]:
    """The fault flags ``--help`` leaves to ``--help-all`` (the registry's advanced kinds; ``zentrack.cli``), and
    the size of a sensor's clock jump."""
    return (*(f.flag for f in registered() if f.advanced), "--clock-jump-s")


def sensors_of(setup: RunSetup) -> tuple[dict[int, float], dict[int, list[int]], dict[int, float]]:
    """A run's sensors of their own (``[sensor_timing]``): each one's rate (Hz), the trackers that take it and its
    configured clock offset (s); all empty when the truth measures."""
    timing = setup.sensor_timing
    if timing is None:
        return {}, {}, {}
    takers = {s: [i for i, took in enumerate(timing.takes) if s in took] for s in range(timing.sensors)}
    return ({s: float(spec.rate_hz) for s, spec in enumerate(timing.streams)}, takers,
            {s: float(spec.offset_s) for s, spec in enumerate(timing.streams)})


def sensor_faults_refused(faults: list[Fault], setup: RunSetup, scenario: str) -> str | None:
    """The line that refuses a sensor fault for a scenario whose truth measures (no sensors of their own), or
    None."""
    asked_for = [f for f in faults if f.target == SENSOR]
    if not asked_for or setup.sensor_timing is not None:
        return None
    return (f"{asked_for[0].flag}: scenario {scenario} has no sensors of their own (no [sensor_timing] section: its "
            "truth measures for every tracker), so there is no sensor process to fault; choose one that has (exp2-async)")


def _add_fault_flag(p: argparse.ArgumentParser, fault: Fault) -> None:
    p.add_argument(fault.flag, type=fault_period, default=fault.default_every, help=fault.help)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float_in(10.0, MAX_SOAK_S, "duration"), default=600.0,
                   help=f"seconds of each run, 10 to {MAX_SOAK_S:g} (default 600)")
    p.add_argument("--nodes", type=nodes_int, help="trackers (default: the scenario's, 10 for patrol; ring layouts only)")
    p.add_argument("--scenario", default=SOAK_SCENARIO, metavar="NAME|PATH", type=catalogue.scenario_arg,
                   help=catalogue.help_text(SOAK_SCENARIO) + "; a target that leaves the sensors' field before the "
                        "end is refused (--unobserved); its filter, fusion rule and sample period are used, --duration "
                        "sets the steps")
    for fault in registered():  # each kind's period: the tracker faults', then their lengths, then the services'
        if fault.target == TRACKER:
            _add_fault_flag(p, fault)
    p.add_argument("--fault-s", type=float_in(0.1, 3600.0, "fault_s"), default=5.0,
                   help="length of a freeze or cut, 0.1 to 3600 s (default 5)")
    p.add_argument("--restart-after", type=float_in(0.0, 3600.0, "restart_after"), default=2.0,
                   help="seconds between a kill and the restart, 0 to 3600 (default 2)")
    p.add_argument("--clock-jump-s", type=float_in(0.1, 3600.0, "clock_jump_s"), default=CLOCK_JUMP_S,
                   help=f"how far back a sensor's clock steps at each --clock-jump-every, 0.1 to 3600 s (default "
                        f"{CLOCK_JUMP_S:g}: beyond a tracker's 10 s stale limit, so each jumped detection is refused "
                        "as stale until the tracker follows)")
    for fault in registered():
        if fault.target != TRACKER:
            _add_fault_flag(p, fault)
    p.add_argument("--drain-s", type=float_in(1.0, 3600.0, "drain_s"), default=DRAIN_S,
                   help=f"how long a drained node stays out of service, 1 to 3600 s (default {DRAIN_S:g}: longer than "
                        "swarm takes to start its trackers elsewhere)")
    p.add_argument("--router", action="store_true", help="loopback runs: every process connects through a router")
    add_secure_argument(p, "or without it made in <out>/certs; loopback runs only (implies --router)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 file for every process of both runs, merged over zentrack's safe defaults "
                        "(mounted into the services with the netns and compose engines)")
    p.add_argument("--engine", choices=("auto", "loopback", "netns", "compose", "stack"), default="auto",
                   help="where the cluster runs: processes on loopback, network namespaces (root), or docker "
                        "compose on a Docker engine (containers; kills, pauses and network disconnects), or a "
                        "Docker Swarm stack (task kills that swarm restarts, pauses; docs/swarm.md); "
                        "default auto: namespaces when --cut-every > 0, else loopback")
    p.add_argument("--image", default="zentrack:latest", help="--engine compose|stack: the image to run (built before)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the scenario and of the fault schedule")
    p.add_argument("--cpu-hog", type=int_in(0, MAX_HOGS, "processes"), default=0, metavar="N",
                   help="run both runs beside N busy-loop processes at normal priority (a loaded host on purpose: "
                        "2 keep 2 cores busy); stopped with the soak, reported in report.json (default 0: none)")
    p.add_argument("--realtime-nice", type=int_in(-20, 0, "nice"), default=REALTIME_NICE, metavar="N",
                   help=f"the nice value of the trackers, the truth and the router in both runs, -20 to 0 (default {REALTIME_NICE}: above "
                        "ordinary work, so that a restarted tracker gets the CPU to start on a loaded host; needs "
                        "root or CAP_SYS_NICE, else reported and left; 0: unchanged)")
    p.add_argument("--unobserved", action="store_true",
                   help="run a scenario whose target leaves the sensors' field before the end (refused otherwise), "
                        "and report how far the fault-free run's error grows")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--rejudge", action="store_true",
                   help="run nothing: judge the soak saved in --out again by the current accuracy-per-fault rule "
                        "(report.json updated, figure redrawn; zentrack.cluster.soak.rejudge)")
    p.add_argument("--plan", action="store_true",
                   help="start nothing: check the flags and print the fault schedule this soak would apply")


def auto_engine(faults: list[Fault]) -> str:
    """``--engine auto``: namespaces when a fault asked for needs a verb that loopback processes lack and
    namespaces have (a link cut), else loopback."""
    needs_netns = any(not has_verbs(LoopbackBackend, f) and has_verbs(NetnsBackend, f) for f in faults)
    return "netns" if needs_netns else "loopback"


def soak_setup(args: argparse.Namespace) -> RunSetup:
    """The soaked run: ``--scenario`` (its filter, fusion rule and sample period) in realtime, ``--duration``
    seconds long, with ``--nodes`` trackers (ring layouts only; default: the scenario's) and ``--seed``."""
    ts = load_scenario_config(args.scenario, multitarget=True).ts
    steps = max(1, int(round(args.duration / ts)))
    setup = scenario_setup(args.scenario, nodes=args.nodes, steps=steps, seed=args.seed, timing_mode="realtime")
    setup.source = "soak"
    return setup


def run(args: argparse.Namespace) -> int:
    setup_logging()
    out = Path(args.out)
    if getattr(args, "rejudge", False):
        return rejudge(out, args.scenario)
    setup = soak_setup(args)
    scn = setup.run_data  # one target's run, or many targets' (then the errors are GOSPA)
    field = check_field(scn, getattr(args, "unobserved", False))  # before anything starts: one line, exit 2
    args.nodes = scn.nodes  # the fault schedule picks among the scenario's trackers
    args.sensor_rates, args.sensor_takers, configured = sensors_of(setup)  # ... and its sensors of their own
    faults = asked(args)
    refused = sensor_faults_refused(faults, setup, args.scenario)
    if refused:
        raise ValueError(refused)
    engine = args.engine if args.engine != "auto" else auto_engine(faults)
    # the flags and files given: checked before anything is made or started (one line, exit 2)
    lacking = unsupported(faults, engine, ENGINES)  # a fault whose verbs the engine's backend lacks
    if lacking:
        raise ValueError(lacking)
    if args.secure is not None and engine != "loopback":
        raise ValueError("--secure: the secure soak runs on the loopback engine (--cut-every 0, no --engine netns/compose)")
    sensors = len(setup.sensor_streams())  # sensors of their own: one certificate each
    roles = run_roles(scn.nodes, sensors, ("router", "truth", "recorder"))
    secure = certificate_folder(args.secure, out / "certs", roles)  # a given folder lacking one: exit 2 now
    if secure is not None:
        args.router = True
    for fault in faults:
        if fault.target == "router" and engine == "loopback" and not args.router:
            raise ValueError(f"{fault.flag} needs a router: pass --router (or --engine netns or compose)")
    zenoh_file = None
    if args.zenoh_config:
        zenoh_file = str(Path(args.zenoh_config).resolve())
        build_config("peer", file=zenoh_file)  # a bad file is one clear error before anything starts
    events = schedule(args)
    if not events:  # nothing to judge the network's recovery by: refused before anything starts
        raise ValueError(no_fault_message(args))
    if getattr(args, "plan", False):  # what this soak would do, and nothing started or written
        for line in plan_lines(events, args, engine):
            print(line)
        return 0
    # what this host must have: root for namespaces, a swarm worker to drain, the image
    if engine == "netns" and os.geteuid() != 0:
        raise ValueError("network namespaces need root: run as root, or pass --cut-every 0 (or --engine compose)")
    if args.drain_every > 0 and not any(n.role == "worker" and n.status == "ready" for n in swarm_nodes_or_none()):
        raise ValueError("--drain-every: this engine leads no swarm with a ready worker to drain "
                         "(bash deploy/swarm-nodes.sh up --workers 1 --image IMAGE makes one in namespaces)")
    if engine in ("compose", "stack"):
        check_image(args.image)
    out.mkdir(parents=True, exist_ok=True)
    if secure is not None and args.secure == "":  # --secure without a folder: this soak's own certificates
        make_certificates(secure, scn.nodes, sensors=sensors)
    results, runs, leftovers = {}, [], []
    lean_start = prepare_lean_start()  # what a restarted tracker spends starting (docs/networks.md, loaded hosts)
    hog = CpuHog(getattr(args, "cpu_hog", 0))
    hog.start()  # both runs beside it: the reference is judged on the same loaded host
    for label, evts, folder in (("faulty", events, out), ("reference", [], out / "reference")):
        folder.mkdir(parents=True, exist_ok=True)
        tag = "s" if label == "faulty" else "r"
        backend: LoopbackBackend | NetnsBackend | ComposeBackend | StackBackend
        if engine == "stack":
            backend = StackBackend(setup, folder, tag, args.image, args.seed, args.scenario)
            backend.plan_drains(evts)
        elif engine == "compose":
            backend = ComposeBackend(setup, folder, tag, args.image, args.seed, args.scenario,
                                     zenoh_config=beside(zenoh_file, folder))
        elif engine == "netns":
            backend = NetnsBackend(setup, folder, viewer=label == "faulty", tag=tag, scenario=args.scenario,
                                   seed=args.seed, zenoh_config=zenoh_file)
        else:
            backend = LoopbackBackend(setup, folder, viewer=label == "faulty", router=args.router, secure=secure,
                                      zenoh_config=zenoh_file, clock_jump_s=args.clock_jump_s)
        log.info("soak: %s run, %d trackers, %.0f s, %d fault events, %s", label, args.nodes, args.duration,
                 len(evts), engine)
        try:
            results[label] = run_one(backend, evts, args.duration, Prioritizer(getattr(args, "realtime_nice", 0)),
                                     label=f"soak, {label} run")
        except BaseException:
            hog.stop()
            raise
        finally:
            backend.stop()
        if isinstance(backend, (ComposeBackend, StackBackend)):
            runs.append(backend.run)
            leftovers += backend.leftovers()
        else:
            runs.append("compose" if isinstance(backend, NetnsBackend) else backend.cluster.run_name)
        results[label]["drains"] = getattr(backend, "drains", [])
        for f in results[label]["faults"]:  # a sensor fault hits the trackers that take the sensor
            if sensor_of(f["node"]) is not None:
                f["trackers"] = args.sensor_takers.get(sensor_of(f["node"]), [])
        if args.sensor_takers:  # each tracker's detections, kept and refused (the trackers wrote their reports)
            reports = backend.node_reports() if isinstance(backend, LoopbackBackend) else {}
            results[label]["sensor_counts"] = tracker_counts(results[label]["recorder"], reports)
        write_json(folder / "summary.json", results[label]["recorder"].summary())
        results[label]["recorder"].save_estimates(folder / ("tracks.npz" if setup.multitarget else "estimates.npz"))
    hog_report = hog.stop()
    report = evaluate(results["faulty"], results["reference"], args.duration, runs, leftovers)
    report.update({"scenario": args.scenario, "ts": scn.ts, "duration_s": args.duration, "nodes": args.nodes, "seed": args.seed, "secure": args.secure is not None,
                   "mode": {"netns": "namespaces"}.get(engine, engine), "faults": results["faulty"]["faults"], "schedule": events,
                   "rss": results["faulty"]["rss"], "cpu_hog": hog_report,
                   "drains": results["faulty"]["drains"],
                   "lean_start": lean_start, "priority": {k: results[k]["priority"] for k in results}, "field": field})
    if args.sensor_takers:
        report["sensors"] = sensor_report(results["faulty"]["faults"], results["faulty"]["sensor_counts"],
                                          results["reference"]["sensor_counts"], args.sensor_takers, configured,
                                          args.clock_jump_s)
        if any(e["clock_jumps_at_s"] for e in report["sensors"]["sensors"].values()):
            report["criteria"]["sensor_clocks_followed"] = clocks_followed(report["sensors"])
    report["usage"] = {k: usage_by_type(results[k]["rss"], results[k].get("cpu", {})) for k in results}
    report["misses"] = {"faulty": miss_report(report["summary"]), "reference": miss_report(report["reference_summary"])}
    if field is not None and field["first_step_out"] is not None:  # --unobserved: how far the error grows
        report["reference_error_growth"] = error_growth(position_errors(results["reference"]["recorder"]), scn.ts)
    rrd = out / "recording.rrd"
    report["criteria"]["outputs_complete"]["recording_bytes"] = rrd.stat().st_size if rrd.exists() else 0
    if not rrd.exists():
        report["criteria"]["outputs_complete"]["pass"] = False
    if args.drain_every > 0:
        report["criteria"]["drains_applied"] = drains_applied(report["drains"])
    report["pass"] = verdict = passed(report["criteria"])
    figures = write_error_plot(position_errors(results["faulty"]["recorder"]), results["faulty"]["faults"], scn.ts,
                               out / "error.png", f"soak of {args.scenario}, seed {args.seed}"
                               + (" (error: GOSPA of the confirmed tracks)" if setup.multitarget else ""),
                               reference=position_errors(results["reference"]["recorder"]),
                               accuracy=report["criteria"]["accuracy_per_fault"]["windows"])
    summary_figures = write_summary_figures(report, report["criteria"]["accuracy_per_fault"]["windows"], out,
                                            f"soak of {args.scenario}")
    write_json(out / "report.json", report)
    for line in verdict_lines(report["criteria"]):
        print(line)
    for line in window_table(report["criteria"]["accuracy_per_fault"]):
        print(line)
    for line in [*fault_lines(report), *(sensor_lines(report["sensors"]) if "sensors" in report else []),
                 *miss_lines(report["misses"]["reference"], "the fault-free reference run")]:
        print(line)
    if field is not None and "reference_error_growth" in report:
        g = report["reference_error_growth"]
        print(f"the target leaves the sensors' field at step {field['first_step_out']}: without faults the network "
              f"median error grows from {g['first_m']:.1f} m (first {g['window_s']:.0f} s) to {g['last_m']:.1f} m (last "
              f"{g['window_s']:.0f} s), {g['growth']:.1f}x")
    print(outputs_line("soak passed" if verdict else f"soak FAILED ({', '.join(failed(report['criteria']))})", report=out / "report.json", error_plot=figures,
                       **summary_figures, recording=rrd if rrd.exists() else None))
    return 0 if verdict else 1
