"""Names on Rerun's map view, drawn as vector text: each named target's vessel name or call sign as the outlines
of its glyphs, geographic line strings beside the target.

Rerun 0.41's map view draws no text (its only visualizers are ``GeoPoints`` and ``GeoLineStrings``, and neither
takes labels: rerun-io/rerun#9452), so the text is geometry. Matplotlib's :class:`~matplotlib.textpath.TextPath`
gives a string's glyph outlines (DejaVu Sans, the font matplotlib ships; curves flattened to polylines); they are
scaled so that a capital letter is ``height`` metres tall, placed with their baseline half a capital below the
target and their start :data:`NAME_GAP` capitals east of it, in the run's east-north-up frame, and converted to
latitude and longitude with the map's other rows (Web Mercator is conformal: the text stays upright and
undistorted). ``height`` comes from the region's zoom (:func:`name_height`): :data:`NAME_POINTS` UI points tall when
the map view opens, growing and shrinking with the map as one zooms.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

#: a capital letter's height on the map at the region's zoom, in UI points
NAME_POINTS = 12.0
#: the gap between a target and the start of its name, in capital heights
NAME_GAP = 0.7
#: the font: matplotlib's own, present wherever matplotlib is
FONT = "DejaVu Sans"


@lru_cache(maxsize=1)
def _cap_height() -> float:
    """The height of a capital of :data:`FONT` at size 1."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath

    return float(TextPath((0, 0), "H", size=1.0, prop=FontProperties(family=FONT)).get_extents().y1)


@lru_cache(maxsize=4096)
def glyph_outlines(text: str) -> tuple[np.ndarray, ...]:
    """The closed outlines of ``text``'s glyphs, each ``(m, 2)``, in capital heights: the baseline at y = 0, the
    text starting at x = 0 (cached per string: a name is drawn at every step)."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath

    path = TextPath((0, 0), text, size=1.0, prop=FontProperties(family=FONT))
    outlines = [np.asarray(p, dtype=float) / _cap_height() for p in path.to_polygons(closed_only=True)]
    return tuple(o for o in outlines if len(o) >= 2)


def name_strokes(positions: np.ndarray, names: list[str], height: float) -> list[np.ndarray]:
    """The outlines of each name beside its target (module docstring): east-north-up polylines ``(m, 3)`` (m) at
    the targets' heights, every outline of the first name, then of the second, ..."""
    strokes = []
    for p, name in zip(np.reshape(positions, (-1, 3)), names):
        start = np.array([p[0] + NAME_GAP * height, p[1] - 0.5 * height])
        for outline in glyph_outlines(name):
            xy = start + height * outline
            strokes.append(np.column_stack([xy, np.full(len(xy), p[2])]))
    return strokes


def name_height(metres_per_point: float) -> float:
    """A name's capital height (m) on a map showing ``metres_per_point`` metres per UI point."""
    return NAME_POINTS * metres_per_point
