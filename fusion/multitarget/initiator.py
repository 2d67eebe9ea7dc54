"""Track initiation: two-point differencing for point sensors, priors only for bearing-only sensors.

:class:`TwoPointInitiator` (two-point differencing, Bar-Shalom, Li & Kirubarajan 2001 Sec. 5.5.3) is for
returns that measure position components of the state directly (a Cartesian point sensor: return component
``i`` is state component ``position_indices[i]``). A return no track gated becomes a candidate; a return of
the next scan within the velocity gate of a candidate starts a tentative track at

    p = z_2,   v = (z_2 - z_1) / T,   P_pp = R_2,   P_pv = R_2 / T,   P_vv = (R_1 + R_2) / T^2

(the errors ``w_1``, ``w_2`` of the two returns are independent), the other state components at mean 0 with
their ``prior_cov``. The velocity gate holds every pair of returns of a target no faster than ``max_speed``
with probability at least ``P_G``: ``|z_2 - z_1| <= max_speed T + sqrt(gamma lambda_max(R_1 + R_2))``,
``gamma = chi2_m(P_G)``. Pairs are chosen by 2-D assignment on the distance
(:func:`~zentrack.fusion.multitarget.gnn.best_assignment`); candidates not paired at the next scan are dropped.
Candidates are kept **per sensor** (``Scan.sensor``): a tracker that takes several sensors' scans each step (a
centralized one) pairs each sensor's leftovers with the same sensor's at the step before, never with another
sensor's of the same instant. A pair whose new point lies within the gate (``gamma``, on ``R + R'``) of a track
another sensor's pair already started at this step is the same target seen twice and starts nothing. With
sensors of their own (:meth:`TwoPointInitiator.births_at`) each scan has its time: a sensor's candidates pair with
its next scan whenever that comes, ``T`` the interval between them (the gate widens with it).

:class:`PriorInitiator` starts no track from returns (a bearing-only return does not locate a target): its
tracks come from :meth:`~zentrack.fusion.multitarget.base.Initiator.from_prior`, e.g. a neighbour's track.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..scan import Scan
from .base import Birth, Initiator, check_gaussian
from .gating import gate_gamma
from .gnn import best_assignment

Array = np.ndarray


def started_already(z: Array, cov: Array, started: Sequence[tuple[Array, Array]], gamma: float) -> bool:
    """Whether the point ``z`` (covariance ``cov``) lies within the gate ``gamma`` of a point ``(z0, cov0)`` of
    ``started`` (on ``cov + cov0``): the same target, started already."""
    for z0, cov0 in started:
        d = z - z0
        if float(d @ np.linalg.solve(cov + cov0, d)) <= gamma:
            return True
    return False


class TwoPointInitiator(Initiator):
    """Two-point differencing over consecutive scans (module docstring); ``prior_cov`` ``(k, k)`` is the
    kinematic prior covariance, used for the components the two returns do not give."""

    def __init__(self, ts: float, max_speed: float, prior_cov: Array, position_indices: Sequence[int] = (0, 1, 2),
                 velocity_indices: Sequence[int] = (3, 4, 5), gate_prob: float = 0.999) -> None:
        super().__init__()
        if not ts > 0 or not max_speed >= 0:
            raise ValueError(f"ts must be positive and max_speed non-negative, got {ts} and {max_speed}")
        k = np.shape(prior_cov)[0] if np.ndim(prior_cov) == 2 else 0
        _, self.prior_cov = check_gaussian(np.zeros(k), prior_cov, "prior_cov")
        self.pos = np.asarray(position_indices, dtype=int)
        self.vel = np.asarray(velocity_indices, dtype=int)
        if self.pos.size != self.vel.size or self.pos.size == 0:
            raise ValueError(f"position_indices and velocity_indices must be non-empty and as long, got "
                             f"{self.pos.tolist()} and {self.vel.tolist()}")
        if np.any(np.concatenate([self.pos, self.vel]) >= k) or np.intersect1d(self.pos, self.vel).size:
            raise ValueError(f"position and velocity indices must be distinct components of the {k}-state")
        self.ts, self.max_speed = float(ts), float(max_speed)
        self.gamma = gate_gamma(self.pos.size, gate_prob)
        #: per sensor: the returns of its last scan no track and no candidate took, their noise, step and time (s;
        #: None on the run's grid)
        self.candidates: dict[int, tuple[Array, Array, int, float | None]] = {}
        #: the step of the last births and their (position, noise) pairs, so no target starts twice in one step
        self.started: tuple[int, list[tuple[Array, Array]]] = (-1, [])

    def births_from_returns(self, returns: Array, scan: Scan, step: int) -> list[Birth]:
        return self._paired(returns, scan, step, None)

    def births_at(self, returns: Array, scan: Scan, step: int, t: float) -> list[Birth]:
        """Sensors of their own: a candidate pairs with the same sensor's next scan whenever it comes, ``T`` the
        interval between the two scans' times (s) in the velocity, its covariance and the gate."""
        return self._paired(returns, scan, step, float(t))

    def _gap(self, previous: tuple[Array, Array, int, float | None] | None, step: int, t: float | None) -> float | None:
        """The interval ``T`` (s) between a sensor's previous candidates and its scan now (at ``step``, time ``t``;
        None: on the run's grid), or None when they do not pair: on the grid, only candidates of the step before."""
        if previous is None:
            return None
        if t is None:
            return self.ts if previous[2] == step - 1 else None
        before = previous[3]
        return t - before if before is not None and t > before else None

    def _paired(self, returns: Array, scan: Scan, step: int, t: float | None) -> list[Birth]:
        noise = scan.noise_cov
        returns = np.asarray(returns, dtype=float).reshape(-1, noise.shape[0])
        if returns.shape[1] != self.pos.size:
            raise ValueError(f"two-point initiation: returns have {returns.shape[1]} components, "
                             f"position_indices {self.pos.size}")
        births: list[Birth] = []
        fresh = np.ones(len(returns), dtype=bool)
        if self.started[0] != step:
            self.started = (step, [])
        previous = self.candidates.get(scan.sensor)
        gap = self._gap(previous, step, t)
        if previous is not None and gap is not None and len(returns):
            old, old_noise = previous[0], previous[1]
            reach = self.max_speed * gap + np.sqrt(self.gamma * np.linalg.eigvalsh(old_noise + noise)[-1])
            dist = np.linalg.norm(returns[:, None, :] - old[None, :, :], axis=-1)  # (new, old)
            pairs = best_assignment(reach - dist, dist <= reach)
            for new, cand in enumerate(pairs):
                if cand >= 0:
                    fresh[new] = False
                    if not self._started_already(returns[new], noise):
                        births.append(self._birth(old[cand], old_noise, returns[new], noise, gap))
                        self.started[1].append((returns[new], noise))
        self.candidates[scan.sensor] = (returns[fresh], noise, step, t)
        return births

    def _started_already(self, z: Array, noise: Array) -> bool:
        """Whether another sensor's pair started a track at ``z`` (within the gate) this step."""
        return started_already(z, noise, self.started[1], self.gamma)

    def _birth(self, z1: Array, r1: Array, z2: Array, r2: Array, t: float) -> Birth:
        mean = np.zeros(self.prior_cov.shape[0])
        mean[self.pos], mean[self.vel] = z2, (z2 - z1) / t
        set_ = np.concatenate([self.pos, self.vel])
        cov = self.prior_cov.copy()
        cov[set_, :] = 0.0
        cov[:, set_] = 0.0
        cov[np.ix_(self.pos, self.pos)] = r2
        cov[np.ix_(self.pos, self.vel)] = r2 / t
        cov[np.ix_(self.vel, self.pos)] = r2 / t
        cov[np.ix_(self.vel, self.vel)] = (r1 + r2) / t**2
        return Birth(mean, cov)


class PriorInitiator(Initiator):
    """Starts tracks only from :meth:`~zentrack.fusion.multitarget.base.Initiator.from_prior` (bearing-only)."""

    def births_from_returns(self, returns: Array, scan: Scan, step: int) -> list[Birth]:
        return []
