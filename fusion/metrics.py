"""Accuracy and consistency metrics over stacks of estimates.

Errors are ``(R, K, M, n)`` (runs, steps, nodes, state) and covariances ``(R, K, M, n, n)``.
"""
from __future__ import annotations

import numpy as np

Array = np.ndarray


def running_rmse(err: Array) -> Array:
    """Node-averaged running RMSE (seed 000 eq. 64 / 68): sqrt( 1/(M k) sum_i sum_{j<=k} ||e_ij||^2 ), ``(R, K)``."""
    sq = np.sum(err**2, axis=-1).mean(axis=2)  # (R, K)
    return np.sqrt(np.cumsum(sq, axis=1) / np.arange(1, sq.shape[1] + 1))


def nees(err: Array, cov: Array) -> Array:
    """Normalised estimation error squared e^T P^-1 e, ``(R, K, M)``."""
    sol = np.linalg.solve(cov, err[..., None])[..., 0]
    return np.sum(err * sol, axis=-1)


def anees_band(dof: int, samples: int, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` band of the average of ``samples`` independent chi-square(``dof``) NEES values."""
    from scipy.stats import chi2  # imported here: tracker processes never need scipy.stats

    lo, hi = chi2.ppf([(1 - prob) / 2, (1 + prob) / 2], dof * samples) / samples
    return float(lo), float(hi)


def consistency_ratio(err: Array, cov: Array) -> float:
    """eta = (1/T) sum_k tr(Sigma_hat_k) / tr(P_k) (seed 000 eq. 65), averaged over nodes.

    Sigma_hat_k is the Monte Carlo error covariance over runs; P_k the runs' mean reported covariance.
    eta > 1: the filter is optimistic.
    """
    emp = np.mean(np.sum(err**2, axis=-1), axis=0)  # (K, M): tr of the empirical covariance
    rep = np.mean(np.trace(cov, axis1=-2, axis2=-1), axis=0)  # (K, M)
    return float(np.mean(emp / rep))


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
