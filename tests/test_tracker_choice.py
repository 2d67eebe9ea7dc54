"""Choosing a many-target node's tracker (issue 53): ``[tracker] kind`` in a scenario file and ``zentrack run
--tracker``, carried to every node's configuration slice; what cannot run a PMBM tracker (bearing or mixed sensors,
sensors of their own, one target) refused in one line naming the key or flag, exit status 2 for the CLI."""
from __future__ import annotations

import pytest

from zentrack.cli import main
from zentrack.config.node_config import NodeConfigError
from zentrack.config.run_setup import scenario_setup
from zentrack.config.scenario_config import ScenarioConfigError, parse, resolve


def with_tracker(name: str, extra: str) -> str:
    """A catalogue file's text with its ``[tracker]`` section's body ``extra`` (added, or in place of its own)."""
    text = resolve(name)[1]
    if "\n[tracker]\n" in text:
        head, rest = text.split("\n[tracker]\n", 1)
        return head + "\n[tracker]\n" + extra + "\n" + rest.split("\n", 1)[1]
    return text + "\n[tracker]\n" + extra + "\n"


def config(name: str, extra: str):
    return parse(f"{name}.toml", with_tracker(name, extra))


def test_a_scenario_names_its_nodes_tracker_and_every_slice_carries_it():
    cfg = config("mt-crossing", 'kind = "pmbm"')
    assert cfg.tracker == "pmbm"
    assert parse("x.toml", resolve("mt-crossing")[1]).tracker == "gnn"  # the default
    setup = scenario_setup("mt-crossing")
    assert setup.tracker == "gnn" and setup.node_config(3).multitarget["tracker"] == "gnn"


@pytest.mark.parametrize(("name", "extra", "why"), [
    ("mt-bearing", 'kind = "pmbm"', "point sensors only"),
    ("mt-async", 'kind = "pmbm"', "sensors of their own"),
    ("mt-crossing", 'kind = "jpda"', "jpda"),
    ("patrol", 'kind = "gnn"', "only a many-target scenario"),
])
def test_a_tracker_a_scenario_cannot_run_is_refused_naming_the_key(name, extra, why):
    with pytest.raises(ScenarioConfigError) as err:
        config(name, extra)
    text = str(err.value)
    assert ": tracker.kind: " in text and why in text and "\n" not in text, text


@pytest.mark.parametrize(("argv", "why"), [
    (["--scenario", "mt-bearing", "--tracker", "pmbm"], "point sensors only"),
    (["--scenario", "patrol", "--tracker", "pmbm"], "only a many-target scenario"),
    (["--scenario", "mt-crossing", "--tracker", "jpda"], "invalid choice"),
])
def test_run_refuses_a_tracker_it_cannot_run_in_one_line(argv, why, tmp_path, capsys):
    try:
        code = main(["run", *argv, "--steps", "3", "--out", str(tmp_path / "out")])
    except SystemExit as exc:  # (argparse's own refusal of a choice)
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert why in err[-1], err
    assert not (tmp_path / "out").exists()  # nothing started, nothing written


def test_the_flag_wins_over_the_scenario_and_a_forged_slice_is_refused(tmp_path):
    path = tmp_path / "mt-pmbm.toml"
    path.write_text(with_tracker("mt-crossing", 'kind = "pmbm"'))
    assert scenario_setup(str(path)).tracker == "pmbm"
    assert scenario_setup(str(path), tracker="gnn").node_config(0).multitarget["tracker"] == "gnn"
    cfg = scenario_setup("mt-crossing", tracker="pmbm").node_config(0)
    assert cfg.multitarget["tracker"] == "pmbm"
    cfg.multitarget["tracker"] = "magic"
    with pytest.raises(NodeConfigError, match=r"multitarget.tracker: must be one of gnn, pmbm, got 'magic'"):
        cfg.validate()


def test_pmbm_nodes_share_their_scans_unless_told_not_to(tmp_path):
    assert scenario_setup("mt-crossing", tracker="pmbm").node_config(0).multitarget["share_scans"] is True
    assert scenario_setup("mt-crossing").node_config(0).multitarget["share_scans"] is False
    path = tmp_path / "mt.toml"
    path.write_text(with_tracker("mt-crossing", 'kind = "pmbm"\nshare_scans = false'))
    assert scenario_setup(str(path)).node_config(0).multitarget["share_scans"] is False
    import argparse

    from zentrack.config.run_setup import resolve_setup
    from zentrack.config.scenario_flags import add_scenario_arguments

    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    setup = resolve_setup(p.parse_args(["--scenario", "mt-crossing", "--share-scans"]))  # GNN nodes sharing
    assert setup.node_config(0).multitarget == {**setup.node_config(0).multitarget, "tracker": "gnn",
                                                "share_scans": True}
    with pytest.raises(ValueError, match="--share-scans: nodes share the scans of each step; sensors of their own"):
        resolve_setup(p.parse_args(["--scenario", "mt-async", "--share-scans"]))
    with pytest.raises(ScenarioConfigError, match=r"tracker.share_scans: must be true or false, got 'yes'"):
        config("mt-crossing", 'kind = "gnn"\nshare_scans = "yes"')
    cfg = setup.node_config(0)
    cfg.multitarget["share_scans"] = 1
    with pytest.raises(NodeConfigError, match=r"multitarget.share_scans: must be true or false, got 1"):
        cfg.validate()
