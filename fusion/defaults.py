"""Defaults (and the one cap on rounds) shared by the filters, the fusion rules and their registry entries, the
simulator, the configuration, the command line and the benches: each stated once, here.

Pure constants (no imports), so importing them costs nothing on a tracker's start.
"""
from __future__ import annotations

#: bound on E|d^order F_r|^2 per lumped component of the extended-state filters (paper 0 Assumption 2); every
#: ``qbar`` parameter, flag and scenario key defaults to it
DEFAULT_QBAR = 1e-6

#: the local filter a run uses when neither the scenario nor a flag names one (the DTESKF node of paper 0)
DEFAULT_FILTER = "teskf"

#: the fusion rule a run uses when neither the scenario nor a flag names one (CI diffusion, paper 0)
DEFAULT_FUSION = "ci"

#: the word in the place of a fusion rule (``--fusion``, TOML ``[fusion] rule``) for the centralized filter: one
#: centre with every node's measurements (paper 0 Algorithm 1 on the stacked measurements), which only the
#: batched simulator runs (a live run has a tracker per sensor)
CENTRALIZED = "centralized"

#: a realtime tracker fuses at ``t_k + DEFAULT_DEADLINE_FRAC * Ts`` unless the scenario or a flag says otherwise
DEFAULT_DEADLINE_FRAC = 0.5

#: false-rejection probability of each tracker's chi-square gate on its neighbours' messages (0: no gate)
DEFAULT_GATE = 1e-3

#: the most fusion (or consensus) rounds per step any rule takes: every round is a message per node
MAX_ROUNDS = 32
#: the trackers a many-target node may run: GNN with M-of-N confirmation, or a PMBM filter (point sensors)
MULTITARGET_TRACKERS = ("gnn", "pmbm")
