"""Accuracy metrics of Monte Carlo studies over stacks of estimates: running RMSE, lost runs and the summary of
a run set (consistency figures from :mod:`zentrack.fusion.consistency`).

Errors are ``(R, K, M, n)`` (runs, steps, nodes, state) and covariances ``(R, K, M, n, n)``.
"""
from __future__ import annotations

import numpy as np

from zentrack.fusion.consistency import anees_band, consistency_ratio, nees

Array = np.ndarray


def running_rmse(err: Array) -> Array:
    """Node-averaged running RMSE (paper 0 eq. 64 / 68): sqrt( 1/(M k) sum_i sum_{j<=k} ||e_ij||^2 ), ``(R, K)``."""
    sq = np.sum(err**2, axis=-1).mean(axis=2)  # (R, K)
    return np.sqrt(np.cumsum(sq, axis=1) / np.arange(1, sq.shape[1] + 1))


#: consecutive steps the error must stay beyond the scene for the run to count as lost (a spike is not)
LOST_STEPS = 10


def divergence_steps(err: Array, extent: Array, position: list[int], steps: int = LOST_STEPS) -> Array:
    """Per run, the first step of the first stretch of ``steps`` consecutive steps (all of them in a shorter
    run) in which the node-averaged position error exceeds the scene's ``extent`` (per run: a filter
    that far off for that long has lost the target, whatever the units and scale of the scenario); -1 if
    never. Non-finite errors count as beyond it."""
    pos_err = np.sqrt(np.sum(err[..., position] ** 2, axis=-1)).mean(axis=2)  # (R, K)
    beyond = ~(pos_err <= np.asarray(extent, dtype=float)[:, None])
    r, k = beyond.shape
    need = min(steps, k)
    out = np.full(r, -1)
    for run in range(r):
        count = 0
        for step in range(k):
            count = count + 1 if beyond[run, step] else 0
            if count == need:
                out[run] = step - need + 1
                break
    return out


def summarize(err: Array, cov: Array, groups: dict[str, list[int]], diverged_at: Array | None = None,
              lost_at: Array | None = None) -> dict:
    """Per-run final running RMSE per component group and in total, ANEES with its band, and eta.

    ``groups`` names index sets of the state, e.g. ``{"p": [0, 1, 2], "v": [3, 4, 5]}``.
    The ANEES band treats each run-step as one sample (nodes are averaged first because their errors are
    correlated), so it has ``R*K`` samples of ``n`` degrees of freedom.
    A diverged run (``diverged_at[r] >= 0``: its numbers stopped being finite) scores RMSE = inf and is left
    out of ANEES and eta. A run that lost the target (``lost_at[r] >= 0``, :func:`divergence_steps`) counts as
    diverged too, from that step (``diverged_at`` in the output), but keeps its RMSE and consistency figures.
    """
    r, k, m, n = err.shape
    diverged = np.zeros(r, dtype=bool) if diverged_at is None or len(diverged_at) == 0 else diverged_at >= 0
    out: dict = {"rmse": {}}
    for key, idx in list(groups.items()) + [("tot", list(range(n)))]:
        final = running_rmse(err[..., idx])[:, -1]
        out["rmse"][key] = np.where(diverged, np.inf, final).tolist()
    ok = ~diverged
    first = np.where(diverged, np.asarray(diverged_at) if diverged.any() else -1, -1)
    if lost_at is not None and len(lost_at):
        lost = np.asarray(lost_at) >= 0
        first = np.where(lost & ((first < 0) | (np.asarray(lost_at) < first)), lost_at, first)
    out["diverged_runs"] = int(np.sum(first >= 0))
    out["diverged_at"] = [int(v) for v in first]
    if ok.any():
        ne = nees(err[ok], cov[ok])
        out["anees"] = float(ne.mean())
        out["anees_per_run"] = ne.mean(axis=(1, 2)).tolist()
        out["anees_band"] = list(anees_band(n, int(ok.sum()) * k))
        out["eta"] = consistency_ratio(err[ok], cov[ok])
    else:
        out["anees"], out["anees_per_run"], out["anees_band"], out["eta"] = float("nan"), [], [], float("nan")
    return out
