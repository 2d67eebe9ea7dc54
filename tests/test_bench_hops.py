"""``zentrack bench hops``: round trips through 0, 1 and 2 linked routers, every ping answered.

Which path is faster is a measurement, printed by the benchmark; on a loaded CI host a direct path can be
slower than a routed one, so the test asserts the figures' shape and the derived column, not their order.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ZENTRACK = str(Path(sys.executable).with_name("zentrack"))


@pytest.mark.slow
def test_bench_hops_times_every_path_and_each_router_adds_latency(tmp_path):
    out = subprocess.run([ZENTRACK, "bench", "hops", "--pings", "300", "--json", str(tmp_path / "hops.json")],
                         capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads((tmp_path / "hops.json").read_text())
    paths = {r["path"]: r for r in doc["results"]}
    assert list(paths) == ["direct", "1 router", "2 routers"]
    assert all(r["rtt_ms"]["count"] == 300 for r in paths.values())  # every ping after the warm-up answered
    # the echo of "2 routers" is a client of the other router: every ping answered means the link carried it
    assert [r["routers"] for r in paths.values()] == [0, 1, 2]
    for r in paths.values():  # figures only, no ordering: how the paths compare is the benchmark's to print
        q = r["rtt_ms"]
        assert 0 < q["p50"] <= q["p90"] <= q["p99"] < 5000
    for name, prev in (("1 router", "direct"), ("2 routers", "1 router")):
        added = paths[name]["one_way_added_ms"]["p50"]
        assert added == pytest.approx((paths[name]["rtt_ms"]["p50"] - paths[prev]["rtt_ms"]["p50"]) / 2)
    assert "2 routers" in out.stdout and "one way added" in out.stdout
