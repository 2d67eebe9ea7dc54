"""Rows per entity, sent to Rerun as columns (one ``send_columns`` call per entity and flush)."""
from __future__ import annotations

import numpy as np
import rerun as rr


class ColumnBuffer:
    """Rows per entity, sent with one ``send_columns`` call per entity every flush (far cheaper than one
    ``log`` call per row). A crash loses at most the rows since the last flush.

    Radii are Rerun's: positive in scene units, negative in UI points (a fixed size on screen)."""

    KINDS = {
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
    }

    def __init__(self, rec: rr.RecordingStream, ts: float) -> None:
        self.rec, self.ts = rec, ts
        self.rows: dict[tuple[str, str], list] = {}

    def add(self, entity: str, kind: str, step: int, *values) -> None:
        self.rows.setdefault((entity, kind), []).append((step, values))

    def flush(self) -> None:
        for (entity, kind), rows in self.rows.items():
            steps = np.array([r[0] for r in rows])
            self.rec.send_columns(
                entity,
                indexes=[rr.TimeColumn("step", sequence=steps), rr.TimeColumn("time", duration=steps * self.ts)],
                columns=self.KINDS[kind]([r[1] for r in rows]),
            )
        self.rows.clear()
