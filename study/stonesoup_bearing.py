"""Stone Soup's side of the comparator on bearing-only and mixed (camera + radar) networks: the angle-only
measurement model, one hypothesiser per sensor kind, and an initiator whose held tracks start from triangulated
points.

What Stone Soup gets, for :func:`~zentrack.study.stonesoup_multitarget.run_stonesoup`:

- **bearing measurement**: Stone Soup's own :class:`CartesianToElevationBearing` (``[elevation, bearing]`` of the
  position ``mapping=(0, 1, 2)`` seen from ``translation_offset`` = the sensor's position, no rotation:
  ``asin(dz / r)``, ``atan2(dy, dx)``), which is zentrack's azimuth/elevation model
  (:func:`~zentrack.fusion.measurement.bearing`: ``atan2(dy, dx)``, ``atan2(dz, hypot(dx, dy))``, the same
  angles) with the two components swapped: each return ``(az, el)`` becomes a detection ``[Elevation(el),
  Bearing(az)]`` and the sensor's noise covariance is permuted to match. Stone Soup's angle types wrap the
  innovations;
- **update**: :class:`ExtendedKalmanUpdater` (zentrack's per-track filter on these scenarios is its EKF), each
  detection with its own sensor's model (a radar's ``LinearGaussian``, a camera's angles);
- **association**: ``GNNWith2DAssignment`` on ``PDAHypothesiser`` hypotheses, one hypothesiser per sensor kind
  (:func:`kind_hypothesiser`): a camera's clutter density is per rad², a radar's per m³, as zentrack's
  :class:`~zentrack.fusion.multitarget.tracker.SensorModel` per sensor;
- **initiation**: Stone Soup's ``MultiMeasurementInitiator`` holds tentative tracks and updates them with the
  returns no track took (bearings too, by the EKF). What it cannot do is start a track from one bearing (its
  ``SimpleMeasurementInitiator`` needs an invertible model: one ray has no range). So the held tracks' initiator is
  :func:`triangulating_initiator`: it hands every scan's **leftover bearings** (the returns neither a track nor a held
  track took) to **zentrack's triangulation** exactly as zentrack's centralized tracker does
  (:class:`~zentrack.fusion.multitarget.triangulation.TriangulationInitiator` with ``sensor=None``: each scan's
  leftover rays against those of the step's scans before it, the chi-square pair gate, a third ray to confirm,
  the maximum-likelihood fit of every ray kept and its inverse-Fisher covariance; each ray used once), and turns
  each triangulated point into a Stone Soup position **detection** (``LinearGaussian`` on the position with the
  fit's covariance) that Stone Soup's ``SimpleMeasurementInitiator`` starts a held track from (the position and
  its covariance, the velocity from the new-track covariance, mean 0: what zentrack's birth is). A radar's
  leftover returns start held tracks themselves, as in the point comparator.

So from zentrack Stone Soup gets the triangulated points (position and covariance) of the leftover bearings, and
nothing else: which returns are leftovers, the held tracks, their confirmation, the association and the updates
are its own.
"""
from __future__ import annotations

import datetime
from collections.abc import Sequence
from typing import Any

import numpy as np

from zentrack.fusion.multitarget.network import TrackerSettings
from zentrack.fusion.multitarget.triangulation import TriangulationInitiator
from zentrack.fusion.scan import Scan
from zentrack.truth.simulation.multitarget import MultiTargetData

Array = np.ndarray
#: a detection's ``metadata`` keys: the sensor's index and kind
SENSOR, KIND = "sensor", "kind"


def angle_model(position: Array, noise_cov: Array) -> Any:
    """Stone Soup's ``CartesianToElevationBearing`` of a bearing sensor at ``position`` whose zentrack noise covariance
    (of ``(az, el)``) is ``noise_cov``, permuted to Stone Soup's ``(el, az)`` (module docstring)."""
    from stonesoup.models.measurement.nonlinear import CartesianToElevationBearing
    from stonesoup.types.array import StateVector

    noise = np.asarray(noise_cov, dtype=float)
    return CartesianToElevationBearing(ndim_state=6, mapping=(0, 1, 2), noise_covar=noise[::-1, ::-1].copy(),
                                       translation_offset=StateVector(np.asarray(position, dtype=float)))


def angle_detection(z: Array, when: datetime.datetime, model: Any, meta: dict | None = None) -> Any:
    """A zentrack bearing return ``(az, el)`` as the Stone Soup detection ``[Elevation(el), Bearing(az)]``."""
    from stonesoup.types.angle import Bearing, Elevation
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection

    return Detection(StateVector([Elevation(z[1]), Bearing(z[0])]), timestamp=when, measurement_model=model,
                     metadata=meta or {})


