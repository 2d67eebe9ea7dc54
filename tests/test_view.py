"""``zentrack view PATH.rrd`` (issue 50): a saved recording served to a browser on 127.0.0.1 until Ctrl-C, its
address printed; a missing or foreign file is one line and exit 2; Ctrl-C stops the server and frees its ports."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from zentrack.cli import main
from zentrack.viewer.ports import port_in_use


@pytest.mark.parametrize("make", ["missing", "folder", "text"])
def test_a_missing_or_foreign_file_is_one_line_and_exit_2(make, tmp_path, capsys):
    path = tmp_path / "run.rrd"
    if make == "folder":
        path.mkdir()
    elif make == "text":
        path.write_text("not a recording\n")
    assert main(["view", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0], err
    assert {"missing": "no such file", "folder": "not a file", "text": "not a Rerun recording"}[make] in err[0]


def _recording(path: Path) -> Path:
    import rerun as rr

    rec = rr.RecordingStream("zentrack-view-test")
    rec.save(str(path))
    rec.log("points", rr.Points3D([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    rec.flush()
    rec.disconnect()
    return path


@pytest.mark.slow
def test_it_serves_until_ctrl_c_then_frees_its_ports(tmp_path):
    from zentrack.common.ports import free_port

    rrd = _recording(tmp_path / "recording.rrd")
    web, grpc = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, "-m", "zentrack", "view", str(rrd), "--web-port", str(web),
                             "--grpc-port", str(grpc)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        line = proc.stdout.readline()  # (the process prints it once both ports listen; the limit is the test's)
        assert line.startswith(f"view: serving {rrd} at http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}"
                               f"/proxy&hide_welcome_screen "), \
            line + proc.stderr.read() if proc.poll() is not None else line
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as page:
            assert page.status == 200
        assert port_in_use(grpc)
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=20) == 0
        end = time.monotonic() + 10
        while (port_in_use(web) or port_in_use(grpc)) and time.monotonic() < end:
            time.sleep(0.1)
        assert not port_in_use(web) and not port_in_use(grpc), "a port is still held after Ctrl-C"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


@pytest.mark.slow
def test_a_screenshot_of_a_recording_is_the_drawn_viewer_and_leaves_nothing_running(tmp_path):
    """``view PATH.rrd --screenshot OUT.png``: headless Chromium draws the recording; the picture has the viewer's
    text and the run's colours (Chromium's one-shot ``--screenshot`` saved the loading page, issue 50)."""
    import numpy as np
    from PIL import Image

    from zentrack.common.ports import free_port
    from zentrack.viewer.screenshot import MIN_BRIGHT_PIXELS, chromium

    assert chromium(), "Chromium is part of the test environment (.ci/run installs it)"
    run = tmp_path / "run"
    made = subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario", "exp2", "--nodes", "3", "--steps", "40",
                           "--timing", "lockstep", "--viewer", "--out", str(run)], capture_output=True, text=True,
                          timeout=300)
    assert made.returncode == 0, made.stderr[-2000:]
    shot = tmp_path / "viewer.png"
    web, grpc = free_port(), free_port()
    done = subprocess.run([sys.executable, "-m", "zentrack", "view", str(run / "recording.rrd"), "--web-port", str(web),
                           "--grpc-port", str(grpc), "--screenshot", str(shot)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == f"view: {shot} (the viewer drawing {run / 'recording.rrd'})", \
        done.stdout + done.stderr
    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert pixels.shape == (1000, 1600, 3)
    assert int((pixels.min(axis=2) >= 150).sum()) >= MIN_BRIGHT_PIXELS  # text, the truth, the plots
    assert len(np.unique(pixels.reshape(-1, 3) // 16, axis=0)) > 50, "one colour: the loading page"
    assert not port_in_use(web) and not port_in_use(grpc)


def test_a_screenshot_without_chromium_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    rrd = _recording(tmp_path / "recording.rrd")
    monkeypatch.setenv("PATH", str(tmp_path))  # no chromium here
    assert main(["view", str(rrd), "--screenshot", str(tmp_path / "v.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "--screenshot needs Chromium" in err and not (tmp_path / "v.png").exists()
