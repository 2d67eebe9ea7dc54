"""One vocabulary: the same filter, fusion-rule and scenario names in every command, ``--timing`` for the run's
timing and ``--zenoh-mode`` for the Zenoh mode everywhere; the old spellings work for one release, each with one
deprecation line on stderr."""
from __future__ import annotations

import argparse
import json

import pytest

from zentrack.cli import build_parser, main
from zentrack.config.run_setup import resolve_setup
from zentrack.fusion.defaults import CENTRALIZED
from zentrack.fusion.filters import FILTER_REGISTRY
from zentrack.fusion.rules import RULE_REGISTRY

PROCESS_COMMANDS = {"truth": [], "node": ["--id", "0"], "viewer": [], "record": ["--out", "x"], "status": [],
                    "health": []}


def parse(argv: list[str]) -> argparse.Namespace:
    return build_parser(argv).parse_args(argv)


def subcommand_help(command: str) -> str:
    parser = build_parser([command])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    return " ".join(sub.format_help().split())


def warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if "deprecated" in line]


def test_run_mode_is_the_old_name_of_timing(capsys):
    new = parse(["run", "--timing", "lockstep", "--out", "x"])
    assert capsys.readouterr().err == ""
    old = parse(["run", "--mode", "lockstep", "--out", "x"])
    assert vars(old) == vars(new)
    (line,) = warnings(capsys.readouterr().err)
    assert line == "zentrack run: warning: --mode lockstep is deprecated and goes in the next release; use --timing lockstep"
    assert "--timing" in subcommand_help("run") and "--mode" not in subcommand_help("run")


@pytest.mark.parametrize("command", sorted(PROCESS_COMMANDS))
def test_a_process_commands_mode_is_the_old_name_of_zenoh_mode(command, capsys):
    extra = PROCESS_COMMANDS[command]
    new = parse([command, *extra, "--zenoh-mode", "client"])
    assert capsys.readouterr().err == "" and new.zenoh_mode == "client"
    old = parse([command, *extra, "--mode", "client"])
    assert vars(old) == vars(new)
    (line,) = warnings(capsys.readouterr().err)
    assert line.startswith(f"zentrack {command}: warning: --mode client is deprecated") and "--zenoh-mode client" in line
    text = subcommand_help(command)
    assert "--zenoh-mode {peer,client,router}" in text and "--mode" not in text
    if command in ("truth", "node"):
        assert "--timing {realtime,lockstep}" in text


def test_the_generated_and_scripted_command_lines_use_the_new_flags():
    from pathlib import Path

    from zentrack.cluster.compose import render

    root = Path(__file__).resolve().parent.parent
    texts = [render(4), render(4, secure=True), render(6, hosts=2)]
    texts += [(root / "deploy" / f).read_text() for f in ("docker-compose.yml", "docker-compose.secure.yml",
                                                          "docker-compose.hosts.yml", "quickstart.sh")]
    for text in texts:
        assert '"--mode"' not in text and "--mode " not in text and "ZENTRACK_MODE" not in text
    assert '"--zenoh-mode", "client"' in texts[0] and "ZENTRACK_ZENOH_MODE" in texts[0]
    script = (root / "deploy" / "cluster.sh").read_text()
    assert script.count("--mode client") == 0 and script.count("--zenoh-mode client") == 3


def test_sims_old_combined_names_are_aliases_of_filter_and_fusion(tmp_path, capsys):
    old_json, new_json = tmp_path / "old.json", tmp_path / "new.json"
    common = ["sim", "--scenario", "exp2", "--nodes", "4", "--steps", "40", "--runs", "2"]
    assert main([*common, "--filter", "teskf", "--fusion", "ci,centralized", "--json", str(new_json)]) == 0
    assert warnings(capsys.readouterr().err) == []
    assert main([*common, "--filter", "dteskf,cteskf", "--json", str(old_json)]) == 0
    lines = warnings(capsys.readouterr().err)
    assert lines == ["zentrack sim: warning: --filter dteskf is deprecated and goes in the next release; use --filter "
                     "teskf --fusion RULE",
                     "zentrack sim: warning: --filter cteskf is deprecated and goes in the next release; use --filter "
                     "teskf --fusion centralized"]
    old, new = json.loads(old_json.read_text())["filters"], json.loads(new_json.read_text())["filters"]
    assert list(old) == ["dteskf", "cteskf"] and list(new) == ["teskf+ci", "teskf+centralized"]
    for a, b in (("dteskf", "teskf+ci"), ("cteskf", "teskf+centralized")):
        assert old[a]["rmse"] == new[b]["rmse"] and old[a]["anees"] == new[b]["anees"]
        assert (old[a]["filter"], old[a]["fusion"]) == (new[b]["filter"], new[b]["fusion"])


def test_run_takes_sims_distributed_name_and_refuses_its_centralized_one_in_one_line(capsys):
    args = parse(["run", "--filter", "dukf", "--out", "x"])
    assert args.filter_kind == "ukf"
    assert warnings(capsys.readouterr().err) == ["zentrack: warning: --filter dukf is deprecated and goes in the next "
                                                 "release; use --filter ukf (the fusion rule comes from --fusion)"]
    with pytest.raises(SystemExit) as done:
        parse(["run", "--filter", "cukf", "--out", "x"])
    err = capsys.readouterr().err.strip()
    assert done.value.code == 2 and len(err.splitlines()) == 1 and "only in the batched simulator" in err, err


def test_every_command_takes_the_same_filter_and_rule_names(capsys):
    for name in FILTER_REGISTRY.names():
        assert parse(["run", "--filter", name, "--out", "x"]).filter_kind == name
        assert parse(["node", "--id", "0", "--filter", name]).filter_kind == name
        assert parse(["sim", "--filter", name]).filter == [(name, None, None)]
    for rule in (*RULE_REGISTRY.names(), CENTRALIZED):
        assert parse(["run", "--fusion", rule, "--out", "x"]).fusion == rule
        assert parse(["truth", "--fusion", rule]).fusion == rule
        assert parse(["sim", "--fusion", rule]).fusion == [rule]
    assert warnings(capsys.readouterr().err) == []
    setup = resolve_setup(parse(["run", "--scenario", "exp2", "--filter", "ukf", "--fusion", "ci-fast", "--nodes", "3",
                                 "--steps", "5", "--out", "x"]))
    assert (setup.filter_kind, setup.fusion) == ("ukf", "ci-fast")
    assert main(["sim", "--list-filters"]) == 0
    listing = capsys.readouterr().out
    for name in (*FILTER_REGISTRY.names(), *RULE_REGISTRY.names(), CENTRALIZED):
        assert f"  {name}: " in listing, name
    assert "--filter <name> in sim, run, node, truth" in listing and "d<name>|c<name>" not in listing


def test_rounds_and_parameters_reach_every_rule_of_a_sim_and_none_reach_the_centre(tmp_path, capsys):
    out = tmp_path / "sim.json"
    assert main(["sim", "--nodes", "4", "--steps", "20", "--filter", "teskf", "--fusion", "ci,ci-fast,centralized",
                 "--rounds", "2", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["filters"]
    assert [rows[r]["fusion_params"].get("rounds") for r in rows] == [2, 2, None]
    assert main(["sim", "--fusion", "centralized", "--rounds", "2", "--steps", "5"]) == 2
    assert "no fusion rule to take them" in capsys.readouterr().err
    assert main(["sim", "--fusion", "ci,independent", "--rounds", "2", "--steps", "5"]) == 2
    assert "'independent' has no 'rounds' parameter" in capsys.readouterr().err
