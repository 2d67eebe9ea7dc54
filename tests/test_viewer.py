"""The viewer: what a recording holds, read back with Rerun's own reader; crash-safety; geometry."""
from __future__ import annotations

import signal
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from zentrack.cluster.run.cluster import Cluster
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.truth.simulation.simulate import simulate
from zentrack.viewer.geometry import bearing_direction, covariance_ellipsoid, rotation_to_quaternion
from zentrack.viewer.hints import web_url


def read_rrd(path):
    """entity path -> list of record batches (as python dicts of the columns we use; a duration timeline such as
    ``time`` in seconds)."""
    out = defaultdict(list)
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        cols = {name: python_values(rb.column(name)) for name in rb.schema.names if name != "log_time"}
        out[chunk.entity_path].append(cols)
    return out


def python_values(col) -> list:
    """A column as Python values; durations as seconds (nanoseconds need not fit a ``timedelta``'s microseconds)."""
    import pyarrow as pa

    if pa.types.is_duration(col.type):
        return [None if v is None else v / 1e9 for v in col.cast(pa.duration("ns")).cast(pa.int64()).to_pylist()]
    return col.to_pylist()


def column(batches, name):
    return [v for b in batches if name in b for v in b[name]]


def pump_until(cluster, predicate, timeout: float, what: str) -> float:
    """Record estimates until ``predicate()`` holds; fail after ``timeout`` s. Returns the seconds it took."""
    t0 = time.time()
    end = t0 + timeout
    while not predicate():
        if time.time() >= end:
            raise AssertionError(f"{what}: not within {timeout:.0f} s")
        cluster.recorder.drain(0.2)
    return time.time() - t0


def steps_estimated_by_every_node(cluster) -> int:
    return int(np.all(np.isfinite(cluster.recorder.part.mean), axis=-1).sum(axis=0).min())


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["exp2", "exp2-point"])
def test_recording_holds_every_estimate_ellipsoid_and_the_truth_path(tmp_path, scenario):
    scn = simulate(builtin_spec(scenario, nodes=4, steps=40), runs=1, seed=2)
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "lockstep", 0.5, "test")
    with Cluster(setup, tmp_path / "run", viewer=[]) as cluster:
        cluster.start()
        assert cluster.wait(timeout=200) == 0
        cluster.write_results()
        assert cluster.procs["viewer"].poll() == 0
    rec = read_rrd(tmp_path / "run" / "recording.rrd")
    est = np.load(tmp_path / "run" / "estimates.npz")
    k_steps = scn.steps
    assert sorted(column(rec["/world/truth/position"], "step")) == list(range(k_steps))
    assert sorted(column(rec["/world/truth/path"], "step")) == list(range(1, k_steps))
    labels = column(rec["/world/truth/position"], "Points3D:labels")
    assert len(labels) == k_steps and all(np.ravel(v).tolist() == ["truth"] for v in labels), "the truth is labelled"
    # the frame the target view is drawn in moves with the true position, step by step
    frame_steps = column(rec["/world/target"], "step")
    assert sorted(frame_steps) == list(range(k_steps))
    moved = column(rec["/world/target"], "Transform3D:translation")
    for k, t in zip(frame_steps, moved):
        np.testing.assert_allclose(np.ravel(t), scn.truth[0, k, :3], rtol=1e-6, atol=1e-3)
    key = " ".join(np.ravel(column(rec["/key"], "TextDocument:text")).tolist())
    assert ("Bearings-only" if scenario == "exp2" else "position with noise") in key, key
    for i in range(scn.nodes):
        assert sorted(column(rec[f"/world/nodes/{i}/estimate"], "step")) == list(range(k_steps))
        steps = column(rec[f"/world/nodes/{i}/ellipsoid"], "step")
        assert sorted(steps) == list(range(k_steps)), "one ellipsoid per node per step"
        halves = column(rec[f"/world/nodes/{i}/ellipsoid"], "Ellipsoids3D:half_sizes")
        centers = column(rec[f"/world/nodes/{i}/ellipsoid"], "Ellipsoids3D:centers")
        for k, half, center in zip(steps, halves, centers):
            expected = 3.0 * np.sqrt(np.linalg.eigvalsh(est["cov"][k, i, :3, :3]))
            np.testing.assert_allclose(sorted(np.ravel(half)), expected, rtol=1e-6)  # float32 storage
            np.testing.assert_allclose(np.ravel(center), est["mean"][k, i, :3], rtol=1e-6, atol=1e-4)
        assert len(column(rec[f"/metrics/position_error/{i}"], "step")) == k_steps
    key = "ray" if scenario == "exp2" else "measurement"
    assert len(column(rec[f"/world/nodes/0/{key}"], "step")) == k_steps
    assert column(rec["/events"], "TextLog:text"), "liveliness joins are logged"


