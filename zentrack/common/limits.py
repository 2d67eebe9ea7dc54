"""The limits a run's numbers obey, shared by the scenario files (:mod:`zentrack.config.scenario_config`, which
bounds every TOML key), the flags that override them (:mod:`zentrack.common.argtypes`) and the wire format (a
node id is below :data:`MAX_NODES`): generous for any real tracker, tight enough that no value reaches a
MemoryError, an overflow or a degenerate covariance.  Pure constants, so a tracker parses its flags without
importing the scenario catalogue.
"""
from __future__ import annotations

MAX_STEPS = 1_000_000
MAX_NODES = 1000
MAX_RUNS = 10_000
MAX_NODE_STEPS = 10_000_000  # runs x steps x nodes of one simulation (every array is a multiple of it)
MAX_SEED = 2**63 - 1
#: (low, high), both inclusive, of the extended-state filters' qbar and theta (``[filter]`` keys and flags)
QBAR_RANGE = (1e-15, 1e6)
THETA_RANGE = (1e-12, 1e12)
