"""What a single-target run's screen shows: the scenario's family, its titles and key, and the Rerun blueprint
(the parts every screen shares: :mod:`zentrack.viewer.layout`).

The main view is framed on the target: its origin is ``world/target``, a frame that moves with the true
position (a ``Transform3D`` logged every step), so the truth stays in the middle, the camera follows it and
the estimates, their 3σ ellipsoids and the rays through the target fill the view at a scale set from the
scenario (:func:`target_scale`). The sensors' layout is a second, smaller view of the whole scene.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.viewer.layout import BACKGROUND_RGB, events_view, history, key_view, screen, series

#: the target frame: the views framed on the target take it as their origin
TARGET_FRAME = "world/target"
#: clutter rays (dimmed) and the fusion centre's estimate
CLUTTER_RGB = [120, 120, 120]
FUSED_RGB = [255, 215, 0]
#: sensors further than this from the scene's origin (m): satellites
FAR_SENSORS_M = 50_000.0
#: the plot of sensors of their own: what their latency measures
SENSOR_LATENCY_TITLE = "sensor latency (ms): arrival at the viewer less measurement time, one line per sensor"
#: steps of trail the target view keeps behind the target (the layout view keeps the whole run)
TARGET_TRAIL_STEPS = 100

TITLES = {
    "bearings": "target: truth (white) · estimates (node colours) with 3σ ellipsoids · bearing rays",
    "points": "target: truth (white) · estimates (node colours) with 3σ ellipsoids · position measurements",
    "clutter": "target: truth (white) · estimates, particles · fusion centre (gold) · rays: target (colour), clutter (grey)",
    "extended": "extended object: true outline (white) · each node's estimated outline · scan points",
    "satellites": "ship: truth (white) · each satellite's estimate with 3σ ellipsoid · CI of all (gold)",
    "uav": "target: truth (white) · each UAV's estimate with 3σ ellipsoid · bearing rays",
    "linear": "target: truth (white) · estimates (node colours) with 3σ ellipses",
}
LAYOUT_TITLES = {
    "bearings": "sensor layout · bearing rays",
    "points": "sensor layout",
    "clutter": "sensor layout · rays (grey: clutter returns)",
    "extended": "sensor and relay nodes (grey), links",
    "satellites": "satellites, their tracks and the links",
    "uav": "UAVs, their tracks and links",
    "linear": "scene",
}
KEYS = {
    "bearings": "Bearings-only tracking: each sensor measures azimuth and elevation of the target; a node's "
                "ray is its current line of sight. No single ray fixes the target: the nodes exchange "
                "estimates and fuse them (covariance intersection).",
    "points": "Each sensor measures the target's position with noise (points in its colour).",
    "clutter": "Each scan holds the target's return (ray in the node's colour) and clutter: false returns, the "
               "**grey rays**. The particle filters weigh every return (β: the probability given to the "
               "target's). Gold: the fusion centre.",
    "extended": "An extended object: the nodes estimate its centre **and its outline** from many scan points "
                "per step. White: the true outline. Grey points: relay nodes (no sensor).",
    "satellites": "Video satellites hundreds of km up measure the ship's bearing; markers keep a fixed size on "
                  "screen. Gold: the CI of every satellite's estimate.",
    "uav": "Moving sensors (UAVs) measure bearings; the nodes run several consensus rounds per step "
           "(disagreement per round, lighter: later).",
    "linear": "Each node measures part of the state linearly.",
}

#: the key's paragraph for sensors of their own (:mod:`zentrack.viewer.detections`)
OWN_SENSORS_KEY = (
    "**Sensors of their own**: each sensor samples at its own rate and clock; a ray (or point) is one detection, "
    "drawn at its own measurement time (on `step`: the step whose window takes it), in the colour of the tracker "
    "that takes it. **Sensor latency** (ms, one line per sensor): arrival at the viewer less the measurement time, "
    "both on the run's clock (the sensor's simulated clock offset taken off): the sensor's delay **plus the network "
    "path to the viewer**, like the step latency. **Out of order**: the share of a sensor's detections that came "
    "after one it measured later.")


@dataclass(frozen=True)
class Scene:
    """The family of a scenario (what the titles say) and the half-width in metres of the target view."""

    family: str
    scale: float
    nodes: int
    rounds: bool = False
    #: the centre and half-width (m) of the fixed sensors' layout (None: moving sensors, Rerun frames them)
    layout: tuple[tuple[float, float, float], float] | None = None
    #: the upper end of the NEES band (the plot's initial range is a few times it)
    nees_hi: float = 10.0
    #: sensors of their own (``[sensor_timing]``; 0: the truth measures every step)
    sensors: int = 0

    @property
    def title(self) -> str:
        return TITLES[self.family]

    @property
    def key(self) -> str:
        colours = "White: the truth and its path. Each node's estimate, trail and 3σ ellipsoid are in its own colour " \
                  "(the colour of its label in the sensor layout and of its series in the plots: " \
                  "hover a line to see which node)."
        own = f"{OWN_SENSORS_KEY}\n\n" if self.sensors else ""  # (before the colours: what the run adds, first)
        return f"**{self.family}**: {KEYS[self.family]}\n\n{own}{colours}"


def scene_family(scn) -> str:
    """The scenario's family, from what it simulates: extended object, satellites, clutter, moving sensors,
    point or bearing measurements, or a linear measurement."""
    track = scn.sensor_track if scn.sensor_track is not None else scn.sensors[None]
    if scn.plant == "eot":
        return "extended"
    if float(np.max(np.linalg.norm(track, axis=-1))) > FAR_SENSORS_M:
        return "satellites"
    if scn.has_scans:
        return "clutter"
    if scn.sensor_track is not None:
        return "uav"
    if scn.measurement in ("bearing", "point"):
        return "bearings" if scn.measurement == "bearing" else "points"
    return "linear"


def target_scale(scn, family: str) -> float:
    """Half-width (m) of the target view: four times one scan's position error at the target's range
    (bearings: angle noise times range; about the size of the nodes' 3σ ellipsoids; satellites 1.5 times,
    clutter 2.5 times) or the distance the target covers in 3 steps, whichever is larger; for an extended
    object, 1.8 times its largest semi-axis."""
    truth = scn.truth[0]
    if family == "extended":
        return max(1.8 * float(np.max(truth[:, 5:7])), 1.0)  # [m1, m2, v1, v2, alpha, l1, l2]
    dims = min(3, truth.shape[-1])
    pos = truth[:, :dims]
    sensors = scn.sensor_track if scn.sensor_track is not None else np.broadcast_to(scn.sensors, (len(pos), *scn.sensors.shape))
    sigma = float(np.sqrt(np.max(np.diag(scn.noise_cov[0]))))
    if scn.measurement == "bearing":  # the range over the first 200 steps: what the user sees first
        sigma *= float(np.median(np.linalg.norm(sensors[:200, :, :dims] - pos[:200, None, :], axis=-1)))
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1)
    travel = 3.0 * float(np.median(step)) if len(step) else 0.0
    # satellites: hundreds of km of range make one scan's error large against the filtered one; clutter: the
    # particle filters' estimates are tighter than one return's error
    return max({"satellites": 1.5, "clutter": 2.5}.get(family, 4.0) * sigma, travel, 1.0)


def describe(scn, rounds: bool, sensors: int = 0) -> Scene:
    """The scene of a scenario (``rounds``: the rule runs several rounds per step; ``sensors``: sensors of their
    own)."""
    from zentrack.fusion.consistency import anees_band

    family = scene_family(scn)
    layout = None
    if scn.sensor_track is None and len(scn.sensors):
        lo, hi = scn.sensors.min(axis=0), scn.sensors.max(axis=0)
        cx, cy, cz = (float(c) for c in (lo + hi) / 2)
        layout = ((cx, cy, cz), max(float(np.max(hi - lo)) / 2, 1.0))
    return Scene(family, target_scale(scn, family), scn.nodes, rounds, layout,
                 float(anees_band(scn.truth.shape[-1], 1)[1]), sensors)


def target_eye(scene: Scene) -> rrb.EyeControls3D:
    """A camera in the target frame looking at the target from a fixed offset (it follows the target)."""
    d = 2.2 * scene.scale
    flat = scene.family in ("extended", "linear")
    position = (0.0, -0.6 * d, 1.6 * d) if flat else (-0.8 * d, -1.4 * d, 0.9 * d)
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position, look_target=(0.0, 0.0, 0.0),
                             eye_up=(0.0, 0.0, 1.0))


def _trails(nodes: int, steps: int | None) -> dict[rr.encodings.EntityPathLike, rrb.VisibleTimeRanges]:
    kept = history(steps)
    return {"world/truth/path": kept, **{f"world/nodes/{i}/trail": kept for i in range(nodes)},
            **{f"world/platforms/{i}/trail": kept for i in range(nodes)}}


def target_contents(family: str, nodes: int, sensors: int = 0) -> list[str]:
    """What the target view shows: the truth, the estimates and what is drawn through the target (rays,
    particles, outlines, scan points; ``sensors`` of their own: their detections), not the sensors. (An entity
    filter takes ``**`` only at its end.)"""
    parts = ["estimate", "trail", "particles", "measurement"]
    if family == "extended":  # the outline says what an ellipsoid of the centre would
        parts += ["shape", "points"]
    else:
        parts += ["ellipsoid"]
    if family in ("bearings", "clutter", "uav"):
        parts += ["ray"]
    if family == "satellites":  # a line from 800 km away drawn wide near the target: only its part near the target
        parts += ["ray_near"]
    if family == "clutter":
        parts += ["clutter"]
    detections = [f"+ world/sensors/{s}/{part}" for s in range(sensors) for part in ("ray", "measurement")]
    return ["+ world/truth/**", "+ world/fused/**", *(f"+ world/nodes/{i}/{part}" for i in range(nodes) for part in parts),
            *detections]


def layout_eye(scene: Scene) -> rrb.EyeControls3D | None:
    """Fixed sensors seen from above and a little to the south, so their labels do not overlap."""
    if scene.layout is None:
        return None
    (cx, cy, cz), half = scene.layout
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=(cx, cy - 1.2 * half, cz + 2.6 * half),
                             look_target=(cx, cy, cz), eye_up=(0.0, 0.0, 1.0))


def blueprint(scene: Scene) -> rrb.Blueprint:
    """The viewer's layout: the target view (left), the sensor layout and a key (top right), the plots."""
    target = rrb.Spatial3DView(origin=TARGET_FRAME, contents=target_contents(scene.family, scene.nodes, scene.sensors),
                               name=scene.title,
                               overrides=_trails(scene.nodes, TARGET_TRAIL_STEPS), background=BACKGROUND_RGB,
                               eye_controls=target_eye(scene), line_grid=rrb.LineGrid3D(visible=False))
    layout = rrb.Spatial3DView(origin="world", contents=["+ world/**", f"- {TARGET_FRAME}"],
                               name=LAYOUT_TITLES[scene.family], overrides=_trails(scene.nodes, None),
                               background=BACKGROUND_RGB, eye_controls=layout_eye(scene))
    family_metric: list[rrb.TimeSeriesView] = {
        "clutter": [series("metrics/beta_target", "β: probability of the target's return", 1.0)],
        "extended": [series("metrics/gw", "Gaussian Wasserstein distance to the truth (m)", scene.scale)]
    }.get(scene.family, [])
    rounds = [series("metrics/disagreement", "disagreement after each round (m); lighter: later round")]
    if scene.rounds and not family_metric:  # the family's plot, or the rounds' in its place (else in a tab)
        family_metric, rounds = rounds, []
    own = [series("metrics/out_of_order", "out of order: share of each sensor's detections", 1.0)] if scene.sensors else []
    if scene.sensors:  # (sensors of their own take neither clutter nor extended objects nor rounds)
        family_metric = [series("metrics/sensor_latency_ms", SENSOR_LATENCY_TITLE), *family_metric]
    plots = [series("metrics/position_error", "position error (m), one line per node", scene.scale),
             series("metrics/nees", "NEES per node; grey: 95% band of the mean", 4.0 * scene.nees_hi), *family_metric]
    more = rrb.Tabs(series("metrics/trace_p", "trace of position covariance (m²)"),
                    series("metrics/latency_ms", "step latency (ms)"), series("metrics/pairs_fused", "pairs fused"),
                    *(rounds if scene.rounds else []), *own, events_view())
    return screen(target,
                  rrb.Vertical(rrb.Horizontal(layout, key_view(), column_shares=[3, 2]),
                               *plots, more, row_shares=[4, *([2] * len(plots)), 3]),
                  shares=[3, 2])
