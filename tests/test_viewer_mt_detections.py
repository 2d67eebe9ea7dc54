"""The many-target viewer with sensors of their own (issue 52, item 7; ``zentrack.viewer.detections`` with
``every_return``), fed without Zenoh: mt-async's scans as ``zentrack sensor`` puts them on the wire (each sensor's
clock offset in its stamps, targets' returns and clutter together) through the core in arrival order, the recording
read back with Rerun's reader. Every return of each scan is drawn at the scan's own measurement time on the run's
clock, an empty scan drawn empty; each sensor's latency is its arrival less that time; a forged scan is refused
and counted; the layout has the sensors' tabs and the key says what the points are."""
from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
from test_viewer import column
from test_viewer_detections import KEYS, T0, arrivals, recorded
from test_viewer_layout import views

from zentrack.cli import build_parser
from zentrack.config.run_setup import resolve_setup
from zentrack.transport.codec import Message
from zentrack.transport.messages import Start
from zentrack.viewer.core import Viewer
from zentrack.viewer.multi_target import multi_target
from zentrack.viewer.multi_target_layout import OWN_SENSORS_SCANS_KEY
from zentrack.viewer.single_target_layout import SENSOR_LATENCY_TITLE

STEPS = 30


def mt_setup(scenario: str = "mt-async"):
    argv = ["--scenario", scenario, "--steps", str(STEPS)]
    return resolve_setup(build_parser(["run", *argv]).parse_args(["run", *argv, "--out", "unused"]))


@pytest.fixture(scope="module")
def fed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("vmt")
    setup = mt_setup()
    data = setup.multitarget_data
    rec = rr.RecordingStream("zentrack-test", recording_id="vmt")
    rec.set_sinks(rr.FileSink(str(tmp / "mt.rrd")))
    viewer = Viewer(None, KEYS, *multi_target(data, rec, setup.sensor_timing))
    start = Start(T0, data.ts, STEPS, "realtime", tuple(range(data.nodes)), 0.5, np.zeros(6))
    viewer.handle(Message("start", KEYS.start, start.encode(), T0))
    come = arrivals(setup)
    for t_recv, s, _, wire in come:
        viewer.handle(Message("det", KEYS.det(s), wire.encode(), t_recv))
    forged = come[3][3]
    viewer.handle(Message("det", KEYS.det((come[3][1] + 1) % data.nodes), forged.encode(), T0 + 1.0))
    return setup, viewer, come, recorded(viewer, rec, tmp / "mt.rrd")


def test_every_return_of_each_scan_is_drawn_at_the_scans_own_time(fed):
    setup, viewer, come, rec = fed
    data = setup.multitarget_data
    assert viewer.canvas.logged["det"] == len(come) and viewer.canvas.logged["bad"] == 1, "the forged one refused"
    several = 0
    for s in range(setup.sensor_timing.sensors):
        scans = sorted(((d.t, np.reshape(d.returns, (-1, 3))) for _, sensor, d, _ in come if sensor == s),
                       key=lambda a: a[0])
        drawn = rec[f"/world/sensors/{s}/returns"]
        times, points = column(drawn, "time"), column(drawn, "Points3D:positions")
        order = np.argsort(times, kind="stable")
        assert len(times) == len(scans) > 0, f"sensor {s}: one row per scan, empty ones too"
        for j, (t, returns) in zip(order, scans):
            assert times[j] == pytest.approx(t, abs=1e-6), f"sensor {s}: at its measurement time on the run's clock"
            got = np.reshape(np.asarray(points[j] if points[j] is not None else [], dtype=float), (-1, 3))
            np.testing.assert_allclose(got, returns, atol=1e-2)  # every return, targets' and clutter
            several += len(returns) > 1
        latency = rec[f"/metrics/sensor_latency_ms/{s}"]
        mine = sorted((d.t, (t_recv - T0 - d.t) * 1e3) for t_recv, sensor, d, _ in come if sensor == s)
        got = sorted(zip(column(latency, "time"), (np.ravel(v)[0] for v in column(latency, "Scalars:scalars"))))
        assert [round(t, 6) for t, _ in got] == [round(t, 6) for t, _ in mine]
        assert np.allclose([ms for _, ms in got], [ms for _, ms in mine], atol=1e-3), f"sensor {s}: its clock left in?"
    assert several > 0, "scans of several returns (the crossing targets and clutter)"
    assert data.nodes == setup.sensor_timing.sensors


def test_the_layout_has_the_sensors_tabs_and_the_key_says_what_the_points_are(fed):
    setup, viewer, _, rec = fed
    _, part = multi_target(setup.multitarget_data, rr.RecordingStream("zentrack-test", recording_id="vmt-l"),
                           setup.sensor_timing)
    assert part.topics(KEYS)["det"] == KEYS.det("*") and part.topics(KEYS)["start"] == KEYS.start
    plots = {str(v.origin): v.name for v in views(part.blueprint().root_container)}
    assert plots["metrics/sensor_latency_ms"] == SENSOR_LATENCY_TITLE and "metrics/out_of_order" in plots
    key = np.ravel(column(rec["/key"], "TextDocument:text"))[0]
    assert OWN_SENSORS_SCANS_KEY.strip() in str(key)
    sync = mt_setup("mt-crossing")
    _, plain = multi_target(sync.multitarget_data, rr.RecordingStream("zentrack-test", recording_id="vmt-s"),
                            sync.sensor_timing)
    assert plain.detections is None and "det" not in plain.topics(KEYS)
    assert not {"metrics/sensor_latency_ms", "metrics/out_of_order"} & {
        str(v.origin) for v in views(plain.blueprint().root_container)}
