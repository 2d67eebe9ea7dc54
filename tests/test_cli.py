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
    assert run_cli("sim", "--scenario", "exp2", "--nodes", "4", "--steps", "60", "--runs", "2", "--filter", "teskf",
                   "--fusion", "ci,centralized", "--save-scenario", str(scn_path), "--json", str(out1)) == 0
    text = capsys.readouterr().out
    assert "teskf+ci" in text and "teskf+centralized" in text and "RMSE p" in text
    a = json.loads(out1.read_text())
    assert a["runs"] == 2 and set(a["filters"]) == {"teskf+ci", "teskf+centralized"}
    assert len(a["filters"]["teskf+ci"]["rmse"]["p"]["runs"]) == 2
    assert a["filters"]["teskf+ci"]["us_per_node_step"] > 0
    assert (a["filters"]["teskf+ci"]["filter"], a["filters"]["teskf+ci"]["fusion"]) == ("teskf", "ci")
    assert run_cli("sim", "--scenario-file", str(scn_path), "--filter", "teskf", "--fusion", "ci,centralized",
                   "--json", str(out2), "--save-estimates", str(est)) == 0
    b = json.loads(out2.read_text())
    for name in ("teskf+ci", "teskf+centralized"):
        assert a["filters"][name]["rmse"]["tot"]["runs"] == b["filters"][name]["rmse"]["tot"]["runs"]
    with np.load(est) as npz:
        assert npz["teskf+ci_mean"].shape == (2, 60, 4, 6) and npz["teskf+centralized_cov"].shape == (2, 60, 1, 6, 6)


def exit_code(args: list[str]) -> int:
    """The exit status of ``zentrack ARGS`` run in-process: argparse's SystemExit or main's return value.
    Any other exception propagates, so a bad value that ends in a traceback fails the test."""
    try:
        return run_cli(*args)
    except SystemExit as exc:
        return exc.code


# (arguments, the option at fault): the one error line must name the option and echo the bad value
BAD_ARGUMENTS = [
    (["sim", "--filter", "dkf"], "--filter"),
    (["sim", "--filter", ""], "--filter"),
    (["sim", "--runs", "0"], "--runs"),
    (["sim", "--runs", "-3"], "--runs"),
    (["sim", "--runs", "1.5"], "--runs"),
    (["sim", "--nodes", "0"], "--nodes"),
    (["sim", "--steps", "x"], "--steps"),
    (["sim", "--qbar", "-1"], "--qbar"),
    (["sim", "--qbar", "nan"], "--qbar"),
    (["sim", "--qbar", "inf"], "--qbar"),
    (["sim", "--theta", "0"], "--theta"),
    (["sim", "--scenario", "mars"], "--scenario"),
    (["sim", "--fusion", "magic"], "--fusion"),
    (["sim", "--seed", "x"], "--seed"),
    (["bench", "paper0", "--runs", "x"], "--runs"),
    (["bench", "paper0", "--steps", "0"], "--steps"),
    (["bench", "paper0", "--experiments", "3"], "--experiments"),
    (["bench", "speed", "--nodes", "0"], "--nodes"),
    (["bench", "latency", "--nodes", "0"], "--nodes"),
    (["run", "--nodes", "0", "--out", "x"], "--nodes"),
    (["run", "--timing", "fast", "--out", "x"], "--timing"),
    (["run", "--deadline-frac", "0", "--out", "x"], "--deadline-frac"),
    (["run", "--qbar", "0", "--out", "x"], "--qbar"),
    (["run", "--timeout", "x", "--out", "x"], "--timeout"),
    (["node", "--id", "x"], "--id"),
    (["node", "--id", "0", "--run", "a/b"], "--run"),
    (["node", "--id", "0", "--deadline-frac", "1.5"], "--deadline-frac"),
    (["node", "--id", "0", "--lease-ms", "x"], "--lease-ms"),
    (["node", "--id", "0", "--filter", "pf"], "--filter"),
    (["truth", "--timing", "fast"], "--timing"),
    (["truth", "--wait-timeout", "x"], "--wait-timeout"),
    (["compose", "--nodes", "0"], "--nodes"),
    (["compose", "--steps", "0"], "--steps"),
    (["status", "--timeout", "x"], "--timeout"),
    (["viewer", "--scenario", "exp2", "--flush-s", "x"], "--flush-s"),
    (["soak", "--nodes", "0", "--out", "x"], "--nodes"),
    (["sim", "--fusion-param", "share_scans"], "--fusion-param"),
    (["run", "--fusion", "ci", "--fusion-param", "relay_scans=true", "--out", "x"], "--fusion"),  # needs share_scans
]


