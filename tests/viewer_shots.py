"""Screenshots of the viewer for the documentation: one per scenario family (``docs/images/viewer-<family>.png``),
``viewer-async.png`` of sensors of their own and ``viewer-exp2.png`` for the README. Each is a short lockstep
``zentrack run --viewer`` (realtime for sensors of their own, which run on the wall clock only), its recording served
by the real ``rerun`` binary and captured in headless Chromium (:mod:`webshot`) once the target view shows the
truth and every node's colour. Run from the repository: ``python tests/viewer_shots.py [NAME ...]``.
"""
from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import webshot

from zentrack.common.ports import free_port

ROOT = Path(__file__).resolve().parent.parent
#: image name -> (scenario, steps)
SHOTS = {"exp2": ("exp2", 200), "bearings": ("exp2-irregular", 200), "clutter": ("fpf-clutter", 60),
         "extended": ("eot-s2", 40), "satellites": ("seckf-constellation", 60), "uav": ("dce-ici", 40),
         "ais-nyharbor": ("ais-nyharbor", 80), "adsb-paris": ("adsb-paris", 120), "async": ("exp2-async", 200)}
#: scenarios that run in realtime only (sensors of their own)
REALTIME = {"exp2-async"}
MAX_BYTES = 300_000


def target_view_ready(nodes: int, min_s: float):
    """The target view (left 3/5) shows the white truth and every node's colour, ``min_s`` after the start."""
    from zentrack.viewer.layout import node_color

    t0 = time.time()

    def ready(png: bytes) -> bool:
        view = webshot.png_pixels(png).astype(int)[60:-40, : 1600 * 3 // 5]
        seen = [int((np.abs(view - node_color(i, nodes)).max(axis=2) <= 40).sum()) for i in range(nodes)]
        return time.time() - t0 > min_s and (view.min(axis=2) >= 235).sum() > 30 and min(seen) >= 15

    return ready


def shoot(name: str, scenario: str, steps: int, min_s: float = 60.0) -> Path:
    from zentrack.viewer.server import rerun_binary

    out = ROOT / "docs" / "images" / f"viewer-{name}.png"
    with tempfile.TemporaryDirectory(prefix="viewer-shot-") as tmp:
        run = Path(tmp) / "run"
        timing = [] if scenario in REALTIME else ["--timing", "lockstep"]
        subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario", scenario, "--steps", str(steps), *timing,
                        "--viewer", "--out", str(run)], check=True, stdout=subprocess.DEVNULL)
        web, grpc = free_port(), free_port()
        server = subprocess.Popen([rerun_binary(), "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc),
                                   "--web-viewer-port", str(web), str(run / "recording.rrd")],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            nodes = _nodes(run)
            from zentrack.viewer.hints import web_url

            url = web_url("127.0.0.1", web, grpc)
            png = webshot.screenshot(url, Path(tmp) / "shot.png", ready=target_view_ready(nodes, min_s),
                                     timeout_s=min_s + 180.0, interval_s=3.0)
        finally:
            os.killpg(server.pid, signal.SIGTERM)
            server.wait(timeout=10)
    save_small(png, out)
    return out


def _nodes(run: Path) -> int:
    import json

    return len(json.loads((run / "summary.json").read_text())["nodes"])


def save_small(png: bytes, out: Path) -> None:
    """Write ``png`` to ``out``, quantised to fewer colours when it is larger than :data:`MAX_BYTES`."""
    from PIL import Image

    out.parent.mkdir(parents=True, exist_ok=True)
    image = Image.open(io.BytesIO(png)).convert("RGB")
    image.save(out, optimize=True)
    for colours in (256, 128, 64):
        if out.stat().st_size <= MAX_BYTES:
            return
        image.quantize(colors=colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(out, optimize=True)


if __name__ == "__main__":
    for key in sys.argv[1:] or list(SHOTS):
        print(f"{key}: {shoot(key, *SHOTS[key])}")
