"""Relayed two-hop scans (fusion rules with ``relay_scans``): what a node relays and which relayed scans it uses.

After its estimate a node relays the scans its neighbours forwarded for step k (one ``relay`` message on
``scan/<i>``); each neighbour then updates its prior with the own, the one-hop and the relayed two-hop scans,
one scan per origin. Two relays that carry different scans of one origin are a conflict: neither is used.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from zentrack.fusion.scan import Scan


def same_scan(a: Scan, b: Scan) -> bool:
    """Whether two relayed copies of one origin's scan carry the same returns, pose and noise."""
    return (np.array_equal(a.returns, b.returns) and np.array_equal(a.pose, b.pose)
            and np.array_equal(a.noise_cov, b.noise_cov))


def relayable(forwarded: Iterable[Scan]) -> list[Scan]:
    """The forwarded scans a node relays: those with returns ("no scan" needs no relay)."""
    return [s for s in forwarded if s.count > 0]


@dataclass
class RelayMerge:
    """The two-hop scans a node uses for one step, by origin, and the origins it refused as disputed."""

    extra: dict[int, Scan] = field(default_factory=dict)
    disputed: list[int] = field(default_factory=list)


def merge_relays(relays: Mapping[int, Iterable[Scan]], have: set[int]) -> RelayMerge:
    """The relayed scans of origins the node does not have yet (``have``: its own, its neighbours' and the
    scans it already holds), taking the senders in id order; an origin that two relays disagree about is
    disputed and used from neither."""
    out = RelayMerge()
    disputed: set[int] = set()
    for sender in sorted(relays):
        for scan in relays[sender]:
            origin = scan.sensor
            if origin in have or origin in disputed:
                continue
            if origin in out.extra and not same_scan(out.extra[origin], scan):
                del out.extra[origin]
                disputed.add(origin)
                out.disputed.append(origin)
                continue
            out.extra.setdefault(origin, scan)
    return out


def with_relayed(scans: list[Scan], extra: Mapping[int, Scan], own: int) -> list[Scan]:
    """The scans of the prior's update: the own first, then by origin (as the batched simulator stacks them)."""
    mine = [s for s in scans if s.sensor == own]
    others = sorted([s for s in scans if s.sensor != own] + list(extra.values()), key=lambda s: s.sensor)
    return mine + others
