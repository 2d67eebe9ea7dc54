"""``zentrack viewer``: subscribes to a run and streams it to Rerun (file, web viewer or native viewer).

What is drawn: :mod:`zentrack.viewer.entities` (the scene) and :mod:`zentrack.viewer.metrics` (the time
series); how the screen is laid out, framed on the target: :mod:`zentrack.viewer.layout`. A many-target run
(a ``[targets]`` scenario) is drawn by :mod:`zentrack.viewer.multitarget_view`: tracks, trails, the truth, GOSPA.

Sinks: ``--save PATH.rrd`` (with ``write_footer=False`` so a crash or Ctrl-C still leaves a readable file up to
the last flush), ``--serve`` (a ``rerun --serve-web`` child bound to ``--bind``, 127.0.0.1 by default:
:mod:`zentrack.viewer.server`), and ``--spawn`` (native viewer; needs a display). Memory stays flat: chunks
are flushed on a timer and the file sink keeps no footer index.
"""
from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

import rerun as rr

from zentrack.common.procs import StopFlag, freeze_heap, setup_logging
from zentrack.config.run_setup import resolve_setup
from zentrack.transport.zsession import open_session, zenoh_config
from zentrack.viewer.entities import Viewer
from zentrack.viewer.hints import live_line, recording_line, web_url
from zentrack.viewer.layout import blueprint, describe, multitarget_blueprint, targets_region
from zentrack.viewer.map_view import region_zoom
from zentrack.viewer.metrics import round_message_dims
from zentrack.viewer.multitarget_view import MultiTargetViewer
from zentrack.viewer.ports import check_ports_free
from zentrack.viewer.server import start_web_server, stop_web_server, wait_listening

log = logging.getLogger("zentrack.viewer")


def run(args: argparse.Namespace) -> int:
    setup_logging()
    if not (args.save or args.serve or args.spawn):
        raise ValueError("choose at least one sink: --save PATH.rrd, --serve or --spawn")
    if args.save and not args.save.endswith(".rrd"):
        raise ValueError(f"--save: {args.save} must end in .rrd")
    if not args.flush_s > 0:
        raise ValueError(f"--flush-s must be positive, got {args.flush_s}")
    setup = resolve_setup(args)
    zenoh_config(args, "viewer")  # every flag and file is checked before anything starts
    if args.serve:
        if args.web_port == args.grpc_port:
            raise ValueError(f"--web-port and --grpc-port must differ, both are {args.web_port}")
        check_ports_free({args.web_port: "--web-port", args.grpc_port: "--grpc-port"}, args.bind)
    if args.nice > 0:
        os.nice(args.nice)
    stop = StopFlag()  # SIGTERM from here on ends the loops below and runs every finally
    server = None
    try:
        if args.serve:
            server = start_web_server(args)
            wait_listening(server, args.bind, [args.grpc_port, args.web_port], stop=stop)
        with open_session(args, "viewer") as (session, keys):
            if not stop:
                serve(args, setup, session, keys, stop)
    finally:
        if server is not None:
            stop_web_server(server)
    return 0


def serve(args: argparse.Namespace, setup, session, keys, stop: StopFlag) -> None:
    """Set up the Rerun sinks and log the run until it stops."""
    batcher = rr.ChunkBatcherConfig(flush_tick=args.flush_s, flush_num_bytes=4 * 1024 * 1024, flush_num_rows=2**20)
    rec = rr.RecordingStream("zentrack", recording_id=f"zentrack-{args.run}", batcher_config=batcher)
    sinks: list[rr.GrpcSink | rr.FileSink] = []
    if args.spawn:
        rec.spawn(connect=False)
        sinks.append(rr.GrpcSink())
    if args.save:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(args.save, write_footer=False))
        log.info(recording_line(args.save))
    if args.serve:
        sinks.append(rr.GrpcSink(f"rerun+http://{args.bind}:{args.grpc_port}/proxy"))
        log.info(live_line(web_url(args.bind, args.web_port, args.grpc_port)))
    try:
        if setup.multitarget is not None:
            serve_multitarget(args, setup, session, keys, stop, rec, sinks)
            return
        scene = describe(setup.scenario, rounds=round_message_dims(setup) is not None)
        layout = blueprint(scene)
        rec.set_sinks(*sinks, default_blueprint=layout)
        rec.send_blueprint(layout)
        viewer = Viewer(session, keys, setup, rec, scene, args.flush_s)
        freeze_heap()
        log.info("viewer: run %s, %d nodes, %s scenario (target view %.0f m across), sinks %s", keys.run,
                 setup.scenario.nodes, scene.family, 2 * scene.scale,
                 [s for s, on in (("file", args.save), ("web", args.serve), ("spawn", args.spawn)) if on])
        try:
            viewer.run(stop, None)
            if args.serve and args.linger > 0:
                viewer.run(stop, args.linger)
        finally:
            viewer.close()
            log.info("viewer: logged %s", viewer.logged)
    finally:
        rec.flush()
        rec.disconnect()


def serve_multitarget(args: argparse.Namespace, setup, session, keys, stop: StopFlag, rec: rr.RecordingStream,
                      sinks: list) -> None:
    """Log a many-target run to ``sinks`` until it stops (its layout framed on the targets' region; a recorded
    truth's map, :mod:`zentrack.viewer.map_view`, zoomed to its targets and sensors)."""
    data = setup.multitarget_data
    layout = multitarget_blueprint(data.nodes, targets_region(data.truth), int(data.alive.sum(axis=1).max()),
                                   region_zoom(data))
    rec.set_sinks(*sinks, default_blueprint=layout)
    rec.send_blueprint(layout)
    viewer = MultiTargetViewer(session, keys, data, rec, args.flush_s)
    freeze_heap()
    log.info("viewer: run %s, %d nodes, many-target scenario (%d targets over the run)", keys.run, data.nodes,
             int(data.alive.any(axis=0).sum()))
    try:
        viewer.run(stop, None)
        if args.serve and args.linger > 0:
            viewer.run(stop, args.linger)
    finally:
        viewer.close()
        log.info("viewer: logged %s", viewer.logged)
