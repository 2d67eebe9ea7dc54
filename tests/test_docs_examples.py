"""Every ``zentrack`` command of the README and the docs runs as written, shortened (issue 50).

A page's commands run in its order, in one folder of their own (as a reader following the page would: a file
one command writes, the next reads), as ``python -m zentrack`` with the page's words, the few flags of
:data:`SHORTER` replaced or added so that each takes seconds. Each must exit 0 without a traceback. Two
kinds run their own way: a soak prints its fault schedule (``--plan``: the soaks themselves are
tests/test_soak*.py), and ``zentrack view`` serves until its address is printed, then gets Ctrl-C. What a
page's command needs from before the page (a recording, a finished soak) is made first (:data:`BEFORE`).
The commands are those tests/test_docs_commands.py parses.
"""
from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_docs_commands import COMMANDS

ROOT = Path(__file__).resolve().parents[1]

#: the flags that shorten each kind of command: a value replaces the page's value or is added; None: a switch
SHORTER: dict[str, dict[str, str | None]] = {
    "run": {"--steps": "10", "--timing": "lockstep"},
    "sim": {"--runs": "2", "--steps": "10"},
    "bench paper0": {"--runs": "2", "--steps": "10"},
    "bench paper1": {"--runs": "2", "--steps": "10"},
    "bench paper2": {"--runs": "2", "--steps": "10"},
    "bench paper3": {"--runs": "20", "--single-steps": "10"},
    "bench paper4": {"--runs": "1", "--steps": "10"},
    "bench accuracy": {"--runs": "1", "--steps": "10"},
    "bench multitarget": {"--runs": "1", "--steps": "10"},
    "bench async": {"--runs": "1", "--steps": "10"},
    "bench isolated": {"--runs": "1", "--cuts": "0.5"},
    "bench scale": {"--sizes": "4", "--degree": "2", "--duration": "6"},
    "bench floor": {"--sizes": "4", "--duration": "6"},
    "bench profile": {"--nodes": "4", "--duration": "6", "--profiled": "1"},
    "soak": {"--plan": None},
}
def _recording(folder: Path) -> None:
    """The recording docs/viewer.md opens: a short run with the viewer."""
    done = zentrack(["run", "--scenario", "exp2", "--nodes", "2", "--steps", "10", "--timing", "lockstep",
                     "--viewer", "--out", "out/run"], folder)
    assert done.returncode == 0, done.stderr[-2000:]


def _finished_soak(folder: Path) -> None:
    """The finished soak docs/soak-hour.md judges again (a saved one that passes: tests/test_soak_rejudge.py)."""
    from test_soak_rejudge import _soak_dir

    _soak_dir(folder / "out" / "soak1h", others=5.0)


#: what a page's commands need from before the page, made first in the page's folder
BEFORE = {"docs/viewer.md": _recording, "docs/soak-hour.md": _finished_soak}
#: commands that serve until Ctrl-C
SERVES = {"view"}
#: pages whose commands serve the viewer on its fixed ports (conftest.GROUPS keeps them apart)
VIEWER_PORTS = {"README.md", "docs/getting-started.md", "docs/viewer.md"}


def kind_of(argv: list[str]) -> str:
    return " ".join(argv[:2]) if argv[0] == "bench" else argv[0]


def asynchronous(argv: list[str]) -> bool:
    """Whether ``argv`` runs a catalogue scenario with sensors of their own (``[sensor_timing]``)."""
    if "--scenario" not in argv:
        return False
    path = ROOT / "deploy" / "scenarios" / f"{argv[argv.index('--scenario') + 1]}.toml"
    return path.is_file() and "[sensor_timing]" in path.read_text()


def shortened(argv: list[str]) -> list[str]:
    """``argv`` with :data:`SHORTER`'s flags for its kind; as written: a soak's ``--rejudge``, and a command
    that replays a scenario file (its size is the file's: the command that saved it was shortened)."""
    if "--rejudge" in argv or "--scenario-file" in argv:
        return argv
    out = list(argv)
    shorter = SHORTER.get(kind_of(argv), {})
    if kind_of(argv) == "run" and asynchronous(argv):  # sensors of their own run in realtime only
        shorter = {flag: value for flag, value in shorter.items() if flag != "--timing"}
    for flag, value in shorter.items():
        if flag in out:
            if value is not None:
                out[out.index(flag) + 1] = value
        else:
            out += [flag] if value is None else [flag, value]
    return out


