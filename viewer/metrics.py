"""The viewer's time series and fusion centre: errors and NEES against the truth, covariance, latency,
association probabilities, the disagreement per consensus round, and ``world/fused``.

- ``metrics/<name>/<i>`` per node (series named ``node <i>`` in its colour): position error, NEES (with its 95 %
  χ² band), trace of the position covariance, step latency, pairs fused; ``metrics/beta_target/<i>`` with clutter;
- ``metrics/disagreement/<l>``: the spread of the nodes' position estimates after round l of each step (RMS
  distance to their mean, from the round messages ``prior/<i>``), which shrinks round after round;
- ``world/fused/{estimate,ellipsoid}``: a fusion centre, once every node's estimate of a step is in: the paper's
  covariance-weighted combination (paper 1), or CI with uniform weights (satellites: their estimates are
  correlated through the diffusion, so only CI is consistent).
"""
from __future__ import annotations

import numpy as np
import rerun as rr

from zentrack.fusion.consistency import anees_band
from zentrack.fusion.covariance_intersection import ci_combine
from zentrack.fusion.feedforward import covariance_weighted_fusion
from zentrack.fusion.filters import FilterContext, make_node_filter
from zentrack.fusion.rules import make_rule
from zentrack.transport.messages import EstimateMessage, RoundMessage
from zentrack.viewer.columns import ColumnBuffer
from zentrack.viewer.geometry import covariance_ellipsoid
from zentrack.viewer.layout import log_node_series
from zentrack.viewer.single_target_layout import FUSED_RGB

METRICS = ("position_error", "nees", "trace_p", "latency_ms", "pairs_fused")


def round_message_dims(setup) -> tuple[dict[str, int], int] | None:
    """The blocks of the run's round messages (what ``prior/<i>`` carries) and the rounds per step, when the
    rule has more than one round; None otherwise."""
    params = setup.run_parameters()
    rule = make_rule(params.fusion, params.fusion_params)
    if rule.rounds(0) < 2:
        return None
    scn = setup.scenario
    node = make_node_filter(params.filter, FilterContext.from_scenario(scn, np.random.default_rng(0)), params.filter_params)
    probe = node.initial(scn.x0_estimate[0], np.random.default_rng(0))
    dims = rule.message_dims({name: int(p.vector.shape[-1]) for name, p in node.blocks(probe).items()})
    return dims, int(rule.rounds(0))


