"""Every key of a scenario file is checked against one schema (zentrack/config/scenario_schema.py): a misspelt
key of any section is refused in one line naming the file, the key and the nearest known key; every known key
passes that check; the docs' list of keys is the schema's; a node's configuration JSON likewise."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from zentrack.cli import main
from zentrack.config import catalogue
from zentrack.config.node_config import NodeConfig, NodeConfigError
from zentrack.config.scenario_config import ScenarioConfigError, parse
from zentrack.config.scenario_schema import OPEN_SECTIONS, SCHEMA, keys_markdown

ROOT = Path(__file__).resolve().parents[1]


def _scenario_with(section: str) -> tuple[str, str]:
    """A catalogue scenario that has ``[section]``, and its text."""
    for name in catalogue.names():
        text = catalogue.text(name) or ""
        if re.search(rf"^\[{re.escape(section)}\]\s*$", text, re.M):
            return name, text
    raise AssertionError(f"no catalogue scenario has a [{section}] section")


def _with_key(text: str, section: str, key: str, value: str = "1") -> str:
    return re.sub(rf"^\[{re.escape(section)}\]\s*$", f"[{section}]\n{key} = {value}", text, count=1, flags=re.M)


def _misspelt(key: str) -> str:
    return key + key[-1]  # (a doubled last letter: nearer to its key than to any other)


FIXED = [(section, key) for section, keys in SCHEMA.items() if section not in OPEN_SECTIONS for key in keys]


@pytest.mark.parametrize(("section", "key"), FIXED, ids=[f"{s}.{k}" for s, k in FIXED])
def test_a_misspelt_key_is_refused_naming_the_file_the_key_and_the_nearest(section, key):
    name, text = _scenario_with(section)
    typo = _misspelt(key)
    with pytest.raises(ScenarioConfigError) as err:
        parse(f"{name}.toml", _with_key(text, section, typo))
    message = str(err.value)
    assert message.startswith(f"{name}.toml: {section}.{typo}: unknown key"), message
    assert f"did you mean {key!r}?" in message, message
    assert "\n" not in message


@pytest.mark.parametrize(("section", "key"), FIXED, ids=[f"{s}.{k}" for s, k in FIXED])
def test_every_known_key_passes_the_key_check(section, key):
    name, text = _scenario_with(section)
    if re.search(rf"^{re.escape(key)}\s*=", text.split(f"[{section}]", 1)[1].split("\n[", 1)[0], re.M):
        parse(f"{name}.toml", text)  # (the scenario already sets it: it parses)
        return
    try:
        parse(f"{name}.toml", _with_key(text, section, key))
    except ScenarioConfigError as exc:  # (a value that does not fit is refused, but never as an unknown key)
        assert "unknown key" not in str(exc), exc


def test_the_issues_misspelling_says_what_it_should():
    text = _with_key(catalogue.text("exp2"), "graph", "self_weigth", "0.9")
    with pytest.raises(ScenarioConfigError, match=r"graph\.self_weigth: unknown key; did you mean 'self_weight'\?"):
        parse("mine.toml", text)
    with pytest.raises(ScenarioConfigError, match=r"measurement\.noise_sd: unknown key; did you mean 'noise_std'\?"):
        parse("mine.toml", _with_key(catalogue.text("exp2"), "measurement", "noise_sd", "0.01"))


def test_a_misspelt_section_plant_filter_or_fusion_parameter_gets_the_nearest():
    exp2 = catalogue.text("exp2")
    with pytest.raises(ScenarioConfigError, match=r"grahp: unknown section; did you mean 'graph'\?"):
        parse("mine.toml", exp2 + "\n[grahp]\nkind = \"ring\"\n")
    plant = _scenario_with("plant")[1]
    with pytest.raises(ScenarioConfigError, match=r"did you mean"):
        parse("mine.toml", _with_key(plant, "plant", _misspelt(next(iter(tomllib_section(plant, "plant"))))))
    with pytest.raises(ScenarioConfigError, match=r"no parameter 'qbarr'.*did you mean 'qbar'\?"):
        parse("mine.toml", _with_key(exp2, "filter", "qbarr", "1e-6"))
    with pytest.raises(ScenarioConfigError, match=r"no parameter 'roundz'.*did you mean 'rounds'\?"):
        parse("mine.toml", exp2 + "\n[fusion]\nrule = \"ci\"\nroundz = 2\n")


def tomllib_section(text: str, section: str) -> dict:
    import tomllib

    return tomllib.loads(text)[section]


def test_a_run_of_a_misspelt_file_exits_2_with_one_line_and_starts_nothing(tmp_path, capsys):
    path = tmp_path / "mine.toml"
    path.write_text(_with_key(catalogue.text("exp2"), "graph", "self_weigth", "0.9"))
    out = tmp_path / "run"
    try:
        code = main(["run", "--scenario", str(path), "--nodes", "4", "--steps", "20", "--out", str(out)])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "self_weigth" in err[0] and "did you mean 'self_weight'?" in err[0], err
    assert not (out / "summary.json").exists() and not (out / "logs").exists(), "nothing was started"


def test_the_docs_list_of_keys_is_the_schemas(monkeypatch):
    """The page is the schema's and zentrack's own filters and rules, whatever plug-in this process loaded."""
    from zentrack.fusion.rules import RULE_REGISTRY

    monkeypatch.syspath_prepend(str(ROOT / "tests" / "plugins"))
    import scan_exchange_rule  # noqa: F401 - registers the plug-in rule "ci-scans"

    assert "ci-scans" in RULE_REGISTRY.names()
    assert (ROOT / "docs" / "scenario-keys.md").read_text() == keys_markdown(), \
        "regenerate: zentrack scenarios --keys > docs/scenario-keys.md"


def test_a_node_configuration_with_an_unknown_key_is_refused_with_the_nearest(tmp_path):
    import argparse

    from zentrack.config.run_setup import resolve_setup
    from zentrack.config.scenario_flags import add_scenario_arguments

    p = argparse.ArgumentParser()
    add_scenario_arguments(p)
    good = json.loads(resolve_setup(p.parse_args(["--scenario", "exp2", "--nodes", "3"])).node_config(0).to_json())
    NodeConfig.from_json(json.dumps(good))
    for where, doc, typo, near in [
        ("top", {**good, "neighbourz": good["neighbours"]}, "neighbourz", "neighbours"),
        ("sensor", {**good, "sensor": {**good["sensor"], "noise_covv": 1.0}}, "sensor.noise_covv", "noise_cov"),
    ]:
        with pytest.raises(NodeConfigError) as err:
            NodeConfig.from_json(json.dumps(doc), "node-0.json")
        assert str(err.value).startswith(f"node-0.json: {typo}: unknown key; did you mean {near!r}?"), (where, err.value)


def test_a_mistyped_choice_in_a_scenario_gets_the_nearest():
    exp2 = catalogue.text("exp2")
    with pytest.raises(ScenarioConfigError, match=r"filter\.kind: 'tesfk' is not allowed.*did you mean 'teskf'\?"):
        parse("mine.toml", exp2.replace('kind = "teskf"', 'kind = "tesfk"'))
    with pytest.raises(ScenarioConfigError, match=r"timing\.mode: 'realtme' is not allowed.*did you mean 'realtime'\?"):
        parse("mine.toml", exp2.replace('mode = "realtime"', 'mode = "realtme"'))


def test_a_mistyped_method_of_a_bench_gets_the_nearest():
    import argparse

    from zentrack.common.argtypes import name_list

    with pytest.raises(argparse.ArgumentTypeError, match=r"did you mean 'distributed'\?"):
        name_list(("alone", "distributed", "centralized"), "method")("alone,distrbuted")
