"""``zentrack netns up|down|cut|heal``: run a compose file's services, each in its own network namespace.

No Docker engine runs on the build machines, so this harness wires a compose file the way compose would:
one network namespace per service (``zt<tag>-<service>``), a veth pair into a private bridge, an address on
that bridge, and a per-namespace hosts file (``/etc/netns/<ns>/hosts``, which ``ip netns exec`` mounts over
``/etc/hosts``) so service names resolve. Each service's ``command`` and ``environment`` run unchanged except
that ``zentrack`` is this installation's executable, named volumes become folders of the run folder and
``${VAR}`` / ``${VAR:-default}`` are interpolated from the environment as compose does.
``cut``/``heal`` take a service's link down and up (a network partition of that one service);
``impair A B --delay-ms D --jitter-ms J --loss P [--rate-kbit R]`` makes the path between two services a
slow, lossy link and ``clear A B`` restores it (netem where the kernel has it, else a userspace link:
``zentrack/cluster/engines/link_impair.py``).
Needs root (``ip netns``); everything stays on the bridge's private subnet inside this machine.

``up`` refuses a tag whose bridge or namespaces exist (another harness runs: it is left alone) and a subnet
another bridge holds. Hosts whose firewall drops forwarded bridge traffic (Docker sets the iptables FORWARD
policy to DROP) get two ACCEPT rules for the harness's bridge (``iptables -I FORWARD -i/-o <bridge> -j
ACCEPT``, removed by ``down``); before starting any service ``up`` checks that a TCP connection passes between
two of its namespaces and fails with a message naming the FORWARD chain when it does not.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from zentrack.cluster.engines import link_impair
from zentrack.common.procs import process_running

SUBNET = "10.203.0"  # /24, private to the namespaces this harness creates
FORWARD_CHECK_S = 5.0  # how long up waits for a TCP connection between two of its namespaces


class HarnessInUse(ValueError):
    """``up`` found another harness's bridge, namespaces or subnet; nothing was created or removed."""


class ForwardingBlocked(ValueError):
    """Traffic does not pass between the harness's namespaces (a host firewall)."""


def _ip(*args: str) -> None:
    try:
        subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)
    except subprocess.CalledProcessError as exc:
        raise ValueError(f"ip {' '.join(args)}: {' '.join((exc.stderr or '').split()) or f'exit status {exc.returncode}'}") from None


def _out(*cmd: str) -> str:
    return subprocess.run(list(cmd), capture_output=True, text=True, timeout=30).stdout


def iptables() -> str | None:
    """The iptables executable, if installed (the nft or legacy flavour that ``iptables`` points to)."""
    return shutil.which("iptables")


def iptables_flavours() -> list[str]:
    """``iptables``, and ``iptables-legacy`` too when it is another flavour whose filter table is loaded (a
    Docker that uses legacy iptables): a packet must pass the FORWARD chain of both."""
    exe = iptables()
    if exe is None:
        return []
    found = [exe]
    legacy = shutil.which("iptables-legacy")
    try:
        loaded = "filter" in Path("/proc/net/ip_tables_names").read_text().split()
    except OSError:
        loaded = False
    if legacy and loaded and os.path.realpath(legacy) != os.path.realpath(exe):
        found.append(legacy)
    return found


def forward_policy() -> str:
    """The policy of the iptables FORWARD chain (``ACCEPT``, ``DROP``; per flavour when the legacy tables are
    loaded too), or ``unknown`` without iptables."""
    flavours = iptables_flavours()
    if not flavours:
        return "unknown (iptables is not installed)"
    policies = []
    for exe in flavours:
        policy = next((ln.split()[-1] for ln in _out(exe, "-w", "-S", "FORWARD").splitlines()
                       if ln.startswith("-P FORWARD")), "unknown")
        policies.append(policy if len(flavours) == 1 else f"{policy} ({Path(exe).name})")
    return ", ".join(policies)


def forward_rules(bridge: str) -> list[list[str]]:
    """The two FORWARD rules that let a bridge's traffic through whatever the chain's policy."""
    return [["FORWARD", "-i", bridge, "-j", "ACCEPT"], ["FORWARD", "-o", bridge, "-j", "ACCEPT"]]


