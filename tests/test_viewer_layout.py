"""The viewer's layout (fast, no processes): framed on the target, a sensor layout beside it, plots without
legends, titles per scenario family, and the run's hints on where the recording is and the live address."""
from __future__ import annotations

import numpy as np
import pytest
import rerun.blueprint as rrb

from zentrack.config.scenario_config import load_scenario_config
from zentrack.viewer.hints import rerun_command, run_lines, web_url
from zentrack.viewer.single_target_layout import TARGET_FRAME, TITLES, blueprint, describe

FAMILIES = {"exp2": "bearings", "exp2-irregular": "bearings", "exp2-point": "points", "fpf-clutter": "clutter",
            "eot-s2": "extended", "eot-s3": "extended", "seckf-constellation": "satellites", "seckf-power": "satellites",
            "dce-ici": "uav"}


def scenario(name: str, steps: int = 30):
    cfg = load_scenario_config(name)
    cfg.spec.steps = steps
    return cfg.scenario_data()


def views(container) -> list:
    """Every view of a blueprint container, depth first."""
    out = []
    for item in container.contents:
        out += views(item) if hasattr(item, "contents") and not hasattr(item, "origin") else [item]
    return out


@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_each_scenario_family_gets_its_own_title(name):
    scene = describe(scenario(name), rounds=False)
    assert scene.family == FAMILIES[name]
    assert views(blueprint(scene).root_container)[0].name == TITLES[scene.family]
    assert len(set(TITLES.values())) == len(TITLES), "two families would read the same"


@pytest.mark.parametrize("name", ["exp2", "fpf-clutter", "eot-s2", "seckf-constellation"])
def test_the_main_view_is_framed_on_the_target_and_the_sensors_are_a_second_view(name):
    scn = scenario(name)
    scene = describe(scn, rounds=False)
    spatial = [v for v in views(blueprint(scene).root_container) if isinstance(v, rrb.Spatial3DView)]
    target, layout = spatial
    assert str(target.origin) == TARGET_FRAME, "the 3-D view moves with the target"
    shown = [str(c) for c in target.contents]
    drawn = "shape" if scene.family == "extended" else "ellipsoid"  # an extended object's outline, or 3σ
    assert "+ world/truth/**" in shown and "+ world/nodes/0/estimate" in shown and f"+ world/nodes/0/{drawn}" in shown
    assert not any("sensors" in c or "platforms" in c or c.strip("+ ") == "world/**" for c in shown), shown
    assert "EyeControls3D" in target.properties, "a camera fixed in the target frame follows the target"
    assert str(layout.origin) == "world" and "+ world/**" in [str(c) for c in layout.contents]
    # the target view is a close-up: far smaller than the scene the sensors span
    spread = np.ptp(scn.sensor_track if scn.sensor_track is not None else scn.sensors[None], axis=(0, 1)).max()
    assert scene.scale < spread / 4, f"a {2 * scene.scale:.0f} m view of a {spread:.0f} m scene frames the sensors"


def test_the_plots_have_no_legend_that_would_cover_them():
    scene = describe(scenario("exp2"), rounds=False)
    series = [v for v in views(blueprint(scene).root_container) if isinstance(v, rrb.TimeSeriesView)]
    assert len(series) >= 5
    for view in series:
        legend = view.properties["PlotLegend"]
        assert legend.visible is not None and not np.any(legend.visible.as_arrow_array().to_pylist()), view.name


def test_a_run_names_its_recording_how_to_open_it_and_the_live_address():
    lines = run_lines("out/run1/recording.rrd", serve=True)
    assert "out/run1/recording.rrd" in lines[0] and f"`{rerun_command()} out/run1/recording.rrd`" in lines[0]
    assert rerun_command().endswith("rerun")
    assert lines[1].endswith(web_url("127.0.0.1", 9090, 9876)) and "browser" in lines[1]
    assert web_url("0.0.0.0", 1, 2) == "http://127.0.0.1:1/?url=rerun%2Bhttp://127.0.0.1:2/proxy&hide_welcome_screen"
    assert len(run_lines("x.rrd", serve=False)) == 1
