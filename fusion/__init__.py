"""zentrack.fusion: the pure mathematics of zentrack (numpy/scipy only; no I/O, no clocks).

Component families:
- motion and measurement models (:mod:`.motion`, :mod:`.measurement`),
- local filters behind one interface (:mod:`.filters`: TESKF, ESKF, EKF, UKF, CKF),
- fusion rules on information pairs (:mod:`.fusion_rules`: CI diffusion, independent fusion),
- graphs and weights (:mod:`.graphs`), metrics (:mod:`.metrics`),
- scenarios and the batched network simulator (:mod:`.scenario`, :mod:`.simulator`).
"""
from .filters import LOCAL_FILTERS, LocalFilter, make_local_filter
from .fusion_rules import ci_fuse, independent_fuse, renormalise_rows
from .linalg import GaussianState, InformationPair, from_information, to_information
from .scenario import SCENARIOS, ScenarioData, ScenarioSpec, builtin_spec, simulate
from .simulator import FILTERS, NetworkResult, evaluate, run_filter

__all__ = [
    "FILTERS",
    "LOCAL_FILTERS",
    "SCENARIOS",
    "GaussianState",
    "InformationPair",
    "LocalFilter",
    "NetworkResult",
    "ScenarioData",
    "ScenarioSpec",
    "builtin_spec",
    "ci_fuse",
    "evaluate",
    "from_information",
    "independent_fuse",
    "make_local_filter",
    "renormalise_rows",
    "run_filter",
    "simulate",
    "to_information",
]
