"""``zentrack bench multitarget``: every method and GOSPA part in the JSON, the parts adding up, the centralized tracker
beating a lone node, Stone Soup's rows (GNN and JPDA) with the aims against its best, and bad flags refused in one
line.

A short bench (2 runs x 30 steps of ``mt-crossing``) of zentrack's three methods is run once for the module; Stone
Soup's tracker, about a hundred times slower per scan, gets a run of its own over a few steps.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from zentrack.bench.multitarget import PARTS, ZENTRACK_METHODS, scenario_settings
from zentrack.cli import main
from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.study.stonesoup_multitarget import run_stonesoup

ZENTRACK_METHODS = list(ZENTRACK_METHODS)


@pytest.fixture(scope="module")
def short_bench(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("bench") / "mt.json"
    assert main(["bench", "multitarget", "--runs", "2", "--steps", "30", "--methods", ",".join(ZENTRACK_METHODS),
                 "--json", str(out)]) == 0
    assert out.with_suffix(".png").exists() and out.with_suffix(".svg").exists()
    return json.loads(out.read_text())


def test_the_json_has_every_method_with_every_part(short_bench):
    assert list(short_bench["methods"]) == ZENTRACK_METHODS
    assert short_bench["runs"] == 2 and short_bench["steps"] == 30 and short_bench["nodes"] == 8
    for method, row in short_bench["methods"].items():
        for key in ("gospa", "rms_gospa", *PARTS, "switches", "fragmentations", "ms_per_scan"):
            assert np.isfinite(row[key]) and row[key] >= 0, (method, key)
        assert len(row["gospa_over_time"]) == 30
        # the longest run of one false track anywhere: a count of steps, 0 only where no track was ever false
        assert isinstance(row["longest_false"], int) and 0 <= row["longest_false"] <= 30, method
        assert (row["longest_false"] == 0) == (row["false"] == 0), method
        assert len(row["per_node_gospa"]) == (8 if method in ("alone", "distributed", "pmbm-distributed") else 1)
    assert set(short_bench["aims"]) >= {"distributed_over_centralized", "every_node_better_than_alone",
                                        "pmbm_distributed_over_pmbm", "every_pmbm_node_better_than_alone"}
    rows = short_bench["methods"]
    assert short_bench["aims"]["pmbm_distributed_over_pmbm"] == pytest.approx(rows["pmbm-distributed"]["gospa"]
                                                                              / rows["pmbm"]["gospa"])


def test_the_gospa_parts_add_up_to_the_mean_squared_gospa(short_bench):
    """GOSPA^2 = localisation + missed + false at every step (Rahmathullah et al. 2017, Prop. 1), so the mean squared
    parts add up to the mean squared GOSPA, and the mean GOSPA is at most its RMS."""
    for method, row in short_bench["methods"].items():
        total = sum(row[part] for part in PARTS)
        assert total == pytest.approx(row["mean_squared_gospa"], rel=1e-9), method
        assert row["gospa"] <= row["rms_gospa"] + 1e-9
        if method not in ("pmbm", "pmbm-distributed"):  # M of N: the first steps, before any track is confirmed
            assert row["missed"] > 0


def test_the_centralized_tracker_beats_every_lone_node(short_bench):
    """mt-crossing puts every target in every sensor's view (range 2.5 km around a 600 m crossing), and the eight
    sensors have equal noise: the centralized tracker gets eight returns of a target per step where a lone node gets
    one, so its position error variance is near an eighth of a lone node's (information adds). Its localisation
    part must then be below half a lone node's (a loose margin for P_D and the start), and its GOSPA below every
    lone node's (missed and false parts are about equal: both confirm after the same M of N steps)."""
    alone, central = short_bench["methods"]["alone"], short_bench["methods"]["centralized"]
    assert central["localisation"] < alone["localisation"] / 2
    assert central["gospa"] < min(alone["per_node_gospa"])


def test_stonesoup_has_its_row(tmp_path):
    out = tmp_path / "ss.json"
    assert main(["bench", "multitarget", "--runs", "1", "--steps", "4", "--methods", "centralized,stonesoup",
                 "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["stonesoup"] and list(result["methods"]) == ["centralized", "stonesoup"]
    row = result["methods"]["stonesoup"]
    assert row["ms_per_scan"] > 0 and sum(row[p] for p in PARTS) == pytest.approx(row["mean_squared_gospa"])
    assert result["aims"]["centralized_ms_per_scan_below_stonesoup"] is not None


def test_stonesoups_jpda_has_its_row_and_the_aims_are_taken_against_the_better_peer(tmp_path):
    out = tmp_path / "ss.json"
    assert main(["bench", "multitarget", "--runs", "1", "--steps", "4", "--methods",
                 "centralized,distributed,pmbm,stonesoup,stonesoup-jpda", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    rows, aims = result["methods"], result["aims"]
    assert list(rows) == ["distributed", "centralized", "pmbm", "stonesoup", "stonesoup-jpda"]
    best = min(("stonesoup", "stonesoup-jpda"), key=lambda m: rows[m]["gospa"])
    assert aims["stonesoup_best"] == best
    for m in ("centralized", "pmbm", "distributed"):
        assert aims[f"{m}_over_stonesoup_best"] == pytest.approx(rows[m]["gospa"] / rows[best]["gospa"])
    slowest_ours = max(rows[m]["ms_per_scan"] for m in ("centralized", "distributed", "pmbm"))
    fastest_peer = min(rows[m]["ms_per_scan"] for m in ("stonesoup", "stonesoup-jpda"))
    assert aims["least_speedup_over_stonesoup"] == pytest.approx(fastest_peer / slowest_ours)


def test_stonesoups_jpda_weighs_the_returns_it_does_not_assign():
    """On the same scans as its GNN row, Stone Soup's JPDA holds the same tracks at almost the same places (the
    returns of four well-apart targets, 5 clutter returns a scan in 2.5 km), but not the same: its update is the
    mixture of every return in the gate, weighed by its association probability, where the GNN takes one."""
    cfg = load_scenario_config("mt-crossing", multitarget=True)
    settings, _ = scenario_settings(cfg)
    resize(cfg, steps=4)
    data = cfg.multitarget_data(0)
    gnn, jpda = run_stonesoup(data, settings, "gnn"), run_stonesoup(data, settings, "jpda")
    assert (gnn.method, jpda.method) == ("stonesoup", "stonesoup-jpda")
    apart = []
    for (_, a), (_, b) in zip(gnn.views[0], jpda.views[0]):
        assert a.shape == b.shape == (4, 3)
        d = np.linalg.norm(a[:, None] - b[None], axis=-1)
        rows, cols = linear_sum_assignment(d)
        apart.append(d[rows, cols].max())
    assert max(apart) < 0.01 and max(apart) > 1e-9, apart
    with pytest.raises(ValueError, match="association"):
        run_stonesoup(data, settings, "mht")


@pytest.mark.parametrize(("flags", "says"), [
    (["--runs", "0"], "--runs"),
    (["--steps", "-3"], "--steps"),
    (["--methods", "alone,nope"], "nope"),
    (["--scenario", "exp2"], "not a many-target scenario"),
    (["--scenario", "no-such-scenario"], "no-such-scenario"),
    (["--frobnicate"], "--frobnicate"),
])
def test_bad_flags_exit_2_with_one_line(flags, says, capsys):
    with pytest.raises(SystemExit) as exc:
        code = main(["bench", "multitarget", *flags])
        raise SystemExit(code)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err, err
