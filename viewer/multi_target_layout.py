"""What a many-target run's screen shows: the scene from above framed on the targets' region, GOSPA and the
confirmed tracks per node, a map beside the scene for a recorded truth (:mod:`zentrack.viewer.map_view`), and the
key (the parts every screen shares: :mod:`zentrack.viewer.layout`).
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zentrack.viewer.layout import BACKGROUND_RGB, events_view, history, key_view, screen, series
from zentrack.viewer.map_view import MAP_KEY, map_view
from zentrack.viewer.single_target_layout import SENSOR_LATENCY_TITLE

#: steps of trail behind each track (the truth keeps its whole path)
TRACK_TRAIL_STEPS = 15
MULTITARGET_TITLE = "targets: truth (white, thin paths) · tracks per node (big, labelled: confirmed; small: tentative) · trails"
MULTITARGET_KEY = (
    "**Many targets**: the white lines are the targets' true paths, the white points where they are now "
    "({names}); the sensors (``s<i>``) are in their "
    "node's colour. Each node's tracks are drawn in the node's colour under ``world/nodes/<i>`` (hide a node "
    "in the blueprint tree): **confirmed** tracks big and labelled with their network identity "
    "``born/node/serial`` (nodes that fused a track share its identity), **tentative** ones small and dim "
    "(labels hidden), each with its trail of the last {trail} steps.\n\nPlots: GOSPA of each node's confirmed "
    "tracks against the targets present (cut-off {cutoff:.0f} m: one missed target or one false track costs "
    "c²/2) and its parts (m²); the number of confirmed tracks per node, grey: the targets present.")
#: how the key names the truth's targets: simulated (``t<id>``, labels hidden) or recorded (their names, shown)
TARGET_NAMES = {False: "labelled ``t<id>``, hidden: turn them on in the entity's visualizer",
                True: "real vessels or aircraft, labelled with their names or call signs; the tracks' labels are "
                      "hidden to leave them room: turn them on in the entity's visualizer"}


#: what the key adds for sensors of their own
OWN_SENSORS_SCANS_KEY = (
    "\n\n**Sensors of their own**: each sensor's scans, every return (targets' and clutter) as small points in "
    "its tracker's colour under ``world/sensors/<s>/returns``, each scan at its own measurement time on the run's "
    "clock; the tab *sensor latency* has each sensor's arrival at the viewer less its measurement time, *out of "
    "order* the share of its scans that came after one it measured later.")


def multitarget_key(recorded: bool, cutoff: float, own_sensors: bool = False) -> str:
    """The key of a many-target run (markdown): a recorded truth has named targets and a map; sensors of their
    own, their scans."""
    text = MULTITARGET_KEY.format(names=TARGET_NAMES[recorded], trail=TRACK_TRAIL_STEPS, cutoff=cutoff)
    return text + (MAP_KEY if recorded else "") + (OWN_SENSORS_SCANS_KEY if own_sensors else "")


def targets_region(truth: np.ndarray) -> tuple[tuple[float, float, float], float]:
    """The centre and half-width (m) of the box the targets' positions ``(K, T, 3+)`` (NaN: absent) span."""
    pos = truth[..., :3].reshape(-1, 3)
    pos = pos[np.all(np.isfinite(pos), axis=1)]
    if not len(pos):
        return (0.0, 0.0, 0.0), 100.0
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    cx, cy, cz = (float(c) for c in (lo + hi) / 2)
    return (cx, cy, cz), max(float(np.max(hi[:2] - lo[:2])) / 2, 50.0)


def multitarget_blueprint(nodes: int, region: tuple[tuple[float, float, float], float],
                          most_targets: int, zoom: float | None = None, own_sensors: bool = False) -> rrb.Blueprint:
    """The many-target layout: the scene seen from above (framed on the targets' ``region``), the GOSPA and
    confirmed-count plots (the latter up to the most targets present at once, plus one), and a tab of GOSPA's
    parts, the events and the key. It opens on the latest step. ``zoom`` (a recorded truth): a map view at
    that zoom (:func:`~zentrack.viewer.map_view.map_zoom`) beside the scene, which then shows the targets' names
    instead of the tracks' identities (and leaves ``map/`` to the map). ``own_sensors``: tabs of each sensor's
    latency and share out of order."""
    (cx, cy, cz), half = region
    eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=(cx, cy - 0.7 * half, cz + 2.0 * half),
                            look_target=(cx, cy, cz), eye_up=(0.0, 0.0, 1.0))
    trail = [history(TRACK_TRAIL_STEPS)]
    overrides: dict = {"world/truth/paths": [history(None)],
                       "world/truth/targets": rr.Points3D.from_fields(show_labels=zoom is not None)}
    for i in range(nodes):
        overrides[f"world/nodes/{i}/trails"] = trail
        overrides[f"world/nodes/{i}/tentative"] = rr.Points3D.from_fields(show_labels=False)
        overrides[f"world/nodes/{i}/confirmed"] = rr.Points3D.from_fields(show_labels=zoom is None)
    contents = "$origin/**" if zoom is None else ["+ world/**", "- map/**"]
    scene = rrb.Spatial3DView(origin="world", contents=contents, name=MULTITARGET_TITLE, overrides=overrides,
                              background=BACKGROUND_RGB, eye_controls=eye, line_grid=rrb.LineGrid3D(visible=False))
    views = [scene] if zoom is None else [scene, map_view(zoom, history(None))]
    own = [series("metrics/sensor_latency_ms", SENSOR_LATENCY_TITLE),
           series("metrics/out_of_order", "out of order: share of each sensor's scans", 1.0)] if own_sensors else []
    parts = rrb.Tabs(series("metrics/gospa_localisation", "GOSPA localisation part (m²)"),
                     series("metrics/gospa_missed", "GOSPA missed part (m²)"),
                     series("metrics/gospa_false", "GOSPA false part (m²)"), *own, key_view(), events_view())
    plots = rrb.Vertical(series("metrics/gospa", "GOSPA per node (m)"),
                         series("metrics/confirmed", "confirmed tracks per node · grey: targets present",
                                most_targets + 1.0),
                         parts, row_shares=[3, 2, 3])
    return screen(*views, plots, shares=[3, 2] if zoom is None else [5, 5, 4],
                  time_panel=rrb.TimePanel(state="collapsed", timeline="step", play_state="following"))
