"""``zentrack view PATH.rrd``: a saved or finished run served to a browser on this host until Ctrl-C.

The Rerun web server (:mod:`zentrack.viewer.server`, the real ``rerun`` binary in its own process group) with
the recording loaded, on 127.0.0.1 by default; the address is printed once it listens. A run's ``--viewer-serve``
serves only while the run lasts; this serves a run's ``<out>/recording.rrd`` for as long as it is wanted, and
on a machine without a display a browser opens it; ``--screenshot PATH.png`` saves what headless Chromium draws
instead (:mod:`zentrack.viewer.screenshot`) and exits.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from zentrack.common.argtypes import float_in
from zentrack.common.procs import StopFlag
from zentrack.viewer.hints import web_url
from zentrack.viewer.ports import GRPC_PORT, WEB_PORT, check_ports_free, port_number
from zentrack.viewer.screenshot import capture, chromium
from zentrack.viewer.server import start_web_server, stop_web_server, wait_listening

#: the first bytes of every Rerun recording file
RRD_MAGIC = (b"RRF2", b"RRF0", b"RRIO")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="PATH.rrd", help="the recording to serve (a run's <out>/recording.rrd)")
    p.add_argument("--bind", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this host only)")
    p.add_argument("--web-port", type=port_number, default=WEB_PORT, help=f"web viewer port (default {WEB_PORT})")
    p.add_argument("--grpc-port", type=port_number, default=GRPC_PORT, help=f"gRPC port (default {GRPC_PORT})")
    p.add_argument("--screenshot", metavar="PATH.png",
                   help="instead of serving until Ctrl-C: save the viewer as headless Chromium draws it, then exit "
                        "(1 if it had not drawn within --screenshot-timeout)")
    p.add_argument("--screenshot-timeout", type=float_in(5.0, 3600.0, "seconds"), default=120.0, metavar="S",
                   help="seconds to wait for the viewer to draw (default 120)")


def check_recording(path: Path) -> None:
    """ValueError naming the file when it is missing, not a file, or not a Rerun recording."""
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    if not path.is_file():
        raise ValueError(f"{path}: not a file (a run writes <out>/recording.rrd with --viewer)")
    with path.open("rb") as f:
        head = f.read(4)
    if head not in RRD_MAGIC:
        raise ValueError(f"{path}: not a Rerun recording (.rrd)")


def run(args: argparse.Namespace) -> int:
    path = Path(args.recording)
    check_recording(path)
    if args.web_port == args.grpc_port:
        raise ValueError(f"--web-port and --grpc-port must differ, both are {args.web_port}")
    if args.screenshot and chromium() is None:  # what the user asked for, before what the host holds
        raise ValueError("--screenshot needs Chromium (chromium or chromium-browser on PATH)")
    check_ports_free({args.web_port: "--web-port", args.grpc_port: "--grpc-port"}, args.bind)
    stop = StopFlag()  # Ctrl-C or SIGTERM: stop serving, stop the server, exit 0
    server = start_web_server(args, recordings=(str(path.resolve()),))
    try:
        wait_listening(server, args.bind, [args.grpc_port, args.web_port], stop=stop)
        url = web_url(args.bind, args.web_port, args.grpc_port)
        if args.screenshot:
            shot = Path(args.screenshot)
            if not capture(url, shot, timeout_s=args.screenshot_timeout):
                print(f"view: the viewer had not drawn {path} within {args.screenshot_timeout:g} s; the last capture "
                      f"is in {shot}", file=sys.stderr)
                return 1
            print(f"view: {shot} (the viewer drawing {path})")
            return 0
        print(f"view: serving {path} at {url} (Ctrl-C to stop)", flush=True)
        while not stop and server.poll() is None:
            time.sleep(0.2)
        if server.poll() is not None and not stop:
            raise ValueError(f"the Rerun web server exited with status {server.returncode} while serving {path}")
    finally:
        stop_web_server(server)
    return 0
