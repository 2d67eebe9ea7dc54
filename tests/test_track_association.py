"""Track-to-track association (``zentrack.fusion.track_to_track.association``): against its definition by brute
force, the cheap screens against the gate they screen for, the batched gate statistic against the pair-by-pair
formula."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from track_lists import TARGETS, random_spd, track

from zentrack.fusion.defaults import DEFAULT_GATE
from zentrack.fusion.gate import ci_gate_passes, ci_gate_statistic, gate_threshold
from zentrack.fusion.track_to_track import associate_tracks, sum_distance, trace_screen


def brute_force_association(own, other, false_rejection=DEFAULT_GATE) -> set[tuple[int, int]]:
    """The definition: among the matchings of gated pairs, the largest, then the smallest summed distance."""
    gamma = gate_threshold(own[0].mean.size, false_rejection)
    gated = {(i, j) for i, a in enumerate(own) for j, b in enumerate(other)
             if ci_gate_passes(a.mean, a.cov, b.mean, b.cov, gamma)}
    best, best_key = set(), (0, 0.0)
    for size in range(1, min(len(own), len(other)) + 1):
        for rows in itertools.combinations(range(len(own)), size):
            for cols in itertools.permutations(range(len(other)), size):
                pairs = set(zip(rows, cols))
                if pairs <= gated:
                    cost = sum(ci_gate_statistic(own[i].mean, own[i].cov, other[j].mean, other[j].cov)
                               for i, j in pairs)
                    if (-size, cost) < best_key:
                        best, best_key = pairs, (-size, cost)
    return best


def test_association_equals_brute_force_on_small_random_cases():
    rng = np.random.default_rng(33)
    nontrivial = 0
    for case in range(150):
        n = (2, 4)[case % 2]
        centres = rng.normal(scale=3.0, size=(4, n))  # close enough that several pairs pass the gate
        own = [track(0, 0, i, centres[rng.integers(4)] + rng.normal(size=n), random_spd(rng, n))
               for i in range(rng.integers(0, 5))]
        other = [track(0, 1, j, centres[rng.integers(4)] + rng.normal(size=n), random_spd(rng, n, 2.0))
                 for j in range(rng.integers(0, 5))]
        expected = brute_force_association(own, other) if own and other else set()
        got = associate_tracks(own, other)
        assert set(got) == expected, case
        assert got == sorted(got)
        nontrivial += len(expected) >= 2 and len(own) > len(expected)  # a choice was made among gated pairs
    assert nontrivial >= 10


def test_the_cheap_screen_never_refuses_a_pair_the_gate_passes():
    """``sum_distance`` bounds the gate: ``q(omega*) >= m2 / 2^n`` and ``q(1/2) = m2 / 2``, including lopsided
    covariances, where the smallest-volume omega sits at the end of the search."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        n = int(rng.integers(1, 7))
        a = track(0, 0, 0, rng.normal(size=n), random_spd(rng, n, 10.0 ** rng.uniform(-3, 3)))
        b = track(0, 1, 0, rng.normal(scale=5.0, size=n), random_spd(rng, n, 10.0 ** rng.uniform(-3, 3)))
        m2 = float(sum_distance([a], [b])[0, 0])
        diff = a.mean - b.mean
        assert m2 == pytest.approx(diff @ np.linalg.solve(a.cov + b.cov, diff), rel=1e-9)
        assert ci_gate_statistic(a.mean, a.cov, b.mean, b.cov) >= m2 / 2**n * (1 - 1e-9)
        gamma = m2 / 2**n * 0.999  # just below the screen's bound: the gate must refuse
        assert not ci_gate_passes(a.mean, a.cov, b.mean, b.cov, gamma)


