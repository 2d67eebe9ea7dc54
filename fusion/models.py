"""Motion models (plants) and measurement models by name, as a tracker builds them from its configuration.

:data:`PLANT_REGISTRY` maps a plant's name to its factory ``factory(ts, **params)`` and the parameters it takes
(:data:`PLANT_PARAMS`); :data:`MEASUREMENT_REGISTRY` maps a measurement model's name to
``factory(linear_matrix)``. :func:`make_plant` and :func:`make_measurement` build one by name with the checks
every caller relies on. Scenarios (:mod:`zentrack.truth.simulation.scenario`), the bound
(:mod:`zentrack.study.pcrlb`) and a tracker process all build their models here, so a tracker needs no scenario module to know what its plant is.

Plants tagged ``nonlinear-truth`` (:data:`NONLINEAR_TRUTH`) have their truth propagated through their nonlinear
``f`` instead of an ``A x + B F(x)`` form. Models whose code is large or rarely used (the extended object, the
ship plants, the extent measurement of paper 4) are imported when first built.
"""
from __future__ import annotations

import numpy as np

from .measurement import BearingModel, LinearModel, MeasurementModel, PointModel
from .motion import ConstantAcceleration3D, ContinuousCV3D, Exp1Plant, ManeuveringCV3D, MotionModel
from .registry import Param, Registry

Array = np.ndarray

#: plants by name; a factory is ``factory(ts, **params) -> MotionModel`` with only the parameters given
PLANT_REGISTRY: Registry[MotionModel] = Registry("plant")
#: measurement models by name; a factory is ``factory(linear_matrix) -> MeasurementModel``
MEASUREMENT_REGISTRY: Registry[MeasurementModel] = Registry("measurement")

#: extended-object measurement kind -> (object shape, C^h) (paper 4: the spread of the points on the object)
EXTENT_MEASUREMENTS = {"extent-ellipse": ("ellipse", np.eye(2) / 4.0),
                       "extent-rectangle": ("rectangle", np.eye(2) / 3.0)}


def _plant(name: str, params: tuple[str, ...], summary: str, tags: tuple[str, ...] = ()):
    """Register the decorated factory as plant ``name`` taking the (float) ``params``."""

    def add(factory):
        PLANT_REGISTRY.register(name, factory, tuple(Param(p, float, None) for p in params), summary, tags)
        return factory

    return add


@_plant("exp1", ("q", "d_amp", "d_freq"), "paper 0 Experiment 1 (eq. 63), two states")
def _exp1(ts: float, **params: float) -> MotionModel:
    return Exp1Plant(ts=ts, **params)


@_plant("cv3d", ("sigma_w", "alpha", "beta", "turn_rate"), "paper 0 Experiment 2 (eq. 66): manoeuvring 3-D constant velocity")
def _cv3d(ts: float, **params: float) -> MotionModel:
    return ManeuveringCV3D(ts=ts, **params)


@_plant("cv3d-cd", ("q", "em_steps"), "3-D constant velocity of a continuous-discrete system")
def _cv3d_cd(ts: float, **params: float) -> MotionModel:
    return ContinuousCV3D(ts=ts, q=params.get("q", 0.1), em_steps=int(params.get("em_steps", 10)))


@_plant("ca9", ("sigma_w",), "3-D constant acceleration, nine states")
def _ca9(ts: float, **params: float) -> MotionModel:
    return ConstantAcceleration3D(ts=ts, sigma_w=params.get("sigma_w", 0.1))


@_plant("ship-turn", ("a_m", "k_psi"), "paper 3 ship turning at constant acceleration", ("nonlinear-truth",))
def _ship_turn(ts: float, **params: float) -> MotionModel:
    from .motion_ship import ShipTurnCA

    return ShipTurnCA(ts=ts, a_m=params.get("a_m", 0.5), k_psi=params.get("k_psi", 1e-5))  # type: ignore[return-value]


@_plant("ship-power", ("power", "eta", "mass"), "paper 3 ship at constant power", ("nonlinear-truth",))
def _ship_power(ts: float, **params: float) -> MotionModel:
    from .motion_ship import ShipConstantPower

    return ShipConstantPower(  # type: ignore[return-value]
        ts=ts, power=params.get("power", 2.4e5), eta=params.get("eta", 10.0), mass=params.get("mass", 1e4))


@_plant("eot", ("q_pos", "q_vel", "q_alpha", "q_l1", "q_l2"), "paper 4 extended object (S2's defaults, Table 2)")
def _eot(ts: float, **params: float) -> MotionModel:
    from .motion_eot import ExtendedObjectMotion

    q_pos, q_vel = params.get("q_pos", 100.0), params.get("q_vel", 1.0)
    return ExtendedObjectMotion(  # type: ignore[return-value]
        ts, np.diag([q_pos, q_pos, q_vel, q_vel]),
        np.diag([params.get("q_alpha", 0.05), params.get("q_l1", 1.0), params.get("q_l2", 1.0)]))


def _linear(linear_matrix: Array | None) -> MeasurementModel:
    if linear_matrix is None:
        raise ValueError("a linear measurement needs linear_matrix")
    return LinearModel(linear_matrix)


def _extent(kind: str):
    def build(linear_matrix: Array | None) -> MeasurementModel:
        from .filters.mem import ExtentPointModel

        return ExtentPointModel(EXTENT_MEASUREMENTS[kind][1], np.zeros((2, 2)))  # type: ignore[return-value]

    return build


