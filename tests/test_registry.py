"""Registries: parameter validation and its messages, discovery of plug-in modules, the filter registry."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from zentrack.fusion.filters import (
    FILTER_REGISTRY,
    LOCAL_FILTERS,
    ExtendedKalmanFilter,
    ExtendedStateKalmanFilter,
    FilterContext,
    make_local_filter,
)
from zentrack.fusion.measurement import BearingModel
from zentrack.fusion.motion import ManeuveringCV3D
from zentrack.fusion.registry import Param, Registry, load_plugins
from zentrack.fusion.rules import RULE_REGISTRY

FUSION_DIR = Path(__file__).resolve().parent.parent / "fusion"


def small_registry() -> Registry:
    reg = Registry("widget")
    reg.register(
        "box",
        lambda ctx=None, **p: (ctx, p),
        (
            Param("size", float, 1e-6, lo=0.0, hi=1.0, lo_open=True, help="edge"),
            Param("count", int, 1, lo=1, hi=20),
            Param("colour", str, "red", choices=("red", "blue")),
            Param("lid", bool, False),
            Param("scale", float, None, lo=0.0, lo_open=True),
        ),
        "a box",
    )
    reg.register("plain", lambda: "plain", (), "no parameters")
    return reg


def test_create_fills_defaults_normalises_numbers_and_passes_the_context():
    reg = small_registry()
    ctx, params = reg.create("box", {"size": 1, "count": np.int64(3), "lid": np.bool_(True)}, "CTX")
    assert ctx == "CTX"
    assert params == {"size": 1.0, "count": 3, "colour": "red", "lid": True, "scale": None}
    assert type(params["size"]) is float and type(params["count"]) is int and type(params["lid"]) is bool
    assert reg.create("plain") == "plain"
    assert reg.names() == ("box", "plain") and "box" in reg and "lamp" not in reg


@pytest.mark.parametrize(
    "params, words",
    [
        ({"size": 0.0}, ["'size'", "0.0", "0 < size <= 1"]),
        ({"size": 1.5}, ["'size'", "1.5", "0 < size <= 1"]),
        ({"size": float("nan")}, ["'size'", "nan"]),
        ({"size": "big"}, ["'size'", "'big'", "float"]),
        ({"size": True}, ["'size'", "True"]),
        ({"count": 21}, ["'count'", "21", "1 <= count <= 20"]),
        ({"count": 2.0}, ["'count'", "2.0", "int"]),
        ({"colour": "green"}, ["'colour'", "'green'", "('red', 'blue')"]),
        ({"lid": 1}, ["'lid'", "1", "bool"]),
        ({"count": None}, ["'count'", "None"]),
        ({"scale": -1.0}, ["'scale'", "-1.0", "scale > 0 or None"]),
        ({"depth": 3}, ["'depth'", "3", "size, count, colour, lid, scale"]),
    ],
)
def test_invalid_parameters_name_the_parameter_value_and_range(params, words):
    with pytest.raises(ValueError) as err:
        small_registry().create("box", params)
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_unknown_names_list_the_known_ones_and_names_are_unique():
    reg = small_registry()
    with pytest.raises(ValueError, match="unknown widget 'lamp'; choose one of box, plain"):
        reg.create("lamp")
    with pytest.raises(ValueError, match="already registered"):
        reg.register("box", lambda: None)
    with pytest.raises(ValueError, match="duplicate parameter"):
        reg.register("twin", lambda **p: p, (Param("a", int, 1), Param("a", int, 2)))
    with pytest.raises(ValueError, match="type must be one of"):
        Param("x", list, None)
    with pytest.raises(ValueError, match="'x'"):
        Param("x", int, 0, lo=1)  # the default itself is out of range


def test_describe_lines():
    lines = small_registry().describe()
    assert lines[0] == (
        "box: a box; params: size (float, default 1e-06, 0 < size <= 1), count (int, default 1, 1 <= count <= 20), "
        "colour (str, default 'red', colour in ('red', 'blue')), lid (bool, default False, any bool), "
        "scale (float, default None, scale > 0 or None)"
    )
    assert lines[1] == "plain: no parameters; params: none"
    teskf = FILTER_REGISTRY.describe()[0]
    assert teskf.startswith("teskf: ") and "qbar (float, default 1e-06, qbar > 0)" in teskf
    assert any(line.startswith("ci: ") and "rounds (int, default 1, 1 <= rounds <= 32)" in line
               for line in RULE_REGISTRY.describe())


def test_load_plugins_names_a_module_that_does_not_import():
    with pytest.raises(ValueError, match="zentrack.fusion.no_such_plugin"):
        load_plugins(["zentrack.fusion.no_such_plugin"])
    (mod,) = load_plugins(["zentrack.fusion.rules.independent"])
    assert mod.__name__ == "zentrack.fusion.rules.independent"


def test_discovery_imports_every_public_module_of_the_package(tmp_path, monkeypatch):
    pkg = tmp_path / "zt_plugin_pkg_test"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "from zentrack.fusion.registry import Registry\nREG = Registry('gadget', discover=__name__)\n"
        "REG.register('builtin', dict)\n"
    )
    (pkg / "extra.py").write_text("from . import REG\nREG.register('extra', list)\n")
    (pkg / "_private.py").write_text("raise RuntimeError('private modules are not imported')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import zt_plugin_pkg_test

    try:
        reg = zt_plugin_pkg_test.REG
        assert "zt_plugin_pkg_test.extra" not in sys.modules  # lazily: only when the registry is used
        assert reg.names() == ("builtin", "extra")
        assert reg.create("extra") == []
    finally:
        for name in [n for n in sys.modules if n.startswith("zt_plugin_pkg_test")]:
            del sys.modules[name]


def test_a_rule_file_is_found_without_any_other_file_naming_it():
    """The ci3 plug-in: registered in a fresh interpreter by importing the simulator alone, and no other
    file under fusion/ mentions it."""
    script = textwrap.dedent("""
        import sys
        from zentrack.study.simulator import FUSION_RULES
        print(",".join(FUSION_RULES), "zentrack.fusion.rules.ci_rounds" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    names, imported = out.stdout.split()
    assert names.split(",")[:2] == ["ci", "independent"] and "ci3" in names.split(",") and imported == "True"
    mentions = [p.relative_to(FUSION_DIR).as_posix() for p in FUSION_DIR.rglob("*.py")
                if "ci3" in p.read_text() or "ci_rounds" in p.read_text()]
    assert mentions == ["rules/ci_rounds.py"]


def test_filter_registry_keeps_the_builtin_order_and_the_old_factory():
    assert LOCAL_FILTERS[:5] == ("teskf", "eskf", "ekf", "ukf", "ckf")
    assert FILTER_REGISTRY.names() == LOCAL_FILTERS
    motion, meas = ManeuveringCV3D(), BearingModel()
    ctx = FilterContext(motion, meas, np.eye(6), lumped_var=2.0)
    via_registry = FILTER_REGISTRY.create("eskf", {"qbar": 1e-5}, ctx)
    p0_aug = np.diag([1.0] * 6 + [2.0] * 3)
    direct = ExtendedStateKalmanFilter(motion, meas, order=1, qbar=1e-5, theta=None, p0=p0_aug)
    assert isinstance(via_registry, ExtendedStateKalmanFilter) and via_registry.order == 1
    assert via_registry.theta == direct.theta
    np.testing.assert_array_equal(via_registry.q_tilde, direct.q_tilde)
    wrapped = make_local_filter("eskf", motion, meas, np.eye(6), 2.0, qbar=1e-5)
    assert wrapped.theta == direct.theta
    # filters without qbar/theta ignore them in the old wrapper, and reject them in the registry
    assert isinstance(make_local_filter("ekf", motion, meas, np.eye(6), qbar=5.0, theta=2.0), ExtendedKalmanFilter)
    with pytest.raises(ValueError, match="has no parameter 'qbar'"):
        FILTER_REGISTRY.create("ekf", {"qbar": 5.0}, ctx)
    with pytest.raises(ValueError, match="'theta'"):
        make_local_filter("teskf", motion, meas, np.eye(6), theta=-1.0)