def zentrack(argv: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zentrack", *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


def serve_then_stop(argv: list[str], cwd: Path, timeout: float = 60) -> tuple[int, str]:
    """Start a serving command, wait for the line with its address, then Ctrl-C: (exit status, output)."""
    proc = subprocess.Popen([sys.executable, "-m", "zentrack", *argv], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    lines = []
    try:
        end = time.time() + timeout
        while time.time() < end:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "http://127.0.0.1:" in line:
                proc.send_signal(signal.SIGINT)
                break
        return proc.wait(timeout=30), "".join(lines) + proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def page_folder(tmp_path: Path) -> Path:
    """A reader's folder: what the pages read from the repository (the capacity fit) and the folders they
    write into (deploy/)."""
    (tmp_path / "deploy").mkdir()
    (tmp_path / "docs" / "results").mkdir(parents=True)
    shutil.copy(ROOT / "docs" / "results" / "capacity_scale.json", tmp_path / "docs" / "results")
    return tmp_path


PAGES = sorted({page for page, _ in COMMANDS})


def same_run(command: str) -> str:
    """``command`` as it runs, a run's ``--out`` left out (no page reads what one of its runs wrote)."""
    argv = shortened(shlex.split(command)[1:])
    if argv[0] == "run" and "--out" in argv:
        del argv[argv.index("--out"):argv.index("--out") + 2]
    return shlex.join(argv)


#: the page each command runs on: the first that shows it (README.md, then docs/ by name)
FIRST_PAGE: dict[str, str] = {}
for _page, _command in COMMANDS:
    FIRST_PAGE.setdefault(same_run(_command), _page)


def run_page(page: str, folder: Path) -> None:
    if page in BEFORE:
        BEFORE[page](folder)
    for where, command in COMMANDS:
        if where != page or FIRST_PAGE[same_run(command)] != page:
            continue  # (a command several pages show runs on the first of them)
        argv = shortened(shlex.split(command)[1:])
        if argv[0] in SERVES:
            code, output = serve_then_stop(argv, folder)
        else:
            done = zentrack(argv, folder)
            code, output = done.returncode, done.stdout + done.stderr
        assert code == 0 and "Traceback" not in output, \
            f"{page}: `{command}` (run as `zentrack {shlex.join(argv)}`) exit {code}:\n{output[-3000:]}"


def test_every_page_with_commands_is_run():
    assert set(PAGES) >= {"README.md", "docs/getting-started.md", "docs/soak.md", "docs/viewer.md"}
    assert all(kind_of(shlex.split(c)[1:]) in SHORTER or shlex.split(c)[1] in
               {"scenarios", "--help", "compose", "certs", "view"} or "--help" in c or "capacity" in c
               for _, c in COMMANDS), "a command of a new kind: say how it is shortened (SHORTER)"


@pytest.mark.slow
@pytest.mark.parametrize("page", sorted(set(PAGES) - VIEWER_PORTS))
def test_a_docs_page_runs_as_written(page, tmp_path):
    run_page(page, page_folder(tmp_path))


@pytest.mark.slow
@pytest.mark.parametrize("page", sorted(VIEWER_PORTS))
def test_a_docs_page_serving_the_viewer_runs_as_written(page, tmp_path):
    run_page(page, page_folder(tmp_path))


def test_shortening_replaces_or_adds_the_flags():
    assert shortened(["run", "--steps", "300", "--out", "o"]) == ["run", "--steps", "10", "--out", "o", "--timing",
                                                                  "lockstep"]
    assert shortened(["sim", "--scenario", "exp2"]) == ["sim", "--scenario", "exp2", "--runs", "2", "--steps", "10"]
    assert shortened(["soak", "--duration", "120"]) == ["soak", "--duration", "120", "--plan"]
    assert shortened(["soak", "--rejudge", "--out", "o"]) == ["soak", "--rejudge", "--out", "o"]
    assert os.path.basename(sys.executable).startswith("python")
