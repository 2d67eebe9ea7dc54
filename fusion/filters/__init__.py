"""Local filters behind one interface (:class:`LocalFilter`), found by name in :data:`FILTER_REGISTRY`.

Built-ins register when their module is imported (below, in the order of :data:`LOCAL_FILTERS`); any other
module file in this package is imported when the registry is first used, so a new filter is one new file.
"""
from __future__ import annotations

import numpy as np

from ..measurement import MeasurementModel
from ..motion import MotionModel
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, NodeFilter

# the built-ins, imported in registration order: teskf, eskf, ekf, ukf, ckf
from .extended_state import ExtendedStateKalmanFilter, augmented_p0, saturate, trace_balance_theta  # isort: skip
from .ekf import ExtendedKalmanFilter  # isort: skip
from .sigma_point import (  # isort: skip
    PointSet,
    SigmaPointKalmanFilter,
    cubature_kalman_filter,
    cubature_points,
    unscented_kalman_filter,
    unscented_points,
)
from .gaussian_node import GaussianNodeFilter, make_node_filter, stack_scans  # isort: skip

#: the registered filter names (built-ins first, then the modules found in this package)
LOCAL_FILTERS: tuple[str, ...] = FILTER_REGISTRY.names()


def make_local_filter(
    kind: str,
    motion: MotionModel,
    measurement: MeasurementModel,
    p0: np.ndarray,
    lumped_var: float = 1.0,
    qbar: float = 1e-6,
    theta: float | None = None,
) -> LocalFilter:
    """Build a batched local filter by name (one of :data:`LOCAL_FILTERS`) through the registry.

    ``p0`` is the kinematic prior covariance; extended-state filters add ``lumped_var`` I for their
    augmented blocks and, with ``theta=None``, pick theta by the trace balance against that P0.
    ``qbar`` and ``theta`` go to the filters that take them; the others ignore them.
    """
    accepted = {p.name for p in FILTER_REGISTRY.params(kind)}
    params = {k: v for k, v in (("qbar", qbar), ("theta", theta)) if k in accepted}
    built = FILTER_REGISTRY.create(kind, params, FilterContext(motion, measurement, p0, lumped_var))
    if not isinstance(built, LocalFilter):
        raise TypeError(f"local filter {kind!r} runs in a single tracker only (it is not a batched LocalFilter)")
    return built


__all__ = [
    "FILTER_REGISTRY",
    "LOCAL_FILTERS",
    "ExtendedKalmanFilter",
    "ExtendedStateKalmanFilter",
    "FilterContext",
    "GaussianNodeFilter",
    "LocalFilter",
    "NodeFilter",
    "PointSet",
    "SigmaPointKalmanFilter",
    "augmented_p0",
    "cubature_kalman_filter",
    "cubature_points",
    "make_local_filter",
    "make_node_filter",
    "saturate",
    "stack_scans",
    "trace_balance_theta",
    "unscented_kalman_filter",
    "unscented_points",
]