def ellipsoid_of(cov: np.ndarray, dims: int) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes and quaternion of the 3σ ellipsoid of the first ``dims`` (2 or 3) position components."""
    c3 = np.eye(3) * 1e-9
    c3[:dims, :dims] = cov[:dims, :dims]
    return covariance_ellipsoid(c3)


class Metrics:
    """Scores each estimate against the truth of its step (held back until that truth arrives)."""

    def __init__(self, scn, buf: ColumnBuffer, colors: list[list[int]], pos_dims: int, rounds: int | None,
                 extent=None) -> None:
        self.scn, self.buf, self.colors, self.pos_dims, self.rounds, self.extent = scn, buf, colors, pos_dims, rounds, extent
        self.m = scn.nodes
        self.band = anees_band(scn.truth.shape[-1], 1)
        self.truth: dict[int, np.ndarray] = {}
        self.pending: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        self.fusion_inputs: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        self.round_x: dict[tuple[int, int], dict[int, np.ndarray]] = {}

    def log_static(self, rec: rr.RecordingStream) -> None:
        """Each series' name and colour (node i: ``node i`` in its colour)."""
        names = list(METRICS) + (["beta_target"] if self.scn.has_scans and self.extent is None else [])
        log_node_series(rec, self.colors, names)
        for rnd in range(1, (self.rounds or 0) + 1):
            shade = int(60 + 180 * rnd / max(self.rounds or 1, 1))
            rec.log(f"metrics/disagreement/{rnd}", rr.SeriesLines(colors=[[shade, shade, 255]], names=[f"round {rnd}"]),
                    static=True)
        for side, name in (("lo", "95% band, low"), ("hi", "95% band, high")):
            rec.log(f"metrics/nees/band_{side}", rr.SeriesLines(colors=[[150, 150, 150]], names=[name], widths=[2.0]),
                    static=True)

    def pos(self, x: np.ndarray) -> np.ndarray:
        return x[:3] if self.pos_dims == 3 else np.array([x[0], x[1], 0.0])

    def on_truth(self, k: int, x: np.ndarray) -> None:
        self.truth[k] = x
        self.truth.pop(k - 50, None)
        for i, (xe, ce) in self.pending.pop(k, {}).items():
            self._errors(i, k, xe, ce, x)
        for old in [j for j in self.pending if j < k - 50]:
            del self.pending[old]
        self.buf.add("metrics/nees/band_lo", "scalar", k, self.band[0])
        self.buf.add("metrics/nees/band_hi", "scalar", k, self.band[1])

    def on_estimate(self, i: int, e: EstimateMessage) -> None:
        k, x, cov = e.k, e.x, e.P
        truth = self.truth.get(k)
        if truth is not None:
            self._errors(i, k, x, cov, truth)
        else:  # the estimate overtook the truth message: score it when the truth arrives
            self.pending.setdefault(k, {})[i] = (x, cov)
        d = self.pos_dims
        self.buf.add(f"metrics/trace_p/{i}", "scalar", k, float(np.trace(cov[:d, :d])))
        if e.t_meas_pub is not None:
            self.buf.add(f"metrics/latency_ms/{i}", "scalar", k, (e.t_pub - e.t_meas_pub) * 1e3)
        self.buf.add(f"metrics/pairs_fused/{i}", "scalar", k, float(e.fused))

    def _errors(self, i: int, k: int, x: np.ndarray, cov: np.ndarray, truth: np.ndarray) -> None:
        err = x - truth
        self.buf.add(f"metrics/position_error/{i}", "scalar", k, float(np.linalg.norm(err[:self.pos_dims])))
        self.buf.add(f"metrics/nees/{i}", "scalar", k, float(err @ np.linalg.solve(cov, err)))
        if self.extent is not None:
            self.extent.score(i, k, x, truth)

    def beta(self, i: int, k: int, beta: np.ndarray | None, target: int | None) -> None:
        """The association probability node i gave the target's return of step k."""
        if beta is not None and target is not None:
            value = float(beta[target]) if 0 <= target < len(beta) else 0.0
            self.buf.add(f"metrics/beta_target/{i}", "scalar", k, value)

    def on_round(self, i: int, p: RoundMessage) -> None:
        """A node's round message: once every node's message of (step, round) is in, their disagreement."""
        if p.warm:
            return
        block = p.blocks.get("state", p.blocks.get("prior"))  # consensus on measurements: the prior
        if block is None:
            return
        y_mat, y_vec = block
        key = (p.k, p.round)
        got = self.round_x.setdefault(key, {})
        got[i] = self.pos(np.linalg.solve(y_mat, y_vec))
        for old in [kr for kr in self.round_x if kr[0] < p.k - 10]:
            del self.round_x[old]
        if len(got) == self.m:
            pts = np.stack(list(got.values()))
            spread = float(np.sqrt(np.mean(np.sum((pts - pts.mean(axis=0)) ** 2, axis=-1))))
            self.buf.add(f"metrics/disagreement/{p.round}", "scalar", p.k, spread)
            del self.round_x[key]

    def fuse_centre(self, k: int, i: int, x: np.ndarray, cov: np.ndarray) -> None:
        """``world/fused`` once every node's estimate of step k is in (the module docstring says which rule)."""
        got = self.fusion_inputs.setdefault(k, {})
        got[i] = (x, cov)
        for old in [j for j in self.fusion_inputs if j < k - 20]:
            del self.fusion_inputs[old]
        if len(got) < self.m:
            return
        del self.fusion_inputs[k]
        order = sorted(got)
        means, covs = np.stack([got[j][0] for j in order]), np.stack([got[j][1] for j in order])
        if self.scn.has_scans:
            fused = covariance_weighted_fusion(means, covs)
        else:
            infos = np.linalg.inv(covs)
            fused = ci_combine(infos, np.einsum("mij,mj->mi", infos, means), np.full(len(order), 1.0 / len(order)))
        p = self.pos(fused.mean)
        half, quat = ellipsoid_of(fused.cov, min(3, fused.mean.shape[0]))
        self.buf.add("world/fused/estimate", "point", k, p, FUSED_RGB, -6.0)
        self.buf.add("world/fused/ellipsoid", "ellipsoid", k, p, half, quat, FUSED_RGB, -1.5)
