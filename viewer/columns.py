"""Rows per entity, sent to Rerun as columns (one ``send_columns`` call per entity and flush)."""
from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import rerun as rr


def point_sets(rows: list) -> Any:
    """Rows of (positions (n, 3), colours (n, 3), radii (n,), labels (n,)), any n per row (0 included)."""
    return rr.Points3D.columns(
        positions=np.concatenate([np.reshape(r[0], (-1, 3)) for r in rows]),
        colors=np.concatenate([np.reshape(r[1], (-1, 3)) for r in rows]).astype(np.uint8),
        radii=np.concatenate([np.reshape(r[2], -1) for r in rows]),
        labels=[label for r in rows for label in r[3]]).partition([len(r[0]) for r in rows])


def segment_sets(rows: list) -> Any:
    """Rows of (segments [[a, b], ...], colours (n, 3), radii (n,)), any n per row (0 included)."""
    return rr.LineStrips3D.columns(
        strips=[s for r in rows for s in r[0]],
        colors=np.concatenate([np.reshape(r[1], (-1, 3)) for r in rows]).astype(np.uint8),
        radii=np.concatenate([np.reshape(r[2], -1) for r in rows])).partition([len(r[0]) for r in rows])


class ColumnBuffer:
    """Rows per entity, sent with one ``send_columns`` call per entity every flush (far cheaper than one
    ``log`` call per row). A crash loses at most the rows since the last flush.

    Radii are Rerun's: positive in scene units, negative in UI points (a fixed size on screen). A row's kind
    (:data:`KINDS`, and the ``kinds`` a payload adds) says how its rows become columns; ``set`` and ``segset`` take
    sets of any size per step, empty ones included (an empty row clears what the step before drew).

    A row is logged on the ``step`` timeline at its step and on ``time`` at the step's sample time (k·ts), or at
    its own time ``at`` (seconds after the run's start: a detection of a sensor of its own, measured between
    samples)."""

    KINDS: Mapping[str, Callable[[list], Any]] = {
        "scalar": lambda rows: rr.Scalars.columns(scalars=[r[0] for r in rows]),
        "point": lambda rows: rr.Points3D.columns(positions=[r[0] for r in rows], colors=[r[1] for r in rows],
                                                  radii=[r[2] for r in rows]),
        "labelled": lambda rows: rr.Points3D.columns(positions=[r[0] for r in rows], colors=[r[1] for r in rows],
                                                     radii=[r[2] for r in rows], labels=[r[3] for r in rows]),
        "segment": lambda rows: rr.LineStrips3D.columns(strips=[r[0] for r in rows], colors=[r[1] for r in rows],
                                                        radii=[r[2] for r in rows]),
        "cloud": lambda rows: rr.Points3D.columns(
            positions=np.concatenate([r[0] for r in rows]), colors=np.concatenate([r[1] for r in rows]),
            radii=np.concatenate([r[2] for r in rows])).partition([len(r[0]) for r in rows]),
        "segments": lambda rows: rr.LineStrips3D.columns(
            strips=[s for r in rows for s in r[0]], colors=np.concatenate([r[1] for r in rows]),
            radii=np.concatenate([r[2] for r in rows])).partition([len(r[0]) for r in rows]),
        "ellipsoid": lambda rows: rr.Ellipsoids3D.columns(
            centers=[r[0] for r in rows], half_sizes=[r[1] for r in rows], quaternions=[r[2] for r in rows],
            colors=[r[3] for r in rows], line_radii=[r[4] for r in rows],
            fill_mode=[rr.components.FillMode.MajorWireframe] * len(rows)),
        "translation": lambda rows: rr.Transform3D.columns(translation=[r[0] for r in rows]),
        "set": point_sets,
        "segset": segment_sets,
    }

    def __init__(self, rec: rr.RecordingStream, ts: float, kinds: Mapping[str, Callable[[list], Any]] | None = None
                 ) -> None:
        self.rec, self.ts = rec, ts
        self.kinds = {**self.KINDS, **(kinds or {})}
        self.rows: dict[tuple[str, str], list] = {}

    def add(self, entity: str, kind: str, step: int, *values, at: float | None = None) -> None:
        self.rows.setdefault((entity, kind), []).append((step, values, step * self.ts if at is None else at))

    def flush(self) -> None:
        for (entity, kind), rows in self.rows.items():
            steps, times = np.array([r[0] for r in rows]), np.array([r[2] for r in rows], dtype=float)
            self.rec.send_columns(
                entity,
                indexes=[rr.TimeColumn("step", sequence=steps), rr.TimeColumn("time", duration=times)],
                columns=self.kinds[kind]([r[1] for r in rows]),
            )
        self.rows.clear()
