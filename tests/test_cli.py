"""The zentrack CLI: sim, scenario save/replay, benchmarks, and clear errors for bad input."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from zentrack.cli import main


def run_cli(*args: str) -> int:
    return main(list(args))


def test_sim_writes_json_and_replays_saved_scenario(tmp_path, capsys):
    scn_path, out1, out2 = tmp_path / "s.npz", tmp_path / "a.json", tmp_path / "b.json"
    est = tmp_path / "est.npz"
    assert run_cli("sim", "--scenario", "exp2", "--nodes", "4", "--steps", "60", "--runs", "2",
                   "--filter", "dteskf,cteskf", "--save-scenario", str(scn_path), "--json", str(out1)) == 0
    text = capsys.readouterr().out
    assert "dteskf" in text and "cteskf" in text and "RMSE p" in text
    a = json.loads(out1.read_text())
    assert a["runs"] == 2 and set(a["filters"]) == {"dteskf", "cteskf"}
    assert len(a["filters"]["dteskf"]["rmse"]["p"]["runs"]) == 2
    assert a["filters"]["dteskf"]["us_per_node_step"] > 0
    assert run_cli("sim", "--scenario-file", str(scn_path), "--filter", "dteskf,cteskf", "--json", str(out2),
                   "--save-estimates", str(est)) == 0
    b = json.loads(out2.read_text())
    for name in ("dteskf", "cteskf"):
        assert a["filters"][name]["rmse"]["tot"]["runs"] == b["filters"][name]["rmse"]["tot"]["runs"]
    with np.load(est) as npz:
        assert npz["dteskf_mean"].shape == (2, 60, 4, 6) and npz["cteskf_cov"].shape == (2, 60, 1, 6, 6)


@pytest.mark.parametrize(
    "args, message",
    [
        (["sim", "--filter", "dkf"], "unknown filter"),
        (["sim", "--runs", "0"], "at least 1"),
        (["sim", "--qbar", "-1"], "positive"),
        (["sim", "--scenario", "mars"], "invalid choice"),
        (["bench", "paper000", "--runs", "x"], "whole number"),
    ],
)
def test_bad_arguments_exit_2_with_a_message(args, message, capsys):
    with pytest.raises(SystemExit) as exc:
        run_cli(*args)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_bad_scenario_file_is_one_clear_line(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"\x00garbage")
    assert run_cli("sim", "--scenario-file", str(bad)) == 2
    err = capsys.readouterr().err
    assert "bad.npz" in err and "not a readable" in err and "Traceback" not in err
    assert run_cli("sim", "--scenario-file", str(tmp_path / "missing.npz")) == 2
    assert "no such scenario file" in capsys.readouterr().err
    assert run_cli("bench", "paper000", "--experiments", "3") == 2


def test_bench_paper000_prints_both_tables(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert run_cli("bench", "paper000", "--runs", "2", "--steps", "40", "--json", str(out)) == 0
    text = capsys.readouterr().out
    assert "Table 2" in text and "Table 3" in text and "Shape checks" in text
    for name in ("CTESKF", "DTESKF", "DEKF", "DUKF", "DCKF", "DESKF", "CUKF"):
        assert name in text
    data = json.loads(out.read_text())
    assert data["experiments"]["2"]["filters"]["dteskf"]["paper"]["p"] == 6.7649
    assert len(data["experiments"]["1"]["filters"]["cteskf"]["rmse"]["tot"]["runs"]) == 2


def test_bench_speed_reports_ratios(tmp_path, capsys):
    pytest.importorskip("filterpy", reason="FilterPy is the benchmark-only extra (pip install '.[bench]')")
    out = tmp_path / "speed.json"
    assert run_cli("bench", "speed", "--nodes", "3", "--steps", "20", "--runs", "2", "--rounds", "1",
                   "--single-steps", "20", "--json", str(out)) == 0
    data = json.loads(out.read_text())
    assert data["batched"]["dteskf"]["us_per_node_step_R1"] > 0
    assert set(data["ratios"]) >= {"teskf_filter_step / filterpy_ekf", "ukf_filter_step / filterpy_ukf"}
    assert data["single_node"]["agreement"]["ekf_vs_filterpy_max_abs"] < 1e-8  # same EKF, same data


def test_console_script_entry_point(tmp_path):
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, "-m", "zentrack", "sim", "--steps", "20", "--nodes", "3"],
                          capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "dteskf" in proc.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "--scenario", "exp9", "--out", "x"], "built-in scenarios are"),
        (["run", "--scenario-file", "missing.npz", "--out", "x"], "no such scenario file"),
        (["node", "--id", "99", "--scenario", "exp2"], "outside the scenario"),
        (["node", "--id", "0", "--scenario", "exp2", "--lease-ms", "5", "--run", "t"], "--lease-ms"),
        (["truth", "--scenario", "exp2", "--zenoh-config", "missing.json5"], "not a valid Zenoh config"),
    ],
)
def test_process_commands_reject_bad_values_before_starting(args, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert run_cli(*args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


def test_bad_run_name_and_deadline_are_argument_errors(capsys):
    for args in (["node", "--id", "0", "--run", "a/b"], ["node", "--id", "0", "--deadline-frac", "1.5"],
                 ["run", "--nodes", "0", "--out", "x"]):
        with pytest.raises(SystemExit) as exc:
            run_cli(*args)
        assert exc.value.code == 2
    assert "must be" in capsys.readouterr().err