@pytest.mark.parametrize("args, option", BAD_ARGUMENTS, ids=[" ".join(a[0]) for a in BAD_ARGUMENTS])
def test_bad_arguments_exit_2_naming_the_option(args, option, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing may be written, but if it is, not into the repository
    assert exit_code(args) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line]
    assert len(errors) == 1, err
    value = args[args.index(option) + 1]
    assert option in errors[0] and (repr(value) in errors[0] or f" {value}" in errors[0]), err
    assert "Traceback" not in err
    assert not any(tmp_path.iterdir()), "a rejected command must not create files"


@pytest.mark.parametrize("args, option", [(["sim", "--runs", "0"], "--runs"),
                                          (["node", "--id", "0", "--lease-ms", "5", "--run", "t"], "--lease-ms"),
                                          (["bench", "paper0", "--experiments", "3"], "--experiments")])
def test_bad_arguments_from_the_console_script_print_no_traceback(args, option, tmp_path):
    """The same through a real process, so an exception escaping main() would show as a Traceback."""
    proc = subprocess.run([sys.executable, "-m", "zentrack", *args], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert option in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_bad_scenario_file_is_one_clear_line(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"\x00garbage")
    assert run_cli("sim", "--scenario-file", str(bad)) == 2
    err = capsys.readouterr().err
    assert "bad.npz" in err and "not a readable" in err and "Traceback" not in err
    assert run_cli("sim", "--scenario-file", str(tmp_path / "missing.npz")) == 2
    assert "no such scenario file" in capsys.readouterr().err
    assert run_cli("bench", "paper0", "--experiments", "3") == 2


def test_bench_paper0_prints_both_tables(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert run_cli("bench", "paper0", "--runs", "2", "--steps", "40", "--json", str(out)) == 0
    text = capsys.readouterr().out
    assert "Table 2" in text and "Table 3" in text and "Shape checks" in text
    for name in ("CTESKF", "DTESKF", "DEKF", "DUKF", "DCKF", "DESKF", "CUKF"):
        assert name in text
    data = json.loads(out.read_text())
    assert data["experiments"]["2"]["filters"]["dteskf"]["paper"]["p"] == 6.7649
    assert len(data["experiments"]["1"]["filters"]["cteskf"]["rmse"]["tot"]["runs"]) == 2
    assert "p/sqrt(B)" in text and "x1/sqrt(B)" in text
    ratio = data["experiments"]["2"]["filters"]["dteskf"]["rmse_over_sqrt_bound"]["p"]
    assert len(ratio["runs"]) == 2 and all(r > 1.0 for r in ratio["runs"])  # a distributed filter, above the bound


def test_bench_paper1_reports_local_and_fused_rmse_beside_the_bound(tmp_path, capsys):
    out = tmp_path / "p1.json"
    assert run_cli("bench", "paper1", "--runs", "2", "--steps", "16", "--json", str(out)) == 0
    text = capsys.readouterr().out
    assert "sqrt(PCRLB)" in text and "lambda*V_gate" in text and "us per particle-step" in text
    data = json.loads(out.read_text())
    assert set(data["filters"]) == {"pda-fpf", "pda-pf", "pdaf-ekf", "nn-ekf", "pda-fpf+ci"}
    for row in data["filters"].values():
        assert len(row["local_rmse_p"]) == 3 and row["fused_rmse_p_over_sqrt_bound"] > 0
        assert row["fused_rmse_p_over_sqrt_bound_per_run"]["n"] == data["runs"]
        assert isinstance(row["fused_beats_every_local"], bool)
    assert 0 < min(data["information_reduction_factor"]) <= max(data["information_reduction_factor"]) < 1
    assert len(data["sqrt_pcrlb_per_step"]["p"]) == 16 and len(data["curves"]["pda-fpf"]["fused_v"]) == 16
    assert (tmp_path / "p1.png").stat().st_size > 10_000


def test_bench_paper2_reports_the_comparison_the_ranking_and_rmse_against_l(tmp_path, capsys):
    out = tmp_path / "p2.json"
    assert run_cli("bench", "paper2", "--runs", "2", "--steps", "24", "--scenarios", "dce-ici",
                   "--json", str(out)) == 0
    text = capsys.readouterr().out
    assert "paper: DCE-ICI" in text and "684.19" in text and "sqrt(PCRLB)" in text
    data = json.loads(out.read_text())
    sc = data["scenarios"]["dce-ici"]
    assert set(sc["rows"]) == {"local", "ci-centre", "fci-centre", "diff-fci", "diff-ici", "dce-fci", "dce-ici",
                               "dce-ici-metropolis", "ici-centre", "centralized"}
    for row in sc["rows"].values():
        assert row["rmse_p"] > 0 and row["anees"] > 0 and len(row["curve_p"]) == 24
        assert row["rmse_p_over_sqrt_bound_per_run"]["n"] == 2  # each run against its own bound
    assert set(sc["ranking"]) >= {"DCE-ICI < DCE-FCI", "Local worst"}
    assert all(isinstance(v, bool) for v in sc["ranking"].values())
    assert sc["l_star"] == pytest.approx(np.log(7) / np.log(1 / sc["lambda_2"])) and sc["rounds"] >= sc["diameter"]
    assert data["rmse_vs_rounds"]["L"][:3] == [1, 2, 4] and len(data["rmse_vs_rounds"]["rmse_p"]) >= 4
    assert (tmp_path / "p2.png").stat().st_size > 5_000
    assert run_cli("bench", "paper2", "--runs", "1", "--steps", "8", "--scenarios", "dce-ici", "--no-sweep",
                   "--methods", "dce-ici", "--json", str(out)) == 0
    assert set(json.loads(out.read_text())["scenarios"]["dce-ici"]["rows"]) == {"dce-ici"}


def test_bench_speed_reports_ratios(tmp_path, capsys):
    pytest.importorskip("filterpy", reason="FilterPy is the benchmark-only extra (pip install '.[bench]')")
    out = tmp_path / "speed.json"
    assert run_cli("bench", "speed", "--nodes", "3", "--steps", "20", "--runs", "2", "--rounds", "1",
                   "--single-steps", "20", "--json", str(out)) == 0
    data = json.loads(out.read_text())
    assert data["batched"]["dteskf"]["us_per_node_step_R1"] > 0
    assert set(data["ratios"]) >= {"teskf_filter_step / filterpy_ekf", "ukf_filter_step / filterpy_ukf"}
    assert data["single_node"]["agreement"]["ekf_vs_filterpy_max_abs"] < 1e-8  # same EKF, same data
    # the stacked centralized EKF beside FilterPy's on the same stacked measurement: the same estimates
    assert data["ratios"]["centralized_ekf_step / filterpy_stacked_ekf"] > 0
    assert data["single_node"]["agreement"]["centralized_ekf_vs_filterpy_max_abs"] < 1e-8


def test_console_script_entry_point(tmp_path):
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, "-m", "zentrack", "sim", "--steps", "20", "--nodes", "3"],
                          capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "teskf+ci" in proc.stdout


# values only a command's own checks can reject: (arguments, the option, file or value the error names, what it says)
BAD_PROCESS_VALUES = [
    (["run", "--scenario", "exp9", "--out", "x"], "'exp9'", "the catalogue has"),
    (["run", "--scenario-file", "missing.npz", "--out", "x"], "missing.npz", "no such scenario file"),
    (["node", "--id", "99", "--scenario", "exp2"], "node id 99", "outside the scenario"),
    (["node", "--id", "0", "--scenario", "exp2", "--lease-ms", "5", "--run", "t"], "--lease-ms", "at least 100"),
    (["truth", "--scenario", "exp2", "--zenoh-config", "missing.json5"], "missing.json5", "not a valid Zenoh config"),
    (["node", "--id", "0", "--scenario", "exp2", "--connect", "bogus"], "--connect", "not a Zenoh endpoint"),
    (["truth", "--scenario", "exp2", "--listen", "tcp/1.2.3.4:99999"], "--listen", "port from 0 to 65535"),
    (["sim", "--scenario-file", "missing.npz"], "missing.npz", "no such scenario file"),
    (["sim", "--seed", "-1", "--steps", "2", "--nodes", "2"], "--seed", ""),
    (["sim", "--fusion", "hcmci", "--fusion-param", "omega=0.5"], "--fusion-param", "'omega' must be float"),
    (["run", "--fusion", "ci", "--fusion-param", "nope=1", "--out", "x"], "--fusion-param", "no parameter 'nope'"),
    (["status", "--timeout", "nan", "--run", "x"], "--timeout", ""),
]


@pytest.mark.parametrize("args, culprit, message", BAD_PROCESS_VALUES)
def test_process_commands_reject_bad_values_before_starting(args, culprit, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert exit_code(args) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line]
    assert len(errors) == 1, err
    assert culprit in errors[0] and message in errors[0], err
    assert "Traceback" not in err
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


def test_fusion_params_reach_the_rule_in_sim_and_run(tmp_path, capsys):
    """--fusion-param sets a rule's parameter: sharing the scans changes sim's figures, and a run's setup
    carries it to every tracker's configuration."""
    import argparse
    import json

    from zentrack.config.run_setup import resolve_setup
    from zentrack.config.scenario_flags import add_scenario_arguments

    figures = []
    for extra in ([], ["--fusion-param", "share_scans=true"]):
        out = tmp_path / f"sim{len(extra)}.json"
        assert run_cli("sim", "--filter", "eskf", "--fusion", "ci-fast", "--steps", "100", "--nodes", "4",
                       "--json", str(out), *extra) == 0
        figures.append(json.loads(out.read_text()))
    assert [f["fusion_params"] for f in figures] == [{}, {"share_scans": True}]
    rmse = [f["filters"]["eskf+ci-fast"]["rmse"]["p"]["median"] for f in figures]
    assert rmse[1] != rmse[0], "the neighbours' scans change the estimates"
    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    setup = resolve_setup(p.parse_args(["--scenario", "exp2", "--fusion", "hcmci", "--fusion-param", "omega=4",
                                        "--nodes", "3", "--steps", "5"]))
    assert setup.fusion_params == {"omega": 4}
    assert setup.node_config(0).fusion_params["omega"] == 4


def test_a_run_whose_trackers_all_failed_fails_at_once(tmp_path):
    """The truth would wait for its join timeout; the orchestrator stops waiting when no tracker is left."""
    from zentrack.cluster.run.cluster import Cluster, RunFailed

    class Proc:
        def __init__(self, code):
            self.returncode = code

        def poll(self):
            return self.returncode

    class Recorder:
        def drain(self, timeout):
            pass

    cluster = Cluster.__new__(Cluster)
    cluster.recorder, cluster.logs_dir = Recorder(), tmp_path / "logs"
    cluster.procs = {"truth": Proc(None), "node-0": Proc(2), "node-1": Proc(2)}
    with pytest.raises(RunFailed, match="every tracker process failed.*node-0 2, node-1 2"):
        cluster.wait(timeout=5)
    for still_there in (None, 0):  # one tracker still running, or done: the run goes on until the timeout
        cluster.procs["node-1"] = Proc(still_there)
        with pytest.raises(TimeoutError):
            cluster.wait(timeout=0.3)
