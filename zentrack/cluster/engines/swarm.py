"""A Docker Swarm's nodes as the soak drives them: which engine runs each node's tasks, which tracker slots a node
holds, and a node drained and made active again (``docker node update --availability``).

The soak reaches a task's container through the engine of the node it runs on: this host's own, and the namespace
workers of ``deploy/swarm-nodes.sh`` (each with its socket at ``/run/zentrack-swarm/ztsw<i>/docker.sock``). A
node whose engine the soak cannot reach is refused before anything starts (:func:`engines`).

A drain (:func:`pick_drain`) takes the active worker that holds the most tracker tasks: swarm stops them there
and starts each again, same slot, on another node (the stack spreads trackers over the ``zentrack.zone``
label); the drained node's own router waits, pending, until the node is active again. A worker holding a
tracker that another fault hits near the drain is not drained (``avoid``). Swarm does not move tasks
back when a node returns; a later kill's replacement is placed by the spread again, so drains keep finding
trackers to move.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from zentrack.cluster.engines.docker import DockerError, docker

#: where deploy/swarm-nodes.sh keeps its namespace workers' engines
NAMESPACE_WORKERS = Path("/run/zentrack-swarm")


@dataclass(frozen=True)
class SwarmNode:
    """One node of the swarm: its id, host name, role (``manager``/``worker``), availability and status."""

    node_id: str
    hostname: str
    role: str
    availability: str
    status: str


def swarm_nodes() -> list[SwarmNode]:
    """The swarm's nodes (this engine must be a manager), by host name."""
    lines = docker("node", "ls", "--format", "{{.ID}} {{.Hostname}} {{.Status}} {{.Availability}} {{.ManagerStatus}}",
                   timeout=30).splitlines()
    nodes = []
    for line in lines:
        parts = line.split()
        role = "manager" if len(parts) > 4 else "worker"  # ManagerStatus is empty on a worker
        nodes.append(SwarmNode(parts[0], parts[1], role, parts[3].lower(), parts[2].lower()))
    return sorted(nodes, key=lambda n: n.hostname)


def swarm_nodes_or_none() -> list[SwarmNode]:
    """:func:`swarm_nodes`, or none when the engine does not answer or manages no swarm."""
    try:
        if docker("info", "-f", "{{.Swarm.ControlAvailable}}", timeout=30) != "true":
            return []
        return swarm_nodes()
    except DockerError:
        return []


def engines() -> dict[str, str | None]:
    """node id -> the DOCKER_HOST address of the engine that runs its tasks (None: this host's own engine).
    ValueError naming a node of the swarm that none of them is."""
    found: dict[str, str | None] = {docker("info", "-f", "{{.Swarm.NodeID}}", timeout=30): None}
    for sock in sorted(NAMESPACE_WORKERS.glob("ztsw*/docker.sock")):
        address = f"unix://{sock}"
        node_id = docker("info", "-f", "{{.Swarm.NodeID}}", host=address, timeout=30, check=False)
        if node_id:
            found[node_id] = address
    missing = [n.hostname for n in swarm_nodes() if n.node_id not in found and n.status == "ready"]
    if missing:
        raise ValueError(f"swarm node(s) {', '.join(missing)}: no engine the soak can reach to act on their tasks "
                         f"(it reaches this host's and the namespace workers of deploy/swarm-nodes.sh)")
    return found


def tracker_slots(stack: str, node_id: str) -> list[int]:
    """The tracker ids whose running task (slot id + 1) is on ``node_id``."""
    names = docker("service", "ps", f"{stack}_node", "--filter", "desired-state=running", "--filter",
                   f"node={node_id}", "--format", "{{.Name}}", timeout=30, check=False).split()
    return sorted({int(name.rsplit(".", 1)[1]) - 1 for name in names if "." in name})


def pick_drain(stack: str, nodes: list[SwarmNode], avoid: frozenset[int] | set[int] = frozenset()
               ) -> tuple[SwarmNode | None, list[int]]:
    """The active, ready worker holding the most of ``stack``'s tracker tasks (ties: the first by host name) and
    those trackers, among the workers that hold none of the trackers in ``avoid`` (the soak's trackers another
    fault hits near the drain: a tracker is never under two at once); (None, []) when the swarm has no such
    worker."""
    best: tuple[SwarmNode | None, list[int]] = (None, [])
    for node in nodes:
        if node.role != "worker" or node.availability != "active" or node.status != "ready":
            continue
        slots = tracker_slots(stack, node.node_id)
        if avoid.intersection(slots):
            continue
        if best[0] is None or len(slots) > len(best[1]):
            best = (node, slots)
    return best


def set_availability(node: SwarmNode, availability: str) -> None:
    """``docker node update --availability`` (active, pause or drain)."""
    docker("node", "update", "--availability", availability, node.node_id, timeout=60)
