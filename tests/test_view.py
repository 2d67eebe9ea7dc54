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
    from zentrack.cluster.orchestrator import free_port

    rrd = _recording(tmp_path / "recording.rrd")
    web, grpc = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, "-m", "zentrack", "view", str(rrd), "--web-port", str(web),
                             "--grpc-port", str(grpc)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        line = proc.stdout.readline()  # (the process prints it once both ports listen; the limit is the test's)
        assert line.startswith(f"view: serving {rrd} at http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy"), \
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
