"""What the viewer draws for an extended object (paper 4), on the sea surface (z = 0).

- ``world/truth/shape``: the true outline (ellipse or rectangle at the true orientation and semi-axes);
- ``world/nodes/<i>/shape``: node i's estimated outline, from the extent ``[alpha, l1, l2]`` of its estimate;
- ``world/nodes/<i>/points``: the points of node i's scan;
- ``world/sensors`` and ``world/relays`` (static): measuring nodes as large coloured points, relays as small
  grey ones; ``world/graph`` (static): the communication links;
- ``metrics/gw/<i>``: the Gaussian Wasserstein distance between node i's estimate and the truth (an ellipse's
  metric; for a rectangle, of the ellipses with the same semi-axes).
"""
from __future__ import annotations

import numpy as np
import rerun as rr

from zentrack.fusion.extent import ellipse_outline, gaussian_wasserstein, rectangle_outline
from zentrack.viewer.layout import TRUTH_RGB, log_node_series

RELAY_RGB = [150, 150, 150]


class ExtentView:
    """Rows for the viewer's column buffer (``buf.add(entity, kind, step, ...)``) from 7-states
    ``[m1, m2, v1, v2, alpha, l1, l2]``."""

    def __init__(self, scn, buf, colors: list[list[int]]) -> None:
        self.buf, self.colors = buf, colors
        self.rectangle = scn.measurement == "extent-rectangle"
        self.roles = np.asarray(scn.roles)
        self.nodes = np.asarray(scn.sensors, dtype=float)
        self.edges = [(i, int(j)) for i in range(len(self.roles)) for j in np.flatnonzero(scn.adjacency[i]) if j > i]

    def log_static(self, rec: rr.RecordingStream) -> None:
        sensing = np.flatnonzero(self.roles == "sensor")
        relays = np.flatnonzero(self.roles != "sensor")
        rec.log("world/sensors", rr.Points3D(self.nodes[sensing], colors=[self.colors[i] for i in sensing], radii=-6.0,
                                             labels=[f"s{i}" for i in sensing]), static=True)
        if relays.size:  # no labels: a dozen of them overprint each other
            rec.log("world/relays", rr.Points3D(self.nodes[relays], colors=RELAY_RGB, radii=-3.5), static=True)
        if self.edges:
            rec.log("world/graph", rr.LineStrips3D([[self.nodes[i], self.nodes[j]] for i, j in self.edges],
                                                   colors=[70, 70, 110], radii=-0.75), static=True)
        log_node_series(rec, self.colors, ["gw"])

    def outline(self, x: np.ndarray) -> np.ndarray:
        """The closed outline ``(N, 3)`` of the shape of state ``x`` at z = 0."""
        m, p = x[:2], x[4:7]
        flat = rectangle_outline(m, p) if self.rectangle else ellipse_outline(m, p, 64)
        return np.concatenate([flat, np.zeros((flat.shape[0], 1))], axis=1)

    def truth(self, k: int, x: np.ndarray) -> None:
        self.buf.add("world/truth/shape", "segment", k, self.outline(x), TRUTH_RGB, -2.5)

    def estimate(self, i: int, k: int, x: np.ndarray) -> None:
        self.buf.add(f"world/nodes/{i}/shape", "segment", k, self.outline(x), self.colors[i], -1.25)

    def score(self, i: int, k: int, x: np.ndarray, truth: np.ndarray) -> None:
        gw = float(gaussian_wasserstein(x[:2], x[4:7], truth[:2], truth[4:7]))
        self.buf.add(f"metrics/gw/{i}", "scalar", k, gw)

    def scan(self, i: int, k: int, returns: np.ndarray) -> None:
        pts = np.concatenate([returns[:, :2], np.zeros((returns.shape[0], 1))], axis=1)
        self.buf.add(f"world/nodes/{i}/points", "cloud", k, pts, np.tile(self.colors[i], (len(pts), 1)),
                     np.full(len(pts), -2.0))
