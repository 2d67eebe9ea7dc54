"""Every bad value of issue 30, one line: each is refused with exit status 2 and ONE line naming the option,
file or key, before anything starts (no cluster, no output folder); a full disk leaves no ``*.tmp`` behind and
the run says what could not be written.

Most cases parse the real command line in this process (``build_parser``: a refusal is an argparse error, so a
value that would hang the command cannot hang the test) or run the CLI in this process; a few (slow) run it as
a subprocess under a timeout where the whole path matters; the full-disk cases write into a small tmpfs (root
only).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from zentrack.cli import build_parser, check_outputs, main
from zentrack.cluster.deployment.certs import _write as write_certificate_file
from zentrack.common.atomic import replace_atomically
from zentrack.common.report import write_json
from zentrack.config.node_config import NodeConfig
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_config import ScenarioConfigError, builtin_spec, load_scenario_config
from zentrack.config.scenario_file import ScenarioFileError, load_scenario, save_scenario
from zentrack.config.scenario_flags import add_scenario_arguments
from zentrack.truth.simulation.simulate import simulate

HAS_PROC = Path("/proc/self").is_dir()


def refused(argv: list[str], capsys) -> str:
    """The one stderr line of an argparse refusal of ``zentrack <argv>`` (exit status 2)."""
    with pytest.raises(SystemExit) as exc:
        build_parser(argv).parse_args(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert len(err.strip().splitlines()) == 1, err
    return err


# ------------------------------------------------------------------ flags: refused at parse time, nothing starts

SOAK = ["soak", "--cut-every", "0", "--out", "unused"]
FLAG_CASES = [
    # (case, argv, the flag the line must name)
    ("soak-kill-every-nan", [*SOAK, "--kill-every", "nan"], "--kill-every"),
    ("soak-kill-every-tiny", [*SOAK, "--kill-every", "1e-7"], "--kill-every"),
    ("soak-restart-after-nan", [*SOAK, "--restart-after", "nan"], "--restart-after"),
    ("soak-restart-after-negative", [*SOAK, "--restart-after", "-100"], "--restart-after"),
    ("soak-freeze-every-inf", [*SOAK, "--freeze-every", "inf"], "--freeze-every"),
    ("soak-cut-every-tiny", ["soak", "--cut-every", "1e-9", "--out", "unused"], "--cut-every"),
    ("soak-truth-stall-every-nan", [*SOAK, "--truth-stall-every", "nan"], "--truth-stall-every"),
    ("soak-truth-kill-every-tiny", [*SOAK, "--truth-kill-every", "0.001"], "--truth-kill-every"),
    ("soak-router-every-negative", [*SOAK, "--router-every", "-5"], "--router-every"),
    ("soak-fault-s-huge", [*SOAK, "--fault-s", "1e300"], "--fault-s"),
    ("soak-fault-s-nan", [*SOAK, "--fault-s", "nan"], "--fault-s"),
    ("soak-duration-huge", [*SOAK, "--duration", "1e300"], "--duration"),
    ("soak-duration-tiny", [*SOAK, "--duration", "1e-9"], "--duration"),
    ("soak-seed-negative", [*SOAK, "--seed", "-1"], "--seed"),
    ("compose-seed-negative", ["compose", "--seed", "-1"], "--seed"),
    ("compose-run-bad-name", ["compose", "--run", "bad name!"], "--run"),
    ("compose-scenario-unknown", ["compose", "--scenario", "nosuch"], "--scenario"),
    ("certs-host-empty", ["certs", "--out", "unused", "--nodes", "1", "--host", ""], "--host"),
    ("certs-host-not-a-name", ["certs", "--out", "unused", "--nodes", "1", "--host", "a b/c"], "--host"),
    ("node-lease-ms-huge", ["node", "--id", "0", "--lease-ms", str(10**20)], "--lease-ms"),
]


@pytest.mark.parametrize("case, argv, flag", FLAG_CASES, ids=[c[0] for c in FLAG_CASES])
def test_bad_flag_is_one_line_naming_it(case, argv, flag, capsys):
    assert flag in refused(argv, capsys)


def test_good_soak_and_certs_values_still_parse():
    args = build_parser(["soak"]).parse_args([*SOAK, "--kill-every", "0", "--restart-after", "0", "--fault-s", "0.5"])
    assert (args.kill_every, args.restart_after, args.fault_s) == (0.0, 0.0, 0.5)
    args = build_parser(["certs"]).parse_args(["certs", "--out", "x", "--nodes", "1", "--host", "router-1.example",
                                               "--host", "10.0.0.7", "--host", "::1"])
    assert args.host == ["router-1.example", "10.0.0.7", "::1"]


@pytest.mark.slow  # a subprocess: the in-process cases above cover the values
def test_soak_nan_period_exits_2_at_once_and_writes_nothing(tmp_path):
    """The whole command: before, ``--kill-every nan`` spun at 100 % CPU drawing the fault schedule forever."""
    out = tmp_path / "soak"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "soak", "--kill-every", "nan", "--cut-every", "0",
                           "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "--kill-every" in proc.stderr and not out.exists()


# ------------------------------------------------------------------ output paths: checked before anything runs

@pytest.mark.skipif(not HAS_PROC, reason="needs /proc (where nothing can be created, even by root)")
def test_viewer_save_where_nothing_can_be_created_is_one_line(capsys):
    assert main(["viewer", "--save", "/proc/x.rrd", "--run", "badvalues"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--save /proc/x.rrd" in err, err


def bench_output_flags() -> list[tuple[str, str]]:
    """(bench, flag) for every output file or folder flag of every benchmark."""
    from zentrack.cli import BENCHMARKS, OUTPUT_DIRS, OUTPUT_FILES
    from zentrack.common.deprecation import DeprecatedFlag

    found = []
    for name, *_ in BENCHMARKS:
        parser = build_parser(["bench", name])
        sub = next(a for a in parser._actions if a.dest == "command").choices["bench"]
        bench = next(a for a in sub._actions if a.dest == "bench").choices[name]
        for action in bench._actions:
            if action.dest in {**OUTPUT_DIRS, **OUTPUT_FILES} and not isinstance(action, DeprecatedFlag):
                found.append((name, action.option_strings[0]))
    return found


@pytest.mark.skipif(not HAS_PROC, reason="needs /proc")
@pytest.mark.parametrize("bench, flag", bench_output_flags())
def test_every_bench_output_flag_is_checked_up_front(bench, flag):
    argv = ["bench", bench, flag, "/proc/zentrack-bad"]
    with pytest.raises(ValueError, match=f"^{flag} /proc/zentrack-bad: "):
        check_outputs(build_parser(argv).parse_args(argv))


@pytest.mark.slow  # a subprocess
@pytest.mark.skipif(not HAS_PROC, reason="needs /proc")
def test_bench_hops_json_unwritable_runs_nothing():
    """Before: 12 s of round trips, then a line naming ``/proc/x.tmp``."""
    proc = subprocess.run([sys.executable, "-m", "zentrack", "bench", "hops", "--json", "/proc/x"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == "", proc.stdout
    assert proc.stderr.strip() == "zentrack bench hops: error: --json /proc/x: /proc is not writable " \
                                  "(No such file or directory)", proc.stderr


# ------------------------------------------------------------------ scenario files: one line naming file and key

@pytest.fixture(scope="module")
def good_npz(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("scenarios")
    return save_scenario(d / "good.npz", simulate(builtin_spec("exp2", nodes=4, steps=20), runs=1, seed=1))


def variant(good: Path, name: str, **changes) -> Path:
    """``good`` with some keys replaced, written as ``name``.npz beside it (np.savez: no validation on the way)."""
    with np.load(good, allow_pickle=False) as npz:
        data = {key: npz[key] for key in npz.files}
    data.update(changes)
    path = good.with_name(f"{name}.npz")
    np.savez(path, **data)
    return path


def zero_steps(data) -> dict:
    return {key: data[key][:, :0] for key in ("truth", "lumped", "measurements", "present")}


def one_way_link(data) -> dict:
    """Node 0 lists node 1 as a neighbour, node 1 does not list node 0 (weights moved to the diagonal)."""
    adj, w = data["adjacency"].copy(), data["weights"].copy()
    i, j = (int(v) for v in np.argwhere(adj)[0])
    adj[j, i] = False
    w[j, j] += w[j, i]
    w[j, i] = 0.0
    return {"adjacency": adj, "weights": w}


FILE_CASES = {
    # case: (changes given the good file's arrays, the key the line must name)
    "zero-steps": (zero_steps, "'truth'"),
    "lumped-var-negative": (lambda d: {"lumped_var": np.float64(-1.0)}, "'lumped_var'"),
    "lumped-var-nan": (lambda d: {"lumped_var": np.float64(np.nan)}, "'lumped_var'"),
    "adjacency-asymmetric": (one_way_link, "'adjacency'"),
    "measurements-integer": (lambda d: {"measurements": np.round(d["measurements"]).astype(np.int64)}, "'measurements'"),
}


@pytest.mark.parametrize("case", FILE_CASES)
def test_bad_scenario_file_names_file_and_key(good_npz, case):
    make, key = FILE_CASES[case]
    with np.load(good_npz, allow_pickle=False) as npz:
        path = variant(good_npz, case, **make({k: npz[k] for k in npz.files}))
    with pytest.raises(ScenarioFileError) as exc:
        load_scenario(path)
    assert str(path) in str(exc.value) and key in str(exc.value), exc.value


@pytest.mark.parametrize("case", ["zero-steps", "lumped-var-negative", "measurements-integer"])
def test_sim_refuses_bad_scenario_file_in_one_line(good_npz, case, capsys):
    """Before: an IndexError (0 steps), a ZeroDivisionError (lumped_var -1), 230 m RMSE and exit 0 (integers)."""
    make, key = FILE_CASES[case]
    with np.load(good_npz, allow_pickle=False) as npz:
        path = variant(good_npz, f"sim-{case}", **make({k: npz[k] for k in npz.files}))
    assert main(["sim", "--scenario-file", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and key in err, err


@pytest.mark.slow  # a subprocess (before the fix it started a cluster)
@pytest.mark.parametrize("case", ["zero-steps", "lumped-var-negative"])
def test_run_refuses_bad_scenario_file_before_starting(good_npz, case, tmp_path):
    """Before: ``run`` said "run OK" with no estimates (0 steps), or every tracker died (lumped_var -1)."""
    make, key = FILE_CASES[case]
    with np.load(good_npz, allow_pickle=False) as npz:
        path = variant(good_npz, f"run-{case}", **make({k: npz[k] for k in npz.files}))
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario-file", str(path), "--timing", "lockstep",
                           "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert key in proc.stderr and not out.exists()


def test_deeply_nested_toml_is_one_line_naming_the_file(tmp_path, capsys):
    """Before: a RecursionError and some 3000 lines of traceback."""
    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ScenarioConfigError, match=f"^{path}: not valid TOML"):
        load_scenario_config(str(path))
    assert main(["sim", "--scenario", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(path) in err, err


# ------------------------------------------------------------------ a full disk: no *.tmp, nothing lost, say what

@pytest.fixture
def small_disk(tmp_path):
    """A 256 KiB tmpfs (root only), unmounted afterwards."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / "disk"
    mnt.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True, text=True)
    if made.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({made.stderr.strip()})")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def fill(folder: Path) -> None:
    """Fill the file system of ``folder`` to the last byte."""
    with open(folder / "filler", "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
                f.flush()
        except OSError:
            pass


def node_config() -> NodeConfig:
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    return resolve_setup(p.parse_args(["--scenario", "exp2", "--nodes", "3", "--steps", "10"])).node_config(0)


def writers() -> dict:
    """name -> (write the old version, write a new one), each to the path given."""
    small = simulate(builtin_spec("exp2", nodes=3, steps=2), runs=1, seed=1)
    big = simulate(builtin_spec("exp2", nodes=3, steps=400), runs=1, seed=1)
    cfg = node_config()
    return {
        "write_json": (lambda p: write_json(p, {"a": 1}), lambda p: write_json(p, {"a": list(range(20000))})),
        "save_scenario": (lambda p: save_scenario(p, small), lambda p: save_scenario(p, big)),
        "node_config": (cfg.save, cfg.save),
        "certificate": (lambda p: write_certificate_file(p, b"old", private=True),
                        lambda p: write_certificate_file(p, b"x" * 100_000, private=True)),
        "npz": (lambda p: replace_atomically(p, lambda t: np.savez(t, a=np.zeros(1)), ".tmp.npz"),
                lambda p: replace_atomically(p, lambda t: np.savez(t, a=np.zeros(50_000)), ".tmp.npz")),
    }


WRITERS = ["write_json", "save_scenario", "node_config", "certificate", "npz"]


@pytest.mark.parametrize("name", WRITERS)
def test_full_disk_keeps_the_old_file_and_leaves_no_tmp(small_disk, name):
    write_old, write_new = writers()[name]
    suffix = ".npz" if name in ("save_scenario", "npz") else ".json"
    path = small_disk / f"out{suffix}"
    write_old(path)
    before = path.read_bytes()
    fill(small_disk)
    with pytest.raises(OSError):
        write_new(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler", path.name]


@pytest.mark.slow
def test_disk_full_mid_run_says_the_trackers_ran_and_which_reports_are_lost(small_disk):
    """A run whose disk fills once its trackers are up. Before: "every tracker process failed while the truth was
    running" (they had only failed to write their reports) and an empty ``node-<i>.json.tmp`` per tracker."""
    out = small_disk / "run"
    proc = subprocess.Popen([sys.executable, "-m", "zentrack", "run", "--scenario", "exp2", "--nodes", "3", "--steps",
                             "100", "--timing", "realtime", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        logs = [out / "logs" / f"node-{i}.log" for i in range(3)]
        deadline = time.time() + 60
        while not all(p.is_file() and " up: run " in p.read_text() for p in logs):
            assert proc.poll() is None and time.time() < deadline, "the trackers did not come up"
            time.sleep(0.1)
        fill(small_disk)
        stdout, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 1, stderr
    assert "every tracker process failed" not in stderr
    line = next(x for x in stderr.splitlines() if "could not write their reports" in x)
    assert "the trackers ran" in line and all(f"node-{i}.json" in line for i in range(3)), line
    assert "no summary written" in stdout
    assert not list(small_disk.rglob("*.tmp*"))
