"""``zentrack netns up|down|cut|heal``: run a compose file's services, each in its own network namespace.

No Docker engine runs on the build machines, so this harness wires a compose file the way compose would:
one network namespace per service (``zt<tag>-<service>``), a veth pair into a private bridge, an address on
that bridge, and a per-namespace hosts file (``/etc/netns/<ns>/hosts``, which ``ip netns exec`` mounts over
``/etc/hosts``) so service names resolve. Each service's ``command`` and ``environment`` run unchanged except
that ``zentrack`` is this installation's executable and named volumes become folders of the run folder.
``cut``/``heal`` take a service's link down and up (a network partition of that one service).
Needs root (``ip netns``); everything stays on the bridge's private subnet inside this machine.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

SUBNET = "10.203.0"  # /24, private to the namespaces this harness creates


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


def load_compose(path: Path) -> dict:
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read the compose file ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("services"), dict) or not doc["services"]:
        raise ValueError(f"{path}: no services")
    for name, svc in doc["services"].items():
        if not isinstance(svc.get("command"), list) or not svc["command"]:
            raise ValueError(f"{path}: service {name!r} needs a command list")
    return doc


class Harness:
    """The namespaces, links and processes of one compose file, recorded in ``<dir>/netns.json``."""

    def __init__(self, folder: Path, tag: str = "a") -> None:
        if not tag.isalnum() or len(tag) > 3:
            raise ValueError("tag must be 1-3 letters or digits")
        self.dir, self.tag = Path(folder), tag
        self.bridge = f"zt{tag}br"
        self.state_file = self.dir / "netns.json"
        self.procs: dict[str, subprocess.Popen] = {}

    def ns(self, service: str) -> str:
        return f"zt{self.tag}-{service}"

    def up(self, compose: Path, zentrack: str) -> dict:
        if os.geteuid() != 0:
            raise PermissionError("network namespaces need root")
        doc = load_compose(compose)
        services = list(doc["services"])
        if len(services) > 200:
            raise ValueError("at most 200 services")
        self.dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "logs").mkdir(exist_ok=True)
        addrs = {s: f"{SUBNET}.{10 + j}" for j, s in enumerate(services)}
        state = {"tag": self.tag, "bridge": self.bridge, "services": {}, "addrs": addrs}
        self.state_file.write_text(json.dumps(state))
        _ip("link", "add", self.bridge, "type", "bridge")
        _ip("addr", "add", f"{SUBNET}.1/24", "dev", self.bridge)
        _ip("link", "set", self.bridge, "up")
        hosts = "127.0.0.1 localhost\n" + "".join(f"{a} {s}\n" for s, a in addrs.items())
        for j, s in enumerate(services):
            ns, veth = self.ns(s), f"zt{self.tag}v{j}"
            _ip("netns", "add", ns)
            _ip("link", "add", veth, "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip("link", "set", veth, "master", self.bridge, "up")
            _ip("-n", ns, "addr", "add", f"{addrs[s]}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            etc = Path("/etc/netns") / ns
            etc.mkdir(parents=True, exist_ok=True)
            (etc / "hosts").write_text(hosts)
            state["services"][s] = {"ns": ns, "veth": veth}
            self.state_file.write_text(json.dumps(state))
        volumes = {}
        for v in doc.get("volumes") or {}:
            volumes[v] = self.dir / "volumes" / v
            volumes[v].mkdir(parents=True, exist_ok=True)
        for s, svc in doc["services"].items():
            cmd = [zentrack if c == "zentrack" else c for c in svc["command"]]
            for mount in svc.get("volumes") or []:
                name, target = mount.split(":", 1)
                cmd = [c.replace(target, str(volumes[name]), 1) if c.startswith(target) else c for c in cmd]
            state["services"][s]["cmd"] = cmd
            state["services"][s]["env"] = {k: str(v) for k, v in (svc.get("environment") or {}).items()}
            self.state_file.write_text(json.dumps(state))
        for s in services:
            self._spawn(state, s)
        return state

    def _spawn(self, state: dict, service: str) -> int:
        entry = state["services"][service]
        log = open(self.dir / "logs" / f"{service}.log", "ab")
        proc = subprocess.Popen(["ip", "netns", "exec", self.ns(service), *entry["cmd"]], env={**os.environ, **entry["env"]},
                                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        log.close()
        self.procs[service] = proc
        entry["pid"] = proc.pid
        self.state_file.write_text(json.dumps(state))
        return proc.pid

    def restart(self, service: str) -> int:
        """SIGKILL a service (if it runs) and start it again in its namespace."""
        state = self.state()
        self.signal(service, signal.SIGKILL)
        proc = self.procs.get(service)
        if proc is not None:
            proc.wait(timeout=10)
        return self._spawn(state, service)

    def state(self) -> dict:
        return json.loads(self.state_file.read_text()) if self.state_file.exists() else {}

    def set_link(self, service: str, up: bool) -> None:
        """Cut (``up=False``) or heal a service's only link."""
        _ip("-n", self.ns(service), "link", "set", "eth0", "up" if up else "down")

    def signal(self, service: str, sig: int) -> None:
        pid = self.state()["services"][service].get("pid")
        if pid:
            try:
                os.killpg(pid, sig)
            except ProcessLookupError:
                pass

    def down(self, grace: float = 5.0) -> None:
        """Stop every process, then remove namespaces, links, the bridge and the hosts files."""
        state = self.state()
        pids = [s.get("pid") for s in state.get("services", {}).values() if s.get("pid")]
        for pid in pids:
            for sig in (signal.SIGCONT, signal.SIGTERM):
                try:
                    os.killpg(pid, sig)
                except ProcessLookupError:
                    pass
        end = time.time() + grace
        for pid in pids:
            while time.time() < end and _alive(pid):
                time.sleep(0.1)
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for s in state.get("services", {}).values():
            subprocess.run(["ip", "netns", "del", s["ns"]], capture_output=True)
            subprocess.run(["ip", "link", "del", s["veth"]], capture_output=True)
            shutil.rmtree(Path("/etc/netns") / s["ns"], ignore_errors=True)
        if state.get("bridge"):
            subprocess.run(["ip", "link", "del", state["bridge"]], capture_output=True)
        if self.state_file.exists():
            self.state_file.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=("up", "down", "cut", "heal"))
    p.add_argument("service", nargs="?", help="service name (cut, heal)")
    p.add_argument("--compose", default="deploy/docker-compose.yml", help="compose file (up)")
    p.add_argument("--dir", default="out/netns", help="run folder: logs/, volumes/, netns.json")
    p.add_argument("--tag", default="a", help="1-3 characters that keep parallel harnesses apart (default a)")


def run(args: argparse.Namespace) -> int:
    h = Harness(Path(args.dir), args.tag)
    if args.action == "up":
        zentrack = shutil.which("zentrack") or str(Path(sys.executable).with_name("zentrack"))
        try:
            state = h.up(Path(args.compose), zentrack)
        except Exception:
            h.down()
            raise
        for s, a in state["addrs"].items():
            print(f"{s:12s} {a:14s} ns {h.ns(s)}")
    elif args.action == "down":
        h.down()
        print(f"harness in {args.dir} is down")
    else:
        if not args.service:
            raise ValueError(f"{args.action} needs a service name")
        h.set_link(args.service, args.action == "heal")
        print(f"{args.service}: link {'up' if args.action == 'heal' else 'down'}")
    return 0