# a listener in one namespace and a client in another: TCP as the services use it (Zenoh over tcp)
_LISTEN = """
import socket, sys
s = socket.socket(); s.bind((sys.argv[1], 0)); s.listen(4); s.settimeout(float(sys.argv[2]))
print(s.getsockname()[1], flush=True)
try:
    c, _ = s.accept(); c.close()
except OSError:
    pass
"""
_CONNECT = """
import socket, sys, time
end = time.monotonic() + float(sys.argv[3])
while True:
    try:
        socket.create_connection((sys.argv[1], int(sys.argv[2])), timeout=1.0).close()
        sys.exit(0)
    except OSError as exc:
        if time.monotonic() > end:
            print(exc, flush=True)
            sys.exit(1)
        time.sleep(0.1)
"""


_VARIABLE = re.compile(r"\$\{(\w+)(?::-([^}]*))?\}")


def interpolate(text: str, env: Mapping[str, str] | None = None) -> str:
    """Compose's variable interpolation: ``${VAR}`` is VAR's value, ``${VAR:-default}`` the default when VAR is
    unset or empty."""
    values: Mapping[str, str] = os.environ if env is None else env
    return _VARIABLE.sub(lambda m: values.get(m.group(1)) or (m.group(2) or ""), text)


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
        self.created = False  # set once up has written its state (and may have created something to remove)

    def ns(self, service: str) -> str:
        return f"zt{self.tag}-{service}"

    def check_free(self) -> None:
        """Raise :class:`HarnessInUse` when this tag's bridge, namespaces or links, or the harness subnet on
        another bridge, exist: a second ``up`` must neither run beside nor clean up after another harness."""
        found = []
        links = _out("ip", "-o", "link", "show").splitlines()
        names = [ln.split(":", 2)[1].strip().split("@")[0] for ln in links if ln.count(":") >= 2]
        if self.bridge in names:
            found.append(f"bridge {self.bridge}")
        found += [f"link {n}" for n in names if n.startswith(f"zt{self.tag}v")][:3]
        spaces = [ln.split()[0] for ln in _out("ip", "netns", "list").splitlines() if ln.strip()]
        mine = [n for n in spaces if n.startswith(f"zt{self.tag}-")]
        if mine:
            found.append("namespace" + ("s " if len(mine) > 1 else " ") + ", ".join(mine[:3]) + (", ..." if len(mine) > 3 else ""))
        if found:
            raise HarnessInUse(f"netns tag {self.tag!r} is in use ({'; '.join(found)}): another harness runs; stop it "
                               f"with `zentrack netns down --dir <its folder> --tag {self.tag}` or choose another --tag")
        for line in _out("ip", "-o", "-4", "addr", "show").splitlines():
            fields = line.split()
            if "inet" in fields and fields[fields.index("inet") + 1].startswith(f"{SUBNET}."):
                raise HarnessInUse(f"subnet {SUBNET}.0/24 of the netns harness is in use on {fields[1]} (another "
                                   f"harness, or another network): stop that harness first with `zentrack netns down`")

    def up(self, compose: Path, zentrack: str) -> dict:
        if os.geteuid() != 0:
            raise PermissionError("network namespaces need root")
        self.check_free()
        doc = load_compose(compose)
        services = list(doc["services"])
        if len(services) > 200:
            raise ValueError("at most 200 services")
        self.dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "logs").mkdir(exist_ok=True)
        addrs = {s: f"{SUBNET}.{10 + j}" for j, s in enumerate(services)}
        # state records only what this harness created, so that down never removes another's
        state: dict[str, Any] = {"tag": self.tag, "bridge": None, "services": {}, "addrs": addrs, "forward_rules": [],
                                 "impairments": {}}
        self.state_file.write_text(json.dumps(state))
        self.created = True
        _ip("link", "add", self.bridge, "type", "bridge")
        state["bridge"] = self.bridge
        self.state_file.write_text(json.dumps(state))
        _ip("addr", "add", f"{SUBNET}.1/24", "dev", self.bridge)
        _ip("link", "set", self.bridge, "up")
        state["forward_rules"] = self._allow_forward()
        self.state_file.write_text(json.dumps(state))
        hosts = "127.0.0.1 localhost\n" + "".join(f"{a} {s}\n" for s, a in addrs.items())
        for j, s in enumerate(services):
            ns, veth = self.ns(s), f"zt{self.tag}v{j}"
            _ip("netns", "add", ns)
            state["services"][s] = {"ns": ns, "veth": veth}
            self.state_file.write_text(json.dumps(state))
            _ip("link", "add", veth, "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip("link", "set", veth, "master", self.bridge, "up")
            _ip("-n", ns, "addr", "add", f"{addrs[s]}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            etc = Path("/etc/netns") / ns
            etc.mkdir(parents=True, exist_ok=True)
            (etc / "hosts").write_text(hosts)
        self.check_forwarding(state)
        volumes = {}
        for v in doc.get("volumes") or {}:
            volumes[v] = self.dir / "volumes" / v
            volumes[v].mkdir(parents=True, exist_ok=True)
        for s, svc in doc["services"].items():
            cmd = [zentrack if c == "zentrack" else interpolate(c) for c in svc["command"]]
            env = {k: interpolate(str(v)) for k, v in (svc.get("environment") or {}).items()}
            for mount in svc.get("volumes") or []:
                name, target = mount.split(":")[:2]
                # a named volume is a folder of the run; a bind mount (./x, ../x, /x) the compose file's path
                source = volumes[name] if name in volumes else (compose.parent / name).resolve()
                cmd = [c.replace(target, str(source), 1) if c.startswith(target) else c for c in cmd]
                env = {k: v.replace(target, str(source), 1) if v.startswith(target) else v for k, v in env.items()}
            state["services"][s]["cmd"] = cmd
            state["services"][s]["env"] = env
            self.state_file.write_text(json.dumps(state))
        for s in services:
            self._spawn(state, s)
        return state

    def _allow_forward(self) -> list[list[str]]:
        """Insert ACCEPT rules for the bridge at the top of the FORWARD chain (a DROP policy, as Docker sets,
        otherwise drops the bridged traffic); returns the commands' ``[iptables, *rule]`` added, for ``down``."""
        added = []
        for exe in iptables_flavours():
            for rule in forward_rules(self.bridge):
                done = subprocess.run([exe, "-w", "-I", *rule], capture_output=True, text=True, timeout=30)
                if done.returncode == 0:
                    added.append([exe, *rule])
        return added

    def check_forwarding(self, state: dict | None = None, timeout: float = FORWARD_CHECK_S) -> None:
        """Check that a TCP connection passes from one namespace of the harness to another (or from this host
        to the only one); raise :class:`ForwardingBlocked` naming the FORWARD chain when it does not."""
        state = state or self.state()
        services = list(state["services"])
        if not services:
            return
        target, addr = services[0], state["addrs"][services[0]]
        prefix = ["ip", "netns", "exec", self.ns(services[1])] if len(services) > 1 else []
        source = self.ns(services[1]) if len(services) > 1 else "this host"
        listener = subprocess.Popen(["ip", "netns", "exec", self.ns(target), sys.executable, "-c", _LISTEN, addr,
                                     str(timeout + 5)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = listener.stdout, listener.stderr
        assert out is not None and err is not None  # both piped
        try:
            ready, _, _ = select.select([out], [], [], 20.0)  # it prints its port at once (or exits)
            port = out.readline().strip() if ready else ""
            if not port.isdigit():
                raise ValueError(f"netns up: cannot listen in {self.ns(target)} on {addr} "
                                 f"({' '.join(err.read().split())[:200]})")
            probe = subprocess.run([*prefix, sys.executable, "-c", _CONNECT, addr, port, str(timeout)],
                                   capture_output=True, text=True, timeout=timeout + 20)
        finally:
            listener.kill()
            listener.wait(timeout=10)
            out.close()
            err.close()
        if probe.returncode == 0:
            return
        policy = forward_policy()
        if iptables() is None:
            fix = ("iptables is not installed, so the harness cannot add its ACCEPT rules for the bridge: "
                   "install it (apt-get install iptables) or set the FORWARD policy to ACCEPT")
        elif not state.get("forward_rules"):
            fix = (f"adding the harness's rules `iptables -I FORWARD -i {self.bridge} -j ACCEPT` (and -o) failed; "
                   "check `iptables -S FORWARD`")
        else:
            fix = (f"even with the harness's rules `iptables -I FORWARD -i/-o {self.bridge} -j ACCEPT`: look for an "
                   f"earlier DROP rule in `iptables -S FORWARD`")
        raise ForwardingBlocked(
            f"netns up: traffic does not pass on bridge {self.bridge} (TCP from {source} to {target} {addr}:{port}: "
            f"{' '.join(probe.stdout.split()) or 'no connection'} within {timeout:.0f} s): the host firewall drops "
            f"forwarded bridge traffic (iptables FORWARD chain policy: {policy}; Docker sets it to DROP); {fix}")

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
        """Cut (``up=False``) or heal a service's only link. A healed link announces its address (gratuitous ARP,
        ``arp_notify``, as a host's network manager does when its link comes back): the others' ARP entries for
        it failed during the cut, and without the announcement they retry only every second (measured: a cut
        router's trackers re-connected up to 1 s after the heal instead of at once)."""
        if up:
            subprocess.run(["ip", "netns", "exec", self.ns(service), "sh", "-c",
                            "echo 1 > /proc/sys/net/ipv4/conf/eth0/arp_notify"], capture_output=True, timeout=30)
        _ip("-n", self.ns(service), "link", "set", "eth0", "up" if up else "down")

    def impair(self, a: str, b: str, imp: link_impair.Impairment, backend: str = "auto") -> str:
        """Impair the path between services ``a`` and ``b`` (replacing an impairment already there); returns
        the backend used (netem or userspace)."""
        state = self.state()
        for s in (a, b):
            if s not in state.get("services", {}):
                raise ValueError(f"no service {s!r} in the harness in {self.dir} (services: {', '.join(state.get('services', {}))})")
        if a == b:
            raise ValueError(f"impair needs two different services, got {a!r} twice")
        self.clear(a, b)
        state = self.state()
        links = state.setdefault("impairments", {})
        used = {entry["index"] for entry in links.values()}
        index = next(n for n in range(len(used) + 1) if n not in used)
        made = link_impair.setup_link(self.tag, index, {s: (self.ns(s), state["addrs"][s]) for s in (a, b)}, imp,
                                      backend, str(self.dir / "logs"))
        made["index"] = index
        links[link_impair.pair_key(a, b)] = made
        self.state_file.write_text(json.dumps(state))
        return made["backend"]

    def clear(self, a: str, b: str) -> bool:
        """Remove the impairment between ``a`` and ``b``; False when there was none."""
        state = self.state()
        made = state.get("impairments", {}).pop(link_impair.pair_key(a, b), None)
        if made is None:
            return False
        link_impair.clear_link(made)
        self.state_file.write_text(json.dumps(state))
        return True

    def signal(self, service: str, sig: int) -> None:
        pid = self.state()["services"][service].get("pid")
        if pid:
            try:
                os.killpg(pid, sig)
            except ProcessLookupError:
                pass

    def found_by_tag(self) -> dict:
        """What exists of this tag's harness when its state file is gone (its folder removed, its ``up`` killed):
        the namespaces with the processes in them, the links, the bridge and its FORWARD rules, in the state
        file's own shape so that :meth:`down` removes them alike."""
        spaces = [ln.split()[0] for ln in _out("ip", "netns", "list").splitlines() if ln.strip()]
        links = [ln.split(":", 2)[1].strip().split("@")[0] for ln in _out("ip", "-o", "link", "show").splitlines()
                 if ln.count(":") >= 2]
        services = {ns: {"ns": ns, "veth": "", "pids": [int(p) for p in _out("ip", "netns", "pids", ns).split()]}
                    for ns in spaces if ns.startswith(f"zt{self.tag}-")}
        veths = [n for n in links if n.startswith(f"zt{self.tag}v")]
        bridge = self.bridge if self.bridge in links else ""
        rules = [[exe, *rule] for exe in iptables_flavours() for rule in forward_rules(self.bridge)] if bridge else []
        return {"services": services, "links": veths, "bridge": bridge, "forward_rules": rules}

    def down(self, grace: float = 5.0, orphans: bool = False) -> None:
        """Stop every process, then remove namespaces, links, the bridge and the hosts files. Without a state file
        nothing is removed (what exists belongs to another harness) unless ``orphans`` asks for whatever this
        tag's harness left (:meth:`found_by_tag`): a user's explicit ``zentrack netns down --tag T``."""
        state = self.state() or (self.found_by_tag() if orphans else {})
        for made in (state.get("impairments") or {}).values():
            link_impair.clear_link(made)
        for s in state.get("services", {}).values():  # processes in a namespace that no state file names
            for pid in s.get("pids", []):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        pids = [s.get("pid") for s in state.get("services", {}).values() if s.get("pid")]
        for pid in pids:
            for sig in (signal.SIGCONT, signal.SIGTERM):
                try:
                    os.killpg(pid, sig)
                except ProcessLookupError:
                    pass
        end = time.time() + grace
        for pid in pids:
            while time.time() < end and process_running(pid):
                time.sleep(0.1)
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for s in state.get("services", {}).values():
            subprocess.run(["ip", "netns", "del", s["ns"]], capture_output=True)
            if s["veth"]:
                subprocess.run(["ip", "link", "del", s["veth"]], capture_output=True)
            shutil.rmtree(Path("/etc/netns") / s["ns"], ignore_errors=True)
        for veth in state.get("links", []):
            subprocess.run(["ip", "link", "del", veth], capture_output=True)
        for exe, *rule in state.get("forward_rules") or []:
            for _ in range(20):  # every copy of it
                if subprocess.run([exe, "-w", "-D", *rule], capture_output=True, timeout=30).returncode:
                    break
        if state.get("bridge"):
            subprocess.run(["ip", "link", "del", state["bridge"]], capture_output=True)
        if self.state_file.exists():
            self.state_file.unlink()


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=("up", "down", "cut", "heal", "impair", "clear"))
    p.add_argument("service", nargs="?", help="service name (cut, heal; the first of two for impair, clear)")
    p.add_argument("peer", nargs="?", help="impair, clear: the service at the other end of the link")
    p.add_argument("--compose", default="deploy/docker-compose.yml", help="compose file (up)")
    p.add_argument("--dir", default="out/netns", help="run folder: logs/, volumes/, netns.json")
    p.add_argument("--tag", default="a", help="1-3 characters that keep parallel harnesses apart (default a)")
    link_impair.add_impair_arguments(p)


def run(args: argparse.Namespace) -> int:
    h = Harness(Path(args.dir), args.tag)
    if args.action == "up":
        zentrack = shutil.which("zentrack") or str(Path(sys.executable).with_name("zentrack"))
        try:
            state = h.up(Path(args.compose), zentrack)
        except BaseException:
            if h.created:  # never before: what exists then belongs to another harness
                h.down()
            raise
        for s, a in state["addrs"].items():
            print(f"{s:12s} {a:14s} ns {h.ns(s)}")
    elif args.action == "down":
        if h.state():
            h.down()
            print(f"harness in {args.dir} is down")
        else:  # its folder is gone (or another): remove what the tag's harness left, found by its names
            left = h.found_by_tag()
            h.down(orphans=True)
            print(f"no harness state in {args.dir}; removed tag {args.tag!r}'s {len(left['services'])} namespaces"
                  + (f" and bridge {left['bridge']}" if left["bridge"] else ""))
    elif args.action in ("impair", "clear"):
        if not (args.service and args.peer):
            raise ValueError(f"{args.action} needs two service names (the two ends of the link)")
        if args.action == "impair":
            imp = link_impair.impairment_from_args(args)
            if not h.state():
                raise ValueError(f"no harness runs in {args.dir} (start one with `zentrack netns up`)")
            backend = h.impair(args.service, args.peer, imp, args.impair_backend)
            print(f"{args.service} <-> {args.peer}: {imp.delay_ms} +- {imp.jitter_ms} ms, loss {imp.loss}, "
                  f"rate {imp.rate_kbit or 'unlimited'} kbit/s ({backend})")
        else:
            print(f"{args.service} <-> {args.peer}: " + ("cleared" if h.clear(args.service, args.peer) else "was not impaired"))
    else:
        if not args.service:
            raise ValueError(f"{args.action} needs a service name")
        h.set_link(args.service, args.action == "heal")
        print(f"{args.service}: link {'up' if args.action == 'heal' else 'down'}")
    return 0
