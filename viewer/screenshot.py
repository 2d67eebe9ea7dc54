"""``zentrack view PATH.rrd --screenshot OUT.png``: the served recording drawn by the web viewer in headless
Chromium and saved, on a machine without a display.

Chromium's one-shot ``--screenshot`` captures the viewer's loading page (the viewer is WebAssembly that draws
after the page has loaded), so the page is driven over the Chrome DevTools protocol on a pipe
(``--remote-debugging-pipe``: JSON messages ended by a NUL byte, commands on the child's fd 3, replies on its
fd 4; no socket, no extra package) and captured every ``interval_s`` until the viewer has drawn: enough bright
pixels (text, the truth, the plots) and the same picture twice running. Chromium runs in a session of its own
with a private profile, and the whole session is stopped when the capture ends.
"""
from __future__ import annotations

import base64
import fcntl
import io
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from zentrack.common.procs import die_with_parent

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                  "--enable-unsafe-swiftshader", "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--disable-crash-reporter", "--disable-breakpad",
                  "--remote-debugging-pipe"]
WIDTH, HEIGHT = 1600, 1000
#: pixels with every channel at least this bright are the viewer's text and drawings (its background is dark)
BRIGHT = 150
#: a drawn viewer has at least this many bright pixels; its loading page has none
MIN_BRIGHT_PIXELS = 2000
#: pixels with no channel above this are the 3-D views' background
DARK = 40
#: a drawn viewer's 3-D views cover at least this share of it; its welcome page (bright all over) none
MIN_DARK_SHARE = 0.1
#: two captures in a row differing in at most this share of pixels are the same picture
SAME_SHARE = 0.002


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


class DevToolsPipe:
    """The DevTools protocol over Chromium's pipe: ``call`` sends a command and returns its result."""

    def __init__(self, to_browser: int, from_browser: int, timeout_s: float) -> None:
        self.to_browser, self.from_browser, self.timeout_s = to_browser, from_browser, timeout_s
        self.buffer = b""
        self.next_id = 0
        self.session: str | None = None

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params}
        if self.session is not None:
            msg["sessionId"] = self.session
        os.write(self.to_browser, json.dumps(msg).encode() + b"\0")
        end = time.monotonic() + self.timeout_s
        while time.monotonic() < end:
            reply = self._read(end)
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error'].get('message', reply['error'])}")
                return reply.get("result", {})
        raise TimeoutError(f"{method}: Chromium did not answer within {self.timeout_s:.0f} s")

    def _read(self, end: float) -> dict:
        import select

        while b"\0" not in self.buffer:
            ready, _, _ = select.select([self.from_browser], [], [], max(0.0, end - time.monotonic()))
            if not ready:
                raise TimeoutError("Chromium did not answer in time")
            chunk = os.read(self.from_browser, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed its DevTools pipe (it exited)")
            self.buffer += chunk
        message, _, self.buffer = self.buffer.partition(b"\0")
        return json.loads(message)


def drawn(png: bytes, previous: bytes | None) -> bool:
    """Whether ``png`` shows a drawn viewer: bright text and plots beside the dark 3-D views (the loading page
    is dark all over, the welcome page bright all over), and the same picture as ``previous``."""
    import numpy as np
    from PIL import Image

    now = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    bright, dark = int((now.min(axis=2) >= BRIGHT).sum()), float((now.max(axis=2) <= DARK).mean())
    if bright < MIN_BRIGHT_PIXELS or dark < MIN_DARK_SHARE or previous is None:
        return False
    before = np.asarray(Image.open(io.BytesIO(previous)).convert("RGB")).astype(int)
    return before.shape == now.shape and float((np.abs(now - before).max(axis=2) > 16).mean()) <= SAME_SHARE


def capture(url: str, out: Path, timeout_s: float = 90.0, interval_s: float = 2.0) -> bool:
    """Open ``url`` in headless Chromium and write the page to ``out`` (PNG) once the viewer has drawn; at
    ``timeout_s`` the last capture is written all the same. Whether it had drawn. ValueError without Chromium."""
    exe = chromium()
    if exe is None:
        raise ValueError("--screenshot needs Chromium (chromium or chromium-browser on PATH)")
    to_child, to_browser = os.pipe()
    from_browser, from_child = os.pipe()
    profile = tempfile.mkdtemp(prefix="zentrack-shot-")

    def pipes_at_3_and_4() -> None:  # (in the child: first above 4, so that neither overwrites the other)
        die_with_parent()
        high_in, high_out = fcntl.fcntl(to_child, fcntl.F_DUPFD, 10), fcntl.fcntl(from_child, fcntl.F_DUPFD, 10)
        os.dup2(high_in, 3)
        os.dup2(high_out, 4)

    env = {**os.environ, "XDG_CONFIG_HOME": f"{profile}/config", "XDG_CACHE_HOME": f"{profile}/cache"}
    proc = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={WIDTH},{HEIGHT}",
                             "about:blank"], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=env, start_new_session=True, pass_fds=(3, 4),
                            preexec_fn=pipes_at_3_and_4)
    os.close(to_child)
    os.close(from_child)
    png, previous, done = b"", None, False
    try:
        cdp = DevToolsPipe(to_browser, from_browser, timeout_s=30.0)
        target = cdp.call("Target.createTarget", url="about:blank")["targetId"]
        cdp.session = cdp.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        cdp.call("Page.enable")
        cdp.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT, deviceScaleFactor=1, mobile=False)
        cdp.call("Page.navigate", url=url)
        end = time.monotonic() + timeout_s
        while not done and time.monotonic() < end:
            time.sleep(min(interval_s, max(0.0, end - time.monotonic())))
            previous, png = png or None, base64.b64decode(cdp.call("Page.captureScreenshot", format="png")["data"])
            done = drawn(png, previous)
    finally:
        os.close(to_browser)
        os.close(from_browser)
        stop_session(proc)
        shutil.rmtree(profile, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(png)
    return done


def stop_session(proc: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """Stop Chromium's whole session (its zygote, GPU and renderer processes too): SIGTERM, and SIGKILL to
    whatever of it is left once Chromium itself has exited or after ``timeout_s``."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:
        pass
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()
