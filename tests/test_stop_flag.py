"""The stop flag every process sets on SIGTERM/SIGINT (``zentrack.common.procs.StopFlag``).

Run 27 of the suite left a tracker running after its orchestrator was killed: the tracker had two SIGTERMs,
and the second one's handler ran inside the first one's ``threading.Event.set``, which holds a lock, and
waited for that lock for ever (found with gdb's ``py-bt`` on the hung tracker). A storm of SIGTERMs hung the
old flag five times in five; the flag's handler now takes no lock.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from zentrack.common.procs import StopFlag

CHILD = r"""
import time
from zentrack.common.procs import StopFlag
stop = StopFlag()
print("ready", flush=True)
end = time.time() + 2.0
while time.time() < end:
    time.sleep(0.001)
print("alive", bool(stop), flush=True)
"""


def test_a_storm_of_sigterms_sets_the_flag_and_never_hangs_the_process():
    child = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        end = time.time() + 1.5
        sent = 0
        while time.time() < end and child.poll() is None:
            os.kill(child.pid, signal.SIGTERM)
            sent += 1
        out, _ = child.communicate(timeout=20)  # a hung handler never gets here
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert sent > 1000 and child.returncode == 0 and out.strip() == "alive True", (sent, child.returncode, out)


def test_wait_returns_when_the_flag_is_set_or_the_time_is_up():
    flag = StopFlag(handle_signals=False)
    start = time.monotonic()
    assert flag.wait(0.12) is False and time.monotonic() - start >= 0.12
    flag.set()
    start = time.monotonic()
    assert flag.wait(10.0) is True and bool(flag) and time.monotonic() - start < 0.01


def test_the_handlers_are_installed_only_when_asked(monkeypatch):
    before = signal.getsignal(signal.SIGTERM)
    StopFlag(handle_signals=False)
    assert signal.getsignal(signal.SIGTERM) is before
    try:
        flag = StopFlag()
        signal.raise_signal(signal.SIGTERM)
        assert flag
    finally:
        signal.signal(signal.SIGTERM, before)
