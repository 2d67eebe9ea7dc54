"""Screenshot a page in headless Chromium over the DevTools protocol (test helper, loopback only).

Chromium runs in its own process group (``start_new_session=True``): it forks zygote, GPU, renderer and
utility processes that keep writing into the profile directory, so stopping only the parent is not enough.
The whole group is stopped (SIGTERM, then SIGKILL) and waited for before the profile is removed, together
with the crashpad handlers, which leave the group but are found by the profile path in their command line.
Errors while removing the temporary profile never fail a test.

Nothing here sleeps for a fixed time: the page is captured every ``interval_s`` until the caller's
``ready(png)`` predicate accepts it or ``timeout_s`` runs out.
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import websocket  # websocket-client

from zentrack.common.ports import free_port

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=1600,1000",
]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _live_processes():
    """(pid, pgid, command line) of every live (non-zombie) process, from /proc."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()  # state ppid pgrp ...
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if fields[0] != "Z":
            yield int(entry), int(fields[2]), cmdline


def chromium_processes(pgid: int, profile: str) -> list[int]:
    """Live processes of this Chromium: its process group, plus anything naming its private profile folder
    (the crashpad handlers daemonize into sessions of their own; their database is inside the profile)."""
    return [pid for pid, group, cmdline in _live_processes() if group == pgid or profile in cmdline]


def _all_gone(pgid: int, profile: str, timeout_s: float) -> bool:
    end = time.time() + timeout_s
    while time.time() < end:
        if not chromium_processes(pgid, profile):
            return True
        time.sleep(0.05)
    return not chromium_processes(pgid, profile)


def stop_chromium(proc: subprocess.Popen, profile: str, timeout_s: float = 10.0) -> None:
    """Stop every process of this Chromium (SIGTERM, then SIGKILL) and wait until none is left."""
    pgid = proc.pid  # it leads its own session and process group
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pgid, sig)
        except ProcessLookupError:
            pass  # the whole group has exited already
        if sig == signal.SIGKILL:
            for pid in chromium_processes(pgid, profile):  # stragglers outside the group, by their own id
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
        try:
            proc.wait(timeout=timeout_s)  # reaps the leader, so it does not linger as a zombie
        except subprocess.TimeoutExpired:
            continue
        if _all_gone(pgid, profile, timeout_s):
            return
    raise RuntimeError(f"chromium processes {chromium_processes(pgid, profile)} survived SIGKILL")


def page_loaded(cdp: DevTools) -> bool:
    return cdp.call("Runtime.evaluate", expression="document.readyState")["result"].get("value") == "complete"


class DevTools:
    """A minimal Chrome DevTools Protocol client for one page target."""

    def __init__(self, ws_url: str, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        # no Origin header: Chromium from 111 on refuses a DevTools socket whose Origin it was not told to allow
        self.ws = websocket.create_connection(ws_url, timeout=timeout_s, suppress_origin=True)
        self._ids = iter(range(1, 10**9))

    def call(self, method: str, **params):
        msg_id = next(self._ids)
        self.ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
        end = time.time() + self.timeout_s
        while time.time() < end:  # each recv is bounded by the socket timeout
            reply = json.loads(self.ws.recv())
            if reply.get("id") == msg_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
        raise TimeoutError(f"{method}: no reply within {self.timeout_s:.0f} s")

    def capture(self) -> bytes:
        return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])

    def close(self) -> None:
        self.ws.close()


def _page_target(port: int, timeout_s: float) -> dict:
    end = time.time() + timeout_s
    while time.time() < end:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                targets = [t for t in json.load(r) if t.get("type") == "page"]
            if targets:
                return targets[0]
        except OSError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"chromium's DevTools endpoint did not come up within {timeout_s:.0f} s")


def screenshot(url: str, out: Path, ready: Callable[[bytes], bool] | None = None, timeout_s: float = 60.0,
               interval_s: float = 1.0) -> bytes:
    """Open ``url`` and capture it every ``interval_s`` until ``ready(png)`` is true (or, without ``ready``,
    until the document has loaded), at most ``timeout_s``. Writes the last capture to ``out`` and returns it;
    on a timeout the last capture is returned as is, so the caller's assertions say what is missing."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("chromium is not installed")
    port = free_port()
    png = b""
    with tempfile.TemporaryDirectory(prefix="webshot-", ignore_cleanup_errors=True) as profile:
        # config and cache (crash reports too) inside the profile: nothing is left in ~/.config or ~/.cache
        env = {**os.environ, "XDG_CONFIG_HOME": f"{profile}/config", "XDG_CACHE_HOME": f"{profile}/cache"}
        proc = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--remote-debugging-port={port}",
                                 "--remote-debugging-address=127.0.0.1", f"--user-data-dir={profile}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True)
        try:
            start = time.time()
            end = start + timeout_s
            cdp = DevTools(_page_target(port, timeout_s)["webSocketDebuggerUrl"], timeout_s)
            try:
                cdp.call("Page.enable")
                cdp.call("Emulation.setDeviceMetricsOverride", width=1600, height=1000, deviceScaleFactor=1,
                         mobile=False)
                cdp.call("Page.navigate", url=url)
                done = False
                while True:
                    shot_at = time.time()
                    try:  # while the navigation commits, DevTools answers "Not attached to an active page"
                        if page_loaded(cdp):
                            png = cdp.capture()
                            done = ready is None or ready(png)
                    except RuntimeError as exc:
                        print(f"webshot: page not ready yet ({exc})")
                    if done or time.time() >= end:
                        break
                    time.sleep(max(0.0, min(interval_s - (time.time() - shot_at), end - time.time())))
                if not png:  # never loaded: the last state of the page is still the best evidence
                    png = cdp.capture()
                print(f"webshot {url}: {'ready' if done else 'NOT ready'} after {time.time() - start:.1f} s")
            finally:
                cdp.close()
        finally:
            stop_chromium(proc, profile)
    shutil.rmtree(profile, ignore_errors=True)  # the group is gone: nothing can recreate files in it now
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(png)
    return png


def png_pixels(png: bytes):
    """RGB pixels of a PNG as a numpy array."""
    import io

    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
