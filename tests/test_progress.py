"""zentrack.common.progress: a line that updates in place on a terminal, nothing when not a terminal, and the
closing line that says where the outputs are."""
from __future__ import annotations

import io
import logging
from pathlib import Path

from zentrack.common.progress import Progress, note, outputs_line


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_on_a_terminal_the_line_updates_in_place_and_ends_with_a_newline():
    out, clock = Terminal(), Clock()
    with Progress(300, "steps", label="run", stream=out, clock=clock, min_interval=0.0) as bar:
        clock.t += 12.0
        bar.update(120)
        clock.t += 18.0
        bar.update(300)
    text = out.getvalue()
    frames = text.split("\r")[1:]
    assert "run [########            ] 120/300 steps  00:12" in frames
    assert frames[-1].startswith("run [####################] 300/300 steps  00:30")
    assert text.endswith("\n") and text.count("\n") == 1  # one line, redrawn in place
    assert all("\n" not in f for f in frames[:-1])


def test_not_a_terminal_writes_nothing():
    out, clock = io.StringIO(), Clock()
    with Progress(10, stream=out, clock=clock) as bar:
        for k in range(10):
            clock.t += 1.0
            bar.update(k + 1)
    assert out.getvalue() == ""


def test_redraws_at_most_every_min_interval_but_always_the_last_count():
    out, clock = Terminal(), Clock()
    bar = Progress(1000, stream=out, clock=clock, min_interval=1.0)
    for k in range(1000):
        clock.t += 0.001  # a whole second for 1000 updates
        bar.update(k + 1)
    bar.close()
    frames = out.getvalue().split("\r")[1:]
    assert len(frames) <= 3
    assert "1000/1000 steps" in frames[-1]


def test_a_shorter_line_wipes_the_longer_one_and_unknown_total_counts_only():
    out, clock = Terminal(), Clock()
    bar = Progress(None, "estimates", stream=out, clock=clock, min_interval=0.0)
    bar.update(5, note="waiting for node-3")
    bar.update(6)
    bar.close()
    frames = out.getvalue().split("\r")[1:]
    assert "5 estimates  00:00, waiting for node-3" in frames
    wiped = frames[frames.index("5 estimates  00:00, waiting for node-3") + 1]
    assert wiped.startswith("6 estimates  00:00") and len(wiped) == len(frames[1])


def test_outputs_line_names_every_output_and_both_figure_files():
    out = Path("out") / "soak"
    line = outputs_line("soak passed", report=out / "report.json",
                        error_plot=[out / "error.png", out / "error.svg"], recording=None)
    assert line == ("soak passed: report out/soak/report.json, error plot out/soak/error.png out/soak/error.svg")
    assert outputs_line("nothing written") == "nothing written"


def test_messages_and_log_records_go_above_the_bar_which_is_redrawn_below():
    out, clock = Terminal(), Clock()
    handler = logging.StreamHandler(out)
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        bar = Progress(10, stream=out, clock=clock, min_interval=0.0)
        bar.update(3)
        bar.write_above("[exp 2 1/5] dteskf: RMSE 6.8")
        logging.getLogger("zentrack.test").warning("node-3 killed")
        bar.close()
        assert handler.stream is out, "log records go to the stream itself again after the bar"
    finally:
        root.removeHandler(handler)
    lines = out.getvalue().split("\n")
    assert lines[0].endswith("\r[exp 2 1/5] dteskf: RMSE 6.8") and "[######              ] 3/10" in lines[0]
    assert lines[1].endswith("node-3 killed")
    assert lines[-2].split("\r")[-1].startswith("[######              ] 3/10 steps") and lines[-1] == ""


def test_not_a_terminal_messages_are_plain_lines():
    out = io.StringIO()
    bar = Progress(10, stream=out)
    bar.update(3)
    bar.write_above("a message")
    bar.close()
    assert out.getvalue() == "a message\n"


def test_note_advances_the_open_bar_and_writes_above_it(capsys):
    out, clock = Terminal(), Clock()
    with Progress(4, "filters", stream=out, clock=clock, min_interval=0.0):
        note("[exp 1 1/4] cteskf done", done=1)
    frames = out.getvalue().split("\r")
    assert any(f.startswith("[exp 1 1/4] cteskf done\n") for f in frames), frames
    assert frames[-1].startswith("[#####               ] 1/4 filters")
    note("no bar open")  # after the bar closed: a plain line on stderr
    assert capsys.readouterr().err == "no bar open\n"


def test_a_terminal_that_reports_no_size_still_gets_the_bar():
    """A fresh pty reports 0 x 0 (what the Ctrl-C test's terminal is): tqdm would draw nothing at all there."""
    import os
    import pty
    import select
    import subprocess
    import sys
    import time

    master, slave = pty.openpty()
    code = ("from zentrack.common.progress import Progress\n"
            "with Progress(5, 'steps', label='run', min_interval=0.0) as bar:\n"
            "    [bar.update(k + 1) for k in range(5)]\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=slave, stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    text, end = b"", time.monotonic() + 60
    while time.monotonic() < end:
        if select.select([master], [], [], 0.1)[0]:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                break
            if not chunk:
                break
            text += chunk
        elif proc.poll() is not None:
            break
    proc.wait(timeout=30)
    os.close(master)
    assert b"run [####################] 5/5 steps" in text, text