def measurement_model(data: MultiTargetData, sensor: int) -> Any:
    """Stone Soup's measurement model of sensor ``sensor`` (module docstring)."""
    from stonesoup.models.measurement.linear import LinearGaussian

    noise = data.scan(0, sensor).noise_cov
    if data.kind(sensor) == "bearing":
        return angle_model(data.sensors[sensor], noise)
    return LinearGaussian(ndim_state=6, mapping=(0, 1, 2), noise_covar=noise)


def detections_of(data: MultiTargetData, step: int, sensor: int, model: Any, when: datetime.datetime) -> set:
    """Sensor ``sensor``'s returns of ``step`` as Stone Soup detections (a bearing ``(az, el)`` as
    ``[Elevation(el), Bearing(az)]``), tagged with the sensor and its kind."""
    from stonesoup.types.detection import Detection

    kind, meta = data.kind(sensor), {SENSOR: sensor, KIND: data.kind(sensor)}
    returns = data.scan(step, sensor).returns
    if kind == "bearing":
        return {angle_detection(z, when, model, meta) for z in returns}
    return {Detection(z[:, None], timestamp=when, measurement_model=model, metadata=meta) for z in returns}


def kind_hypothesiser(by_kind: dict[str, Any]) -> Any:
    """A Stone Soup hypothesiser that hands a scan's detections to its sensor kind's (``by_kind``: kind ->
    ``PDAHypothesiser`` with that kind's P_D and clutter density). A scan is one sensor's: one kind."""
    from stonesoup.base import Property
    from stonesoup.hypothesiser.base import Hypothesiser

    class KindHypothesiser(Hypothesiser):
        """The hypotheses of the detections' sensor kind's hypothesiser."""

        hypothesisers: dict = Property(doc="sensor kind -> hypothesiser")

        def hypothesise(self, track, detections, timestamp, **kwargs):
            kinds = {d.metadata[KIND] for d in detections}
            if len(kinds) > 1:
                raise ValueError(f"one scan's detections are of one sensor kind, got {sorted(kinds)}")
            kind = kinds.pop() if kinds else next(iter(self.hypothesisers))  # none: only the miss
            return self.hypothesisers[kind].hypothesise(track, detections, timestamp, **kwargs)

    return KindHypothesiser(hypothesisers=by_kind)


def triangulating_initiator(data: MultiTargetData, settings: Sequence[TrackerSettings], prior: Any,
                            start: datetime.datetime) -> Any:
    """The held tracks' initiator (module docstring): leftover bearings triangulated by zentrack's
    ``TriangulationInitiator(None, ...)`` into position detections, those and a radar's leftover returns started
    by Stone Soup's ``SimpleMeasurementInitiator``."""
    from stonesoup.base import Property
    from stonesoup.initiator.base import Initiator
    from stonesoup.initiator.simple import SimpleMeasurementInitiator
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.detection import Detection

    bearing = next(s for s in settings if s.measurement == "bearing")
    ts = bearing.ts

    class TriangulatingInitiator(Initiator):
        """Held tracks from triangulated leftover bearings and from points (module docstring)."""

        starter: Initiator = Property(doc="Stone Soup's initiator of a point")
        triangulation: Any = Property(doc="zentrack's TriangulationInitiator of every sensor's scans")

        def initiate(self, detections, timestamp, **kwargs):
            step = int(round((timestamp - start).total_seconds() / ts))
            points = {d for d in detections if d.metadata[KIND] != "bearing"}
            rays = [d for d in detections if d.metadata[KIND] == "bearing"]
            for sensor in sorted({d.metadata[SENSOR] for d in rays}):
                mine = [d for d in rays if d.metadata[SENSOR] == sensor]
                returns = np.array([[float(d.state_vector[1]), float(d.state_vector[0])] for d in mine])
                scan = Scan(step, sensor, returns, data.sensors[sensor], data.scan(0, sensor).noise_cov)
                for birth in self.triangulation.births_from_returns(returns, scan, step):
                    model = LinearGaussian(ndim_state=6, mapping=(0, 1, 2), noise_covar=birth.cov[:3, :3])
                    points.add(Detection(birth.mean[:3, None], timestamp=timestamp, measurement_model=model,
                                         metadata={SENSOR: sensor, KIND: "triangulated"}))
            return self.starter.initiate(points, timestamp)

    triangulation = TriangulationInitiator(None, bearing.p0, bearing.max_range, bearing.gate_prob,
                                           require_confirmation=True)
    return TriangulatingInitiator(starter=SimpleMeasurementInitiator(prior), triangulation=triangulation)