MEASUREMENT_REGISTRY.register("bearing", lambda linear_matrix: BearingModel(), (), "azimuth and elevation")
MEASUREMENT_REGISTRY.register("point", lambda linear_matrix: PointModel(), (), "Cartesian position")
MEASUREMENT_REGISTRY.register("linear", _linear, (), "z = H x with the scenario's linear_matrix H")
for _kind in EXTENT_MEASUREMENTS:  # the noise C^v comes with every scan
    MEASUREMENT_REGISTRY.register(_kind, _extent(_kind), (), f"points on an extended object ({_kind[7:]})")
del _kind

PLANTS: tuple[str, ...] = PLANT_REGISTRY.names()
#: plant -> the names of the parameters it takes
PLANT_PARAMS: dict[str, tuple[str, ...]] = {n: tuple(p.name for p in PLANT_REGISTRY.params(n)) for n in PLANTS}
#: plants whose truth is propagated through their nonlinear ``f`` (not an ``A x + B F(x)`` form)
NONLINEAR_TRUTH: tuple[str, ...] = tuple(n for n in PLANTS if "nonlinear-truth" in PLANT_REGISTRY.entry(n).tags)
MEASUREMENTS: tuple[str, ...] = MEASUREMENT_REGISTRY.names()


def make_plant(name: str, ts: float, params: dict[str, float]) -> MotionModel:
    """The motion model ``name`` with sample period ``ts`` and parameters (see :data:`PLANT_PARAMS`)."""
    if name not in PLANT_PARAMS:
        raise ValueError(f"unknown plant {name!r}; choose one of {PLANTS}")
    unknown = sorted(set(params) - set(PLANT_PARAMS[name]))
    if unknown:
        raise ValueError(f"plant {name!r} has no parameter(s) {unknown}; allowed: {PLANT_PARAMS[name]}")
    bad = [k for k, v in params.items() if not np.isfinite(v)]
    if bad:
        raise ValueError(f"plant parameter(s) {bad} must be finite")
    return PLANT_REGISTRY.entry(name).factory(ts, **params)


#: plants a tracker may predict over any interval (sensors of their own, ``node/detections.py``), and how their
#: process noise follows the interval: ``per-step`` plants give Q per sample period ts (over dt it is scaled by
#: dt / ts: the same noise per second), ``intensity`` plants build Q from the interval itself
INTERVAL_PLANTS = {"cv3d": "per-step", "ca9": "per-step", "cv3d-cd": "intensity"}


def plant_over(name: str, ts: float, dt: float, params: dict[str, float]) -> MotionModel:
    """Plant ``name`` (sample period ``ts``) over an interval of ``dt`` seconds: its transition over dt and the
    process noise of dt (:data:`INTERVAL_PLANTS`). ValueError for a plant defined on its sample period alone
    (exp1's discrete map, the ships, the extended object) or a ``dt`` that is zero or not finite.

    A negative ``dt`` predicts back (a neighbour's estimate valid a few ms after a tracker's fusion time,
    ``node/diffusion/neighbour_clocks.py``): the transition over dt, with the process noise of ``|dt|``, so an
    estimate loses information whichever way it is carried. (A retrodiction's exact noise, ``A(dt) Q(|dt|)
    A(dt)^T`` from ``x(t) = A(dt) (x(t + |dt|) - w)`` (Bar-Shalom 2002, algorithm A, as ``fusion/filters/oosm.py``
    retrodicts), differs from it at order ``dt^2`` and above: nothing over the few ms a tracker predicts back.)"""
    if name not in INTERVAL_PLANTS:
        raise ValueError(f"plant {name!r} is defined on its sample period only; predicting over any interval "
                         f"(sensors of their own) takes one of {', '.join(INTERVAL_PLANTS)}")
    if not (np.isfinite(dt) and dt != 0):
        raise ValueError(f"an interval must be finite and not zero, got {dt!r}")
    plant = make_plant(name, dt, params)
    if dt < 0:  # the noise of |dt|
        forward = make_plant(name, -dt, params)
        plant.Q = forward.Q
        if hasattr(forward, "noise_factor") and hasattr(plant, "noise_factor"):
            plant.noise_factor = forward.noise_factor
    if INTERVAL_PLANTS[name] == "per-step":
        plant.Q = plant.Q * (abs(dt) / ts)
        if hasattr(plant, "noise_factor"):
            plant.noise_factor = plant.noise_factor * float(np.sqrt(abs(dt) / ts))
    return plant


def make_measurement(kind: str, linear_matrix: Array | None = None) -> MeasurementModel:
    """The measurement model ``kind`` (one of :data:`MEASUREMENTS`; ``linear`` needs ``linear_matrix``)."""
    if kind not in MEASUREMENT_REGISTRY:
        raise ValueError(f"unknown measurement {kind!r}; choose one of {MEASUREMENTS}")
    return MEASUREMENT_REGISTRY.entry(kind).factory(linear_matrix)


__all__ = [
    "EXTENT_MEASUREMENTS",
    "MEASUREMENTS",
    "MEASUREMENT_REGISTRY",
    "NONLINEAR_TRUTH",
    "PLANTS",
    "PLANT_PARAMS",
    "PLANT_REGISTRY",
    "make_measurement",
    "make_plant",
    "plant_over",
    "INTERVAL_PLANTS",
]
