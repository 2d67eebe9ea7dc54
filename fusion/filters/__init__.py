"""Local filters behind one interface (:class:`LocalFilter`), found by name in :data:`FILTER_REGISTRY`.

A filter's module is imported the first time its name is asked for (a tracker running ``teskf`` imports
``extended_state`` and no other filter): the registry is told below which module registers which names, the
built-ins (teskf, eskf, ekf, ukf, ckf) first, in the order of :data:`LOCAL_FILTERS`.  Any other module file in
this package is found by the registry's discovery, so a new filter is one new file (naming it below only
spares a tracker the search).  The classes and helpers listed in ``__all__`` are imported on first access.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..defaults import DEFAULT_QBAR
from ..measurement import MeasurementModel
from ..motion import MotionModel
from ..registry import lazy_package_getattr
from .base import FILTER_REGISTRY, FilterContext, LocalFilter, NodeFilter

if TYPE_CHECKING:
    from .ekf import ExtendedKalmanFilter
    from .extended_state import ExtendedStateKalmanFilter, augmented_p0, saturate, trace_balance_theta
    from .gaussian_node import GaussianNodeFilter, make_node_filter, stack_scans
    from .sigma_point import (
        PointSet,
        SigmaPointKalmanFilter,
        cubature_kalman_filter,
        cubature_points,
        unscented_kalman_filter,
        unscented_points,
    )

    LOCAL_FILTERS: tuple[str, ...]

#: module -> the filters it registers; built-ins first (in registration order), then the other modules of this
#: package (listed in file-name order among the discovered ones whatever their place here)
_MODULES: tuple[tuple[str, tuple[str, ...], bool], ...] = (
    ("extended_state", ("teskf", "eskf"), True),
    ("ekf", ("ekf",), True),
    ("sigma_point", ("ukf", "ckf"), True),
    ("mem", ("mem-ekf", "mem-if"), False),
    ("pda_fpf", ("pda-fpf",), False),
    ("pda_pf", ("pda-pf",), False),
    ("pdaf_ekf", ("pdaf-ekf", "nn-ekf"), False),
    ("seckf", ("seckf", "lin"), False),
    ("srcif", ("srcif",), False),
)
for _module, _names, _builtin in _MODULES:
    FILTER_REGISTRY.expect(f"{__name__}.{_module}", _names, builtin=_builtin)
del _module, _names, _builtin

#: where each lazily imported name of this package is defined
_LAZY = {
    "ExtendedStateKalmanFilter": "extended_state", "augmented_p0": "extended_state", "saturate": "extended_state",
    "trace_balance_theta": "extended_state", "ExtendedKalmanFilter": "ekf",
    "PointSet": "sigma_point", "SigmaPointKalmanFilter": "sigma_point", "cubature_kalman_filter": "sigma_point",
    "cubature_points": "sigma_point", "unscented_kalman_filter": "sigma_point", "unscented_points": "sigma_point",
    "GaussianNodeFilter": "gaussian_node", "make_node_filter": "gaussian_node", "stack_scans": "gaussian_node",
}


#: ``LOCAL_FILTERS`` (every registered name, built-ins first, then the modules found in this package) and the
#: filter classes, imported on first use
__getattr__ = lazy_package_getattr(__name__, globals(), "LOCAL_FILTERS", FILTER_REGISTRY, _LAZY)


def make_local_filter(
    kind: str,
    motion: MotionModel,
    measurement: MeasurementModel,
    p0: np.ndarray,
    lumped_var: float = 1.0,
    qbar: float = DEFAULT_QBAR,
    theta: float | None = None,
    params: dict[str, Any] | None = None,
) -> LocalFilter:
    """Build a batched local filter by name (one of :data:`LOCAL_FILTERS`) through the registry.

    ``p0`` is the kinematic prior covariance; extended-state filters add ``lumped_var`` I for their
    augmented blocks and, with ``theta=None``, pick theta by the trace balance against that P0.
    ``qbar`` and ``theta`` go to the filters that take them; the others ignore them. ``params``: the filter's
    other parameters (a scenario's ``[filter]`` keys), checked by the registry.
    """
    accepted = {p.name for p in FILTER_REGISTRY.params(kind)}
    params = {**(params or {}), **{k: v for k, v in (("qbar", qbar), ("theta", theta)) if k in accepted}}
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
