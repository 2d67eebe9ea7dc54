"""The compose cluster and the swarm stack on a real Docker engine: deploy/docker-test.sh, end to end (root only).

The script installs and starts the engine when needed, builds the image as users do, runs a short compose
cluster and checks health, the summary, the recording and the RMSE against a loopback run; then, on a swarm of
this host and two Docker engines in network namespaces (``deploy/swarm-nodes.sh``), the stack of ``zentrack
compose --stack`` (plain and secure): every task healthy, the trackers spread over the three nodes, a tracker
task killed and replaced in its slot, the worker holding the most trackers drained (its trackers start again on
the other nodes and publish again) and made active again, a rolling update of the trackers mid-run. One image build and one
loopback reference per run length serve every variant. This test runs it and checks what it reports and that
nothing of its projects, stacks, swarm or namespace workers is left.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import host_share
import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(os.geteuid() != 0, reason="needs root: installs and starts a Docker engine"),
    pytest.mark.skipif(shutil.which("apt-get") is None and shutil.which("dockerd") is None,
                       reason="no Docker engine and no apt-get to install one"),
]


@pytest.mark.timeout(2800)  # (the script's own limit below is 2700 s: an engine install and an image build on a fresh host)
def test_docker_compose_and_swarm_stack_run_healthy_recover_and_track_like_loopback_plain_and_secure(tmp_path, request):
    """One image build, two compose clusters and two swarm stacks on it: the plain ones, and the secure ones with
    certificates from `zentrack certs` (the CA key removed; compose: bind-mounted, readable by the image's user;
    stack: swarm secrets and configs), every container healthy over mutual TLS through the router's access
    control. On the stacks (a swarm of three nodes, two of them engines in namespaces) a killed tracker task is
    replaced in its slot and publishes again within 20 steps of its start, a drained node's trackers start on
    the other nodes and publish again within 20 steps of their start, and a rolling update of the tracker service
    completes while the run goes on."""
    # after the namespace tests of this session (conftest.NETNS_GROUP): dockerd loads br_netfilter and sets the
    # FORWARD policy to DROP, which stays after it stops, so the harness's bridged traffic passes iptables; in two
    # suites out of two that ran the partition test after this one had started, its cut-off host lost its first
    # 3.5 s (a suite run one test after another ran this test last)
    from conftest import namespace_tests_ended

    out = tmp_path / "docker"
    # the loopback references first, while the namespace tests still run: lockstep on this host (the estimates of
    # a healthy real-time run without its wait: the same median RMSE to the last digit as the script's real-time
    # run in the image, 6.2 s instead of 95 for 900 steps), where the script finds and uses them
    with host_share.shared():
        for steps in (150, 900):
            ref = subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario", "exp2", "--nodes", "6",
                                  "--steps", str(steps), "--timing", "lockstep", "--out", str(out / f"ref-{steps}" / "run")],
                                 capture_output=True, text=True, timeout=300)
            assert ref.returncode == 0, ref.stderr[-2000:]
    assert namespace_tests_ended(request.session, 1800.0), "the namespace tests did not end within 1800 s"
    stdout, stderr = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    # alone among the slow tests from the engine's install to the end (tests/host_share.py): the swarm stack
    # (thirteen containers, three engines) beside two other slow tests lost every tracker's liveliness at once
    # (RMSE 7.3x loopback's), and beside one its rolling update was rolled back. The script starts once the hold is
    # taken: started before it (run 37 of docs/testing.md), its engine install and image build ran beside the
    # flood test's own exclusive hold, and a 200 ms stall of that run's truth cost a tracker a step
    with host_share.exclusive(), stdout.open("w") as so, stderr.open("w") as se:
        proc = subprocess.Popen(["bash", str(ROOT / "deploy" / "docker-test.sh"), "--nodes", "6", "--steps", "150",
                                 "--variants", "plain,secure,stack,stack-secure", "--swarm-workers", "2", "--out", str(out)],
                                stdout=so, stderr=se, stdin=subprocess.DEVNULL, text=True)
        try:
            proc.wait(timeout=2700)
        finally:
            if proc.poll() is None:  # (a limit or an error of this test): the script's exit trap stops what it started
                proc.terminate()
                try:
                    proc.wait(timeout=180)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout=30)
    done = subprocess.CompletedProcess(proc.args, proc.returncode, stdout.read_text(), stderr.read_text())
    print(done.stdout[-3000:], done.stderr[-3000:])
    if done.returncode != 0:  # the logs of every variant, kept where CI keeps artifacts (tmp_path does not last)
        kept = ROOT / "out" / "artifacts" / "docker-test-failed"
        shutil.rmtree(kept, ignore_errors=True)
        shutil.copytree(out, kept, ignore=shutil.ignore_patterns("*.rrd", "*.npz", "*.tar"), dirs_exist_ok=True)
        (kept / "stderr.txt").write_text(done.stderr)
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads((out / "docker-test.json").read_text())
    assert report["pass"] and report["nodes"] == 6
    assert set(report["variants"]) == {"plain", "secure", "stack", "stack-secure"}
    assert report["image_bytes"] > 50e6  # Python, numpy, scipy, Zenoh and Rerun are in it
    for variant, run in report["variants"].items():
        assert run["nodes_without_finite_rmse"] == [] and len(run["rmse_per_node"]) == 6, variant
        assert run["ratio"] <= 1.5 and run["rrd_chunks"] > 0, variant
    assert "the router enforced access control and node-0 ran mutual TLS" in done.stderr
    assert "the router enforced access control and the replacement ran mutual TLS with its slot's key" in done.stderr
    for variant in ("stack", "stack-secure"):
        run = report["variants"][variant]
        assert run["deploy_to_healthy_s"] > 0 and run["kill_to_replacement_started_s"] > 0, variant
        assert 0 < run["kill_gap_steps"] and run["republished_after_start_steps"] <= 20, variant
        assert run["rolling_update"] == "completed", variant
        assert run["swarm_workers"] == 2 and run["drained_node"].startswith("ztsw"), variant
        assert run["drain_moved"] and run["drain_to_replacements_healthy_s"] > 0, variant
        assert set(run["drain_republished_steps"]) == {str(i) for i in run["drain_moved"]}, variant
        assert all(0 < n <= 20 for n in run["drain_republished_after_start_steps"].values()), variant
    assert "left the swarm: nothing of it left" in done.stderr
    assert not (out / "secure" / "certs" / "ca.key").exists() and (out / "secure" / "certs" / "node-5.key").exists()
    if shutil.which("docker") and subprocess.run(["docker", "info"], capture_output=True).returncode == 0:
        for run in report["variants"].values():
            label = f"label=com.docker.compose.project={run['project']}"
            left = subprocess.run(["docker", "ps", "-a", "-q", "--filter", label], capture_output=True,
                                  text=True).stdout.split()
            assert not left, f"containers left behind: {left}"
        stack_label = "label=com.docker.stack.namespace="
        assert not subprocess.run(["docker", "ps", "-a", "-q", "--filter", stack_label + report["variants"]["stack"]["project"]],
                                  capture_output=True, text=True).stdout.split()
        state = subprocess.run(["docker", "info", "-f", "{{.Swarm.LocalNodeState}}"], capture_output=True, text=True)
        assert state.stdout.strip() == "inactive"
    namespaces = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert "ztsw" not in namespaces, namespaces
    assert subprocess.run(["ip", "link", "show", "ztsw0"], capture_output=True).returncode != 0, "bridge ztsw0 left"
    assert not Path("/run/zentrack-swarm").exists() and not Path("/var/lib/zentrack-swarm").exists()