@pytest.mark.slow
def test_a_clutter_recording_holds_clutter_rays_particles_beta_and_the_fusion_centre(tmp_path):
    """Paper 1 in the viewer: per node and step the target's ray and the clutter rays (J - 1 of them), a
    particle subsample, the association probability of the target's return; the fusion centre per step."""
    from zentrack.config.scenario_config import load_scenario_config
    from zentrack.fusion.feedforward import covariance_weighted_fusion

    cfg = load_scenario_config("fpf-clutter")
    cfg.spec.steps = 20
    scn = cfg.scenario_data()
    setup = RunSetup.from_data(scn, cfg.filter_kind, mode="lockstep", filter_params=dict(cfg.filter_params))
    with Cluster(setup, tmp_path / "run", viewer=[]) as cluster:
        cluster.start()
        assert cluster.wait(timeout=200) == 0
        cluster.write_results()
        assert cluster.procs["viewer"].poll() == 0
    rec = read_rrd(tmp_path / "run" / "recording.rrd")
    est = np.load(tmp_path / "run" / "estimates.npz")
    for i in range(scn.nodes):
        assert sorted(column(rec[f"/world/nodes/{i}/ray"], "step")) == list(range(20))
        clutter = rec[f"/world/nodes/{i}/clutter"]
        strips = column(clutter, "LineStrips3D:strips")
        assert len(column(clutter, "step")) == 20 and all(len(s) == 10 for s in strips)  # 11 returns, 1 is the target
        particles = column(rec[f"/world/nodes/{i}/particles"], "Points3D:positions")
        assert len(particles) == 20 and all(len(p) == 63 or len(p) == 64 for p in particles)
        betas = column(rec[f"/metrics/beta_target/{i}"], "Scalars:scalars")
        assert len(betas) == 20 and all(0.0 <= np.ravel(b)[0] <= 1.0 for b in betas)
        assert np.median([np.ravel(b)[0] for b in betas]) > 0.5, "the target's return is the likely one"
    fused = column(rec["/world/fused/estimate"], "Points3D:positions")
    steps = column(rec["/world/fused/estimate"], "step")
    assert sorted(steps) == list(range(20))
    k = steps[-1]
    ref = covariance_weighted_fusion(est["mean"][k], est["cov"][k])
    np.testing.assert_allclose(np.ravel(fused[-1]), ref.mean[:3], rtol=1e-5, atol=1e-3)


