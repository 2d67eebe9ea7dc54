"""Screenshot a page in headless Chromium over the DevTools protocol (test helper, loopback only)."""
from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import websocket  # websocket-client

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=1600,1000",
]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshot(url: str, out: Path, wait_s: float = 15.0, timeout_s: float = 60.0) -> bytes:
    """Open ``url``, wait ``wait_s`` for it to render, write a PNG to ``out`` and return its bytes."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("chromium is not installed")
    port = _free_port()
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--remote-debugging-port={port}",
                                 "--remote-debugging-address=127.0.0.1", f"--user-data-dir={profile}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            end = time.time() + timeout_s
            targets = None
            while time.time() < end:
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                        targets = [t for t in json.load(r) if t.get("type") == "page"]
                    if targets:
                        break
                except OSError:
                    pass
                time.sleep(0.3)
            if not targets:
                raise RuntimeError("chromium's DevTools endpoint did not come up")
            ws = websocket.create_connection(targets[0]["webSocketDebuggerUrl"], timeout=timeout_s)
            ids = iter(range(1, 10**6))

            def call(method: str, **params):
                msg_id = next(ids)
                ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
                while True:
                    reply = json.loads(ws.recv())
                    if reply.get("id") == msg_id:
                        if "error" in reply:
                            raise RuntimeError(f"{method}: {reply['error']}")
                        return reply.get("result", {})

            call("Page.enable")
            call("Emulation.setDeviceMetricsOverride", width=1600, height=1000, deviceScaleFactor=1, mobile=False)
            call("Page.navigate", url=url)
            time.sleep(wait_s)
            png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
            ws.close()
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(png)
    return png


def png_pixels(png: bytes):
    """RGB pixels of a PNG as a numpy array."""
    import io

    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
