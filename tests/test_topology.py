"""``zentrack run --topology``: a peer mesh for small runs, a router above ``PEER_MESH_LIMIT`` trackers."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from zentrack.cluster.run.options import PEER_MESH_LIMIT, uses_router


def test_auto_meshes_small_runs_and_routes_large_ones():
    assert not uses_router("auto", False, PEER_MESH_LIMIT)
    assert uses_router("auto", False, PEER_MESH_LIMIT + 1)
    assert uses_router("router", False, 2) and uses_router("auto", True, 2)
    assert not uses_router("peers", False, 64)
    with pytest.raises(ValueError, match="--router contradicts --topology peers"):
        uses_router("peers", True, 3)


@pytest.mark.slow
@pytest.mark.parametrize("topology, routed", [("auto", True), ("peers", False)])
def test_a_run_above_the_limit_goes_through_a_router_unless_told_otherwise(tmp_path, topology, routed):
    nodes = PEER_MESH_LIMIT + 2
    proc = subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario", "exp2", "--nodes", str(nodes),
                           "--steps", "15", "--timing", "lockstep", "--topology", topology, "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert ("through a router" in proc.stderr) == routed and ("peer mesh" in proc.stderr) != routed
    assert (tmp_path / "o" / "logs" / "router.log").exists() == routed
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert all(n["steps_estimated"] == 15 for n in summary["nodes"]) and len(summary["nodes"]) == nodes


def test_contradictory_topology_flags_exit_2_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "zentrack", "run", "--router", "--topology", "peers", "--nodes", "2",
                           "--steps", "5", "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "--topology peers" in errors[0], proc.stderr
    assert not (tmp_path / "o").exists()
