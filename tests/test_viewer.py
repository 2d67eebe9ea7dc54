"""The viewer: what a recording holds, read back with Rerun's own reader; crash-safety; geometry."""
from __future__ import annotations

import signal
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from zentrack.fusion.scenario import builtin_spec, simulate
from zentrack.orchestrator import Cluster
from zentrack.runcfg import RunSetup
from zentrack.viewer.geometry import bearing_direction, covariance_ellipsoid, rotation_to_quaternion


def read_rrd(path):
    """entity path -> list of record batches (as python dicts of the columns we use)."""
    out = defaultdict(list)
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        cols = {name: rb.column(name).to_pylist() for name in rb.schema.names if name != "log_time"}
        out[chunk.entity_path].append(cols)
    return out


def column(batches, name):
    return [v for b in batches if name in b for v in b[name]]


@pytest.mark.parametrize("scenario", ["exp2", "exp2-point"])
def test_recording_holds_every_estimate_ellipsoid_and_the_truth_path(tmp_path, scenario):
    scn = simulate(builtin_spec(scenario, nodes=4, steps=40), runs=1, seed=2)
    setup = RunSetup(scn, "teskf", 1e-6, None, "lockstep", 0.5, "test")
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


def test_recording_survives_a_killed_viewer(tmp_path):
    scn = simulate(builtin_spec("exp2", nodes=3, steps=400), runs=1, seed=2)
    setup = RunSetup(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")
    with Cluster(setup, tmp_path / "run", viewer=["--flush-s", "0.5"]) as cluster:
        cluster.start()
        cluster.pump(8.0)
        cluster.procs["viewer"].send_signal(signal.SIGKILL)  # a crash: no chance to flush or close
        cluster.procs["viewer"].wait(timeout=10)
        cluster.stop()
    rec = read_rrd(tmp_path / "run" / "recording.rrd")
    steps = column(rec["/world/nodes/0/estimate"], "step")
    assert len(steps) > 20 and max(steps) < scn.steps  # readable, up to the last flush before the kill


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


def test_web_viewer_renders_the_3d_view_in_headless_chromium(tmp_path):
    """`zentrack viewer --serve` + headless Chromium: the screenshot shows the scene, not the loading page.

    The screenshot is kept as a CI artifact in out/artifacts/web_viewer.png."""
    import webshot

    if webshot.chromium() is None:
        pytest.fail("chromium is not installed: .ci/run installs Debian's chromium package")
    from zentrack.orchestrator import free_port

    web, grpc = free_port(), free_port()
    scn = simulate(builtin_spec("exp2", nodes=6, steps=600), runs=1, seed=4)
    setup = RunSetup(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")
    artifacts = Path(__file__).resolve().parent.parent / "out" / "artifacts"
    with Cluster(setup, tmp_path / "run", viewer=["--serve", "--web-port", str(web), "--grpc-port", str(grpc)]) as cluster:
        cluster.start()
        cluster.pump(10.0)
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy"
        png = webshot.screenshot(url, artifacts / "web_viewer.png", wait_s=20.0)
        blank = webshot.screenshot(f"http://127.0.0.1:{web}/", artifacts / "web_viewer_no_data.png", wait_s=3.0)
    img, empty = webshot.png_pixels(png), webshot.png_pixels(blank)
    assert img.shape[0] >= 900 and img.shape[1] >= 1500
    left = img[:, : img.shape[1] * 3 // 5]  # the 3-D view is the left 60 % in the default blueprint
    colours = {tuple(c) for c in left.reshape(-1, 3)[::7]}
    # our nodes' colours (saturated hues) and many shades (ellipsoids, trails, sensors) in the 3-D view
    vivid = np.ptp(left.astype(int), axis=2) > 60
    assert vivid.mean() > 0.002, f"no coloured content in the 3-D view ({vivid.mean():.4f})"
    assert len(colours) > 200, f"only {len(colours)} colours: looks like the loading page"
    assert not np.array_equal(img, empty)
