"""A fusion rule that lives outside the package (a user's plug-in, named in a scenario's ``plugins``).

``ci-scans``: every node forwards its scan to its neighbours before the local update, updates with its own
and its neighbours' scans (stacked), then fuses by CI diffusion: the measurement-sharing pattern of paper 2
with paper 0's fusion. Used by ``tests/test_contracts.py`` to prove that a scan-exchanging rule runs on the
unchanged runtime.
"""
from __future__ import annotations

from zentrack.fusion.covariance_intersection import ci_fuse
from zentrack.fusion.rules import RULE_REGISTRY, FusionRule


class CIWithScans(FusionRule):
    name = "ci-scans"
    exchanges_scans = True

    def combine(self, round, weights, messages, present=None):
        return {name: ci_fuse(weights, pair, present) for name, pair in messages.items()}


if "ci-scans" not in RULE_REGISTRY:
    RULE_REGISTRY.register("ci-scans", CIWithScans, (), "CI diffusion after exchanging scans with the neighbours")
