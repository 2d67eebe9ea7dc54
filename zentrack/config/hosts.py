"""How a run's trackers are split over hosts: consecutive blocks, one router per host (``zentrack compose
--hosts``, the namespace harness, the capacity model)."""
from __future__ import annotations


def host_of(node: int, nodes: int, hosts: int) -> int:
    """The host of tracker ``node`` when ``nodes`` trackers are split into ``hosts`` consecutive blocks (sizes
    differ by at most one; a ring's neighbours share a host except at the blocks' ends)."""
    return next(h for h in range(hosts) if node < (h + 1) * nodes // hosts)
