"""``zentrack bench hops``: round trips through 0, 1 and 2 linked routers, every ping answered."""
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
    # a message through a router takes an extra process hop each way: the medians order by routers on the path
    assert paths["direct"]["rtt_ms"]["p50"] < paths["1 router"]["rtt_ms"]["p50"] < paths["2 routers"]["rtt_ms"]["p50"]
    assert "one_way_added_ms" in paths["2 routers"] and "2 routers" in out.stdout
