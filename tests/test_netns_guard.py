"""The namespace harness refuses a tag in use (leaving that harness alone) and works behind a DROP firewall.

``zentrack netns up`` adds its own iptables FORWARD ACCEPT rules for its bridge (removed by ``down``) and checks
that TCP passes between two of its namespaces before it returns; when traffic is blocked it fails with a message
naming the FORWARD chain. Root only (network namespaces, iptables).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

from zentrack.cluster.engines.netns import SUBNET, ForwardingBlocked, Harness, HarnessInUse, forward_rules, iptables
from zentrack.common.procs import process_running

pytestmark = [
    pytest.mark.slow,  # creates network namespaces and starts processes in them
    pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces and iptables need root (CI runs as root)"),
]

COMPOSE = """services:
  alpha:
    command: ["sleep", "600"]
  beta:
    command: ["sleep", "600"]
"""
TAG = "g7"  # kept apart from the other tests' harnesses (t, s, r, a)


def cli(*args: str, env: dict | None = None, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zentrack", *args], capture_output=True, text=True, timeout=timeout,
                          env=env)


def one_line(proc: subprocess.CompletedProcess) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


def namespaces(tag: str) -> list[str]:
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=30).stdout
    return [ln.split()[0] for ln in out.splitlines() if ln.startswith(f"zt{tag}-")]


def link_exists(name: str) -> bool:
    return subprocess.run(["ip", "link", "show", name], capture_output=True, timeout=30).returncode == 0


def forward_chain() -> str:
    return subprocess.run([iptables(), "-w", "-S", "FORWARD"], capture_output=True, text=True, timeout=30).stdout




@pytest.fixture
def compose(tmp_path):
    if "inet " + SUBNET + "." in subprocess.run(["ip", "-o", "-4", "addr", "show"], capture_output=True, text=True,
                                                timeout=30).stdout:
        pytest.skip(f"another namespace harness holds {SUBNET}.0/24 on this machine right now")
    path = tmp_path / "compose.yml"
    path.write_text(COMPOSE)
    return path


@contextmanager
def harness_up(folder: Path, compose: Path, tag: str = TAG):
    h = Harness(folder, tag)
    try:
        state = h.up(compose, "zentrack")
        yield h, state
    finally:
        h.down()
        assert not namespaces(tag) and not link_exists(h.bridge), "down left namespaces or the bridge behind"
        if iptables():
            assert h.bridge not in forward_chain(), "down left the harness's FORWARD rules behind"


@contextmanager
def forward_policy_drop():
    """Set the FORWARD policy of ``iptables`` to DROP (as Docker does) and restore it, whatever happens."""
    exe = iptables()
    before = next(ln.split()[-1] for ln in forward_chain().splitlines() if ln.startswith("-P FORWARD"))
    subprocess.run([exe, "-w", "-P", "FORWARD", "DROP"], check=True, capture_output=True, timeout=30)
    try:
        yield
    finally:
        subprocess.run([exe, "-w", "-P", "FORWARD", before], check=True, capture_output=True, timeout=30)


needs_iptables = pytest.mark.skipif(shutil.which("iptables") is None,
                                    reason="iptables is not installed (apt-get install iptables; .ci/run installs it)")


def bridge_traffic_is_filtered() -> bool:
    try:
        return Path("/proc/sys/net/bridge/bridge-nf-call-iptables").read_text().strip() == "1"
    except OSError:
        return False


def test_second_up_with_a_tag_in_use_is_refused_and_the_first_harness_keeps_working(tmp_path, compose):
    with harness_up(tmp_path / "first", compose) as (first, state):
        pids = [s["pid"] for s in state["services"].values()]
        before = (tmp_path / "first" / "netns.json").read_text()
        for folder in (tmp_path / "second", tmp_path / "first"):  # another folder, or the very same one
            line = one_line(cli("netns", "up", "--compose", str(compose), "--dir", str(folder), "--tag", TAG))
            assert f"netns tag '{TAG}' is in use" in line and f"zt{TAG}br" in line, line
        third = Harness(tmp_path / "third", "g8")
        try:
            with pytest.raises(HarnessInUse, match="subnet"):  # another tag on the same subnet is refused too
                third.up(compose, "zentrack")
        finally:
            third.down()
        assert not namespaces("g8") and not link_exists("ztg8br")
        # the first harness is untouched: its state, namespaces, bridge, processes and traffic
        assert (tmp_path / "first" / "netns.json").read_text() == before
        assert sorted(namespaces(TAG)) == [f"zt{TAG}-alpha", f"zt{TAG}-beta"] and link_exists(first.bridge)
        assert all(process_running(p) for p in pids)
        first.check_forwarding()
    assert not any(process_running(p) for p in pids)


@needs_iptables
def test_up_works_behind_a_drop_forward_policy_and_down_removes_its_rules(tmp_path, compose):
    with forward_policy_drop():
        with harness_up(tmp_path / "h", compose) as (h, state):
            chain = forward_chain()
            for rule in forward_rules(h.bridge):
                assert "-A " + " ".join(rule) in chain, chain
            assert state["forward_rules"]
            h.check_forwarding()  # up checked it already; the services' own traffic passes too
        assert h.bridge not in forward_chain()


@needs_iptables
@pytest.mark.skipif(not bridge_traffic_is_filtered(), reason="bridged traffic does not go through iptables here "
                    "(br_netfilter not loaded): a FORWARD policy cannot block it")
def test_blocked_bridge_traffic_fails_with_a_message_naming_the_forward_chain(tmp_path, compose, monkeypatch):
    # in process: a harness that cannot add its rules (as on a host without iptables)
    monkeypatch.setattr(Harness, "_allow_forward", lambda self: [])
    with forward_policy_drop():
        h = Harness(tmp_path / "h", TAG)
        try:
            with pytest.raises(ForwardingBlocked) as err:
                h.up(compose, "zentrack")
        finally:
            h.down()
        msg = str(err.value)
        assert "FORWARD chain policy: DROP" in msg and h.bridge in msg and "\n" not in msg, msg
        assert not h.procs, "no service is started when traffic does not pass"
        assert not namespaces(TAG) and not link_exists(h.bridge)

        # through the CLI, with no iptables on PATH: one line, exit status 2, everything removed again
        bin_dir = tmp_path / "bin"
        bin_dir.mkdir()
        for tool in ("ip", "sleep"):
            (bin_dir / tool).symlink_to(shutil.which(tool))
        env = {**os.environ, "PATH": str(bin_dir)}
        try:
            line = one_line(cli("netns", "up", "--compose", str(compose), "--dir", str(tmp_path / "c"), "--tag", TAG,
                                env=env))
            assert "FORWARD chain policy" in line and "iptables is not installed" in line, line
            assert not namespaces(TAG) and not link_exists(f"zt{TAG}br"), "the failed up cleaned up after itself"
        finally:
            Harness(tmp_path / "c", TAG).down()


def test_down_by_tag_removes_a_harness_whose_folder_is_gone(tmp_path, compose):
    # a harness whose `up` was killed or whose run folder was removed leaves namespaces, processes, the bridge and
    # its FORWARD rules behind; `netns down --tag T` removes them by their names
    h = Harness(tmp_path / "lost", TAG)
    try:
        state = h.up(compose, "zentrack")
        pids = [s["pid"] for s in state["services"].values()]
        (tmp_path / "lost" / "netns.json").unlink()
        Harness(tmp_path / "other", TAG).down()  # a down without state and without asking removes nothing
        assert sorted(namespaces(TAG)) == [f"zt{TAG}-alpha", f"zt{TAG}-beta"] and all(process_running(p) for p in pids)
        proc = cli("netns", "down", "--dir", str(tmp_path / "elsewhere"), "--tag", TAG)
        assert proc.returncode == 0 and "removed tag" in proc.stdout and f"zt{TAG}br" in proc.stdout, proc
        assert not namespaces(TAG) and not link_exists(h.bridge)
        assert not list(Path("/sys/class/net").glob(f"zt{TAG}v*")), "down left the namespaces' links behind"
        if iptables():
            assert h.bridge not in forward_chain(), "down left the harness's FORWARD rules behind"
        assert not any(process_running(p) for p in pids)
    finally:
        h.down(orphans=True)
