"""``zentrack bench multitarget``: every method and GOSPA part in the JSON, the parts adding up, the centralized tracker
beating a lone node, Stone Soup's row, and bad flags refused in one line.

A short bench (2 runs x 30 steps of ``mt-crossing``) of zentrack's three methods is run once for the module; Stone
Soup's tracker, about a hundred times slower per scan, gets a run of its own over a few steps.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from zentrack.bench.multitarget import METHODS, PARTS
from zentrack.cli import main

ZENTRACK_METHODS = [m for m in METHODS if m != "stonesoup"]


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
        assert len(row["per_node_gospa"]) == (8 if method in ("alone", "distributed") else 1)
    assert set(short_bench["aims"]) >= {"distributed_over_centralized", "every_node_better_than_alone"}


def test_the_gospa_parts_add_up_to_the_mean_squared_gospa(short_bench):
    """GOSPA^2 = localisation + missed + false at every step (Rahmathullah et al. 2017, Prop. 1), so the mean squared
    parts add up to the mean squared GOSPA, and the mean GOSPA is at most its RMS."""
    for method, row in short_bench["methods"].items():
        total = sum(row[part] for part in PARTS)
        assert total == pytest.approx(row["mean_squared_gospa"], rel=1e-9), method
        assert row["gospa"] <= row["rms_gospa"] + 1e-9
        assert row["missed"] > 0  # the first steps, before any track is confirmed


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