def test_the_trace_screen_keeps_every_pair_within_the_bound_and_leaves_out_far_ones():
    """``trace_screen`` is necessary for ``sum_distance <= bound``: over lopsided covariances of every size it
    keeps each pair within the bound; on a list of separated targets it leaves out the pairs of different ones."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        n = int(rng.integers(1, 7))
        a = [track(0, 0, i, rng.normal(scale=3.0, size=n), random_spd(rng, n, 10.0 ** rng.uniform(-3, 3)))
             for i in range(4)]
        b = [track(0, 1, i, rng.normal(scale=3.0, size=n), random_spd(rng, n, 10.0 ** rng.uniform(-3, 3)))
             for i in range(5)]
        bound = float(rng.uniform(0.5, 50.0))
        rows, cols = trace_screen(np.stack([t.mean for t in a]), np.stack([t.cov for t in a]),
                                  np.stack([t.mean for t in b]), np.stack([t.cov for t in b]), bound)
        kept = set(zip(rows.tolist(), cols.tolist()))
        within = set(zip(*np.nonzero(sum_distance(a, b) <= bound)))
        assert within <= kept, (within - kept, bound)
    own = [track(0, 0, i, mean) for i, mean in enumerate(TARGETS)]
    other = [track(0, 1, i, mean + 0.5) for i, mean in enumerate(TARGETS)]
    rows, cols = trace_screen(np.stack([t.mean for t in own]), np.stack([t.cov for t in own]),
                              np.stack([t.mean for t in other]), np.stack([t.cov for t in other]),
                              2.0**4 * gate_threshold(4, DEFAULT_GATE))
    assert sorted(zip(rows.tolist(), cols.tolist())) == [(0, 0), (1, 1), (2, 2)]


def test_a_pair_only_the_smallest_volume_bound_passes_is_associated():
    """Lopsided covariances: the smallest-volume omega is far from 1/2, so along the one direction where the
    second estimate is precise the bound is wider than ``2 (P_a + P_b)``: a difference there passes the gate
    with ``m2`` near three times the threshold (the screen must not stop at ``m2 <= 2 threshold``)."""
    gamma = gate_threshold(4, DEFAULT_GATE)
    a = track(0, 0, 0, np.zeros(4), np.eye(4))
    b = track(0, 1, 0, [0.0, 0.0, 0.0, np.sqrt(3.0 * gamma)], np.diag([100.0, 100.0, 100.0, 0.01]))
    m2 = float(sum_distance([a], [b])[0, 0])
    assert m2 > 2.5 * gamma and ci_gate_passes(a.mean, a.cov, b.mean, b.cov, gamma)
    assert associate_tracks([a], [b]) == [(0, 0)]


def test_tracks_of_different_dimensions_are_not_associated():
    with pytest.raises(ValueError, match="dimensions"):
        associate_tracks([track(0, 0, 0, np.zeros(4))], [track(0, 1, 0, np.zeros(2), np.eye(2))])


# ------------------------------------------------------------------------------------------------ fusion




def _gate_statistic_one_pair(d, cov_a, cov_b):
    """The smallest-volume CI bound's statistic of one pair, as fusion/gate.py's docstring derives it."""
    low_inv = np.linalg.inv(np.linalg.cholesky(cov_a))
    lam, vecs = np.linalg.eigh(low_inv @ cov_b @ low_inv.T)
    z2 = (vecs.T @ (low_inv @ d)) ** 2
    w = np.linspace(0.02, 0.98, 49)[:, None]
    scale = 1.0 / w + lam[None, :] / (1.0 - w)
    return float(np.sum(z2 / scale[np.argmin(np.log(scale).sum(axis=1))]))


def test_batched_gate_statistics_equal_the_pair_by_pair_formula_and_refuse_bad_rows():
    from zentrack.fusion.gate import ci_gate_statistics

    rng = np.random.default_rng(5)
    a = rng.standard_normal((12, 6, 6))
    b = rng.standard_normal((12, 6, 6))
    cov_a, cov_b = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(6), b @ b.transpose(0, 2, 1) + 0.1 * np.eye(6)
    d = rng.standard_normal((12, 6)) * 3
    cov_a[3] = -np.eye(6)  # not positive definite
    d[7, 2] = np.nan
    q = ci_gate_statistics(d, cov_a, cov_b)
    for p in range(12):
        if p in (3, 7):
            assert q[p] == np.inf
        else:
            assert q[p] == pytest.approx(_gate_statistic_one_pair(d[p], cov_a[p], cov_b[p]), rel=1e-9)