@pytest.mark.slow
def test_a_uav_recording_holds_moving_sensors_links_and_the_disagreement_per_round(tmp_path):
    """Paper 2 in the viewer: each UAV's position and trail from the pose its scans carry, the communication
    links between the current positions, and after every consensus round the nodes' disagreement, which the
    rounds shrink."""
    from zentrack.config.scenario_config import load_scenario_config

    cfg = load_scenario_config("dce-ici")
    cfg.spec.steps = 12
    scn = cfg.scenario_data()
    setup = RunSetup.from_data(scn, "srcif", mode="lockstep", fusion="dce-ici", fusion_params={"rounds": 6})
    with Cluster(setup, tmp_path / "run", viewer=[]) as cluster:
        cluster.start()
        assert cluster.wait(timeout=200) == 0
        cluster.write_results()
        assert cluster.procs["viewer"].poll() == 0
    rec = read_rrd(tmp_path / "run" / "recording.rrd")
    for i in range(scn.nodes):
        steps = column(rec[f"/world/platforms/{i}/position"], "step")
        assert sorted(steps) == list(range(12))
        pos = column(rec[f"/world/platforms/{i}/position"], "Points3D:positions")
        np.testing.assert_allclose(np.ravel(pos[steps.index(11)]), scn.sensor_track[11, i], rtol=1e-6)
        assert len(column(rec[f"/world/platforms/{i}/trail"], "step")) == 11
    links = column(rec["/world/graph"], "LineStrips3D:strips")  # per step: one strip per link
    # a step's links are drawn when its truth message comes, with the poses known by then (the first steps'
    # truth can overtake every scan): most steps, and every link once all poses are in
    assert len(links) >= 6 and max(len(row) for row in links) == int(scn.adjacency.sum() // 2)
    assert "/world/sensors" not in rec, "moving sensors are not drawn as fixed points"
    spread = {rnd: [np.ravel(v)[0] for v in column(rec[f"/metrics/disagreement/{rnd}"], "Scalars:scalars")]
              for rnd in range(1, 7)}
    assert all(len(v) >= 10 for v in spread.values()), {r: len(v) for r, v in spread.items()}
    assert np.median(spread[6]) < 0.5 * np.median(spread[1]), "consensus rounds shrink the disagreement"


@pytest.mark.slow
def test_recording_survives_a_killed_viewer(tmp_path):
    """With --flush-s 0.5 a crash loses only the last rows: the file stays readable and reaches close to the
    step the run was at when the viewer was killed (5 s of margin over the 0.5 s flush period)."""
    scn = simulate(builtin_spec("exp2", nodes=3, steps=400), runs=1, seed=2)
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")
    path = tmp_path / "run" / "recording.rrd"
    with Cluster(setup, tmp_path / "run", viewer=["--flush-s", "0.5"]) as cluster:
        cluster.start()
        pump_until(cluster, lambda: steps_estimated_by_every_node(cluster) >= 1, 180.0, "a first step from every node")
        took = pump_until(cluster, lambda: steps_estimated_by_every_node(cluster) >= 60, 60.0, "60 steps recorded")
        cluster.procs["viewer"].send_signal(signal.SIGKILL)  # a crash: no chance to flush or close
        at_kill = int(np.flatnonzero(np.isfinite(cluster.recorder.part.mean[:, 0]).all(axis=-1)).max())
        cluster.procs["viewer"].wait(timeout=10)
        cluster.stop()
    steps = column(read_rrd(path)["/world/nodes/0/estimate"], "step")
    print(f"killed the viewer after {took:.1f} s at step {at_kill}; the file holds {len(steps)} steps up to "
          f"{max(steps, default=-1)}")
    assert len(steps) > 20 and max(steps) < scn.steps  # readable, up to the last flush before the kill
    assert max(steps) >= at_kill - 50, "more than 5 s of rows lost: the viewer does not flush every 0.5 s"


def test_viewer_needs_a_sink(capsys):
    from zentrack.cli import main
    assert main(["viewer", "--scenario", "exp2"]) == 2
    assert "choose at least one sink" in capsys.readouterr().err


def test_ellipsoid_geometry(rng):
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.1 * np.eye(3)
    half, q = covariance_ellipsoid(cov)
    x, y, z, w = q
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(r @ np.diag((half / 3) ** 2) @ r.T, cov, atol=1e-9)
    np.testing.assert_allclose(rotation_to_quaternion(np.eye(3)), [0, 0, 0, 1])
    np.testing.assert_allclose(bearing_direction(np.pi / 2, 0.0), [0, 1, 0], atol=1e-12)


def node_colour_pixels(png: bytes, nodes: int) -> list[int]:
    """Pixels of each node's colour (sensor markers, bearing rays, estimates, ellipsoids) in the 3-D view, the
    left 60 % of the default blueprint without the top and bottom bars. The loading and welcome pages have
    none of these colours (their blue and orange are far from them)."""
    import webshot

    from zentrack.viewer.layout import node_color

    img = webshot.png_pixels(png).astype(int)
    view = img[40:img.shape[0] - 40, : img.shape[1] * 3 // 5]
    return [int((np.abs(view - node_color(i, nodes)).max(axis=2) <= 40).sum()) for i in range(nodes)]


def shows_every_node(nodes: int):
    return lambda png: min(node_colour_pixels(png, nodes)) >= 20


def shows_the_ui(png: bytes) -> bool:
    """The viewer's UI has rendered (text and widgets: many shades), not a blank page."""
    import webshot

    return len(np.unique(webshot.png_pixels(png)[::4, ::4].reshape(-1, 3), axis=0)) > 100


@pytest.mark.slow
def test_web_viewer_renders_the_3d_view_in_headless_chromium(tmp_path):
    """`zentrack viewer --serve` + headless Chromium: the screenshot shows the scene, not the loading page.

    The screenshot is kept as a CI artifact in out/artifacts/web_viewer.png."""
    import webshot

    if webshot.chromium() is None:
        pytest.fail("chromium is not installed: .ci/run installs Debian's chromium package")
    from zentrack.common.ports import free_port

    web, grpc = free_port(), free_port()
    # 2400 steps at 10 Hz: the run outlasts the waits below by far (the cluster is stopped at the end of the block)
    scn = simulate(builtin_spec("exp2", nodes=6, steps=2400), runs=1, seed=4)
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")
    artifacts = Path(__file__).resolve().parent.parent / "out" / "artifacts"
    with Cluster(setup, tmp_path / "run", viewer=["--serve", "--web-port", str(web), "--grpc-port", str(grpc)]) as cluster:
        cluster.start()
        # start-up first: eight cold interpreters importing numpy, zenoh and rerun on two busy cores take a while
        pump_until(cluster, lambda: steps_estimated_by_every_node(cluster) >= 1, 180.0, "a first step from every node")
        pump_until(cluster, lambda: steps_estimated_by_every_node(cluster) >= 30, 60.0, "30 steps from every node")
        url = web_url("127.0.0.1", web, grpc)
        # software rendering on a busy 2-core machine: the page loads in ~10 s and one capture takes up to ~12 s
        png = webshot.screenshot(url, artifacts / "web_viewer.png", ready=shows_every_node(scn.nodes), timeout_s=120.0)
        blank = webshot.screenshot(f"http://127.0.0.1:{web}/", artifacts / "web_viewer_no_data.png", ready=shows_the_ui,
                                   timeout_s=60.0)
        assert cluster.procs["truth"].poll() is None, "the run ended before the screenshot: it proves less"
    img = webshot.png_pixels(png)
    assert img.shape[0] >= 900 and img.shape[1] >= 1500
    seen = node_colour_pixels(png, scn.nodes)
    assert min(seen) >= 20, f"pixels of each node's colour in the 3-D view: {seen} (the loading page has none)"
    # framed on the target: the white truth in the middle of a dark target view (the layout view has the sensors)
    view = img[40:img.shape[0] - 40, : img.shape[1] * 3 // 5].astype(int)
    h, w = view.shape[:2]
    middle = view[int(h * 0.3):int(h * 0.7), int(w * 0.3):int(w * 0.7)]
    assert np.median(view) < 60, f"the target view's background is not dark (median {np.median(view)})"
    assert (middle.min(axis=2) >= 235).sum() >= 10, "no white truth marker in the middle of the target view"
    assert shows_the_ui(blank), "the viewer without data did not render its page"
    assert max(node_colour_pixels(blank, scn.nodes)) < 20, "the page without data must not pass for the scene"
