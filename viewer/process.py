"""``zentrack viewer``: subscribes to a run and streams it to Rerun (file, web viewer or native viewer).

What is drawn: the viewer core (:mod:`zentrack.viewer.core`: subscriptions, the loop, events) drives one payload
part, :mod:`zentrack.viewer.single_target` (the scene; time series: :mod:`zentrack.viewer.metrics`; layout, framed
on the target: :mod:`zentrack.viewer.single_target_layout`) or, for a many-target run (a ``[targets]`` scenario),
:mod:`zentrack.viewer.multi_target` (tracks, trails, the truth, GOSPA; :mod:`zentrack.viewer.multi_target_layout`).

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
from zentrack.config.run_setup import RunSetup, resolve_setup
from zentrack.transport.keys import Keys
from zentrack.transport.zsession import open_session, zenoh_config
from zentrack.viewer.core import Viewer
from zentrack.viewer.hints import live_line, recording_line, web_url
from zentrack.viewer.multi_target import multi_target
from zentrack.viewer.ports import check_ports_free
from zentrack.viewer.server import start_web_server, stop_web_server, wait_listening
from zentrack.viewer.single_target import single_target

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


def serve(args: argparse.Namespace, setup: RunSetup, session, keys: Keys, stop: StopFlag) -> None:
    """Set up the Rerun sinks and log the run until it stops: a many-target run (a ``[targets]`` scenario) through
    :func:`~zentrack.viewer.multi_target.multi_target`, any other through
    :func:`~zentrack.viewer.single_target.single_target`."""
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
        canvas, payload = (single_target(setup, rec) if setup.multitarget is None
                           else multi_target(setup.multitarget_data, rec, setup.sensor_timing))
        layout = payload.blueprint()
        rec.set_sinks(*sinks, default_blueprint=layout)
        rec.send_blueprint(layout)
        viewer = Viewer(session, keys, canvas, payload, args.flush_s)
        freeze_heap()
        log.info("viewer: run %s, %s, sinks %s", keys.run, payload.summary(),
                 [s for s, on in (("file", args.save), ("web", args.serve), ("spawn", args.spawn)) if on])
        try:
            viewer.run(stop, None)
            if args.serve and args.linger > 0:
                viewer.run(stop, args.linger)
        finally:
            viewer.close()
            log.info("viewer: logged %s", canvas.logged)
    finally:
        rec.flush()
        rec.disconnect()
