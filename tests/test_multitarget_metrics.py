"""Multi-target metrics (zentrack.fusion.multitarget.metrics) against their definitions by brute force over every
assignment on small random sets, on hand-made cases, and against Stone Soup's GOSPAMetric and OSPAMetric."""
from __future__ import annotations

import datetime
import itertools

import numpy as np
import pytest

from zentrack.fusion.multitarget.metrics import (
    gospa,
    identity_switches_and_fragmentations,
    ospa,
    summarize_run,
)

SIZES = range(6)  # set sizes 0..5


def random_sets(rng: np.random.Generator, cases: int = 120):
    """Pairs of 2-D sets of sizes 0..5 in a 10 x 10 box: with c = 3 some pairs lie beyond the cut-off."""
    for _ in range(cases):
        n, m = rng.choice(SIZES, size=2)
        yield rng.uniform(0, 10, size=(n, 2)), rng.uniform(0, 10, size=(m, 2))


def dist(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[:, None, :] - y[None, :, :], axis=-1)


def gospa_by_definition(x, y, c, p, alpha):
    """Rahmathullah et al. 2017, Definition 1: min over the injections of the smaller set into the larger."""
    if len(x) > len(y):
        x, y = y, x
    d = np.minimum(dist(x, y), c) ** p if len(x) else np.zeros((0, len(y)))
    best = min(sum(d[i, j] for i, j in enumerate(perm)) for perm in itertools.permutations(range(len(y)), len(x)))
    return (best + c**p / alpha * (len(y) - len(x))) ** (1 / p)


def gospa_by_assignment_sets(x, y, c, p):
    """Proposition 1 (alpha = 2): min over every assignment set gamma (partial matchings, uncut distances) of
    localisation + c^p/2 (|X| + |Y| - 2|gamma|); returns (total, localisation, missed, false)."""
    d = dist(x, y) ** p if len(x) and len(y) else np.zeros((len(x), len(y)))
    best = None
    for k in range(min(len(x), len(y)) + 1):
        for rows in itertools.combinations(range(len(x)), k):
            for cols in itertools.permutations(range(len(y)), k):
                loc = sum(d[i, j] for i, j in zip(rows, cols))
                cost = loc + c**p / 2 * (len(x) + len(y) - 2 * k)
                if best is None or cost < best[0]:
                    best = (cost, loc, c**p / 2 * (len(y) - k), c**p / 2 * (len(x) - k))
    assert best is not None
    return (best[0] ** (1 / p),) + best[1:]


def ospa_by_definition(x, y, c, p):
    """Schuhmacher, Vo, Vo 2008, Sec. III: (total, localisation, cardinality), over the permutations of the larger."""
    if len(x) > len(y):
        x, y = y, x
    m, n = len(x), len(y)
    if n == 0:
        return 0.0, 0.0, 0.0
    d = np.minimum(dist(x, y), c) ** p if m else np.zeros((0, n))
    loc = min(sum(d[i, j] for i, j in enumerate(perm)) for perm in itertools.permutations(range(n), m))
    card = c**p * (n - m)
    return ((loc + card) / n) ** (1 / p), (loc / n) ** (1 / p), (card / n) ** (1 / p)


# ------------------------------------------------------------------------------------- GOSPA by brute force


@pytest.mark.parametrize("p", [1.0, 2.0, 3.0])
def test_gospa_equals_both_definitions_by_brute_force(p):
    rng = np.random.default_rng(int(p))
    c = 3.0
    for x, y in random_sets(rng):
        g = gospa(x, y, c, order=p)
        total, loc, missed, false = gospa_by_assignment_sets(x, y, c, p)
        assert g.total == pytest.approx(total, rel=1e-12, abs=1e-12)
        assert g.total == pytest.approx(gospa_by_definition(x, y, c, p, 2.0), rel=1e-12, abs=1e-12)
        assert (g.localisation, g.missed, g.false) == pytest.approx((loc, missed, false), rel=1e-12, abs=1e-12)
        assert g.total**p == pytest.approx(g.localisation + g.missed + g.false, rel=1e-12, abs=1e-12)
        assert g.n_missed == len(y) - g.n_assigned and g.n_false == len(x) - g.n_assigned
        assert g.missed == pytest.approx(c**p / 2 * g.n_missed) and g.false == pytest.approx(c**p / 2 * g.n_false)
        # the pairs are a matching of points closer than c whose distances make up the localisation
        assert len(set(g.pairs[:, 0])) == len(set(g.pairs[:, 1])) == g.n_assigned
        if g.n_assigned:
            d = dist(x[g.pairs[:, 0]], y[g.pairs[:, 1]]).diagonal()
            assert np.all(d < c) and np.sum(d**p) == pytest.approx(g.localisation)


@pytest.mark.parametrize("alpha", [0.5, 1.0])
def test_gospa_total_for_alpha_below_two_equals_definition_1(alpha):
    rng = np.random.default_rng(11)
    for x, y in random_sets(rng, 60):
        g = gospa(x, y, 3.0, order=2.0, alpha=alpha)
        assert g.total == pytest.approx(gospa_by_definition(x, y, 3.0, 2.0, alpha), rel=1e-12, abs=1e-12)
        assert g.total**2 == pytest.approx(g.localisation + g.missed + g.false)


def test_gospa_hand_made_cases():
    c, p = 4.0, 2.0
    none = np.zeros((0, 2))
    empty = gospa(none, [], c, p)
    assert (empty.total, empty.localisation, empty.missed, empty.false) == (0.0, 0.0, 0.0, 0.0)
    missed = gospa(none, [[1.0, 2.0]], c, p)  # one truth, no estimate: c^p / 2
    assert (missed.total, missed.missed, missed.false, missed.n_missed, missed.n_false) == (np.sqrt(8.0), 8.0, 0, 1, 0)
    false = gospa([[1.0, 2.0]], none, c, p)
    assert (false.total, false.missed, false.false, false.n_missed, false.n_false) == (np.sqrt(8.0), 0, 8.0, 0, 1)
    far = gospa([[0.0, 0.0]], [[10.0, 0.0]], c, p)  # beyond c: one missed and one false, not a pair
    assert (far.n_assigned, far.n_missed, far.n_false, far.localisation) == (0, 1, 1, 0.0)
    assert far.total == pytest.approx(c) and far.pairs.shape == (0, 2)
    # a 3-4-5 pair within c, a false estimate far away
    near = gospa([[0.0, 0.0], [50.0, 50.0]], [[3.0 / 5 * 3, 4.0 / 5 * 3]], c, p)
    assert (near.localisation, near.n_assigned, near.n_false, near.false) == (pytest.approx(9.0), 1, 1, 8.0)
    assert near.pairs.tolist() == [[0, 0]]
    # the pair exactly at c counts as missed + false (Stone Soup does the same)
    at_c = gospa([[0.0, 0.0]], [[c, 0.0]], c, p)
    assert (at_c.n_assigned, at_c.n_missed, at_c.n_false) == (0, 1, 1)


@pytest.mark.parametrize("bad, match", [
    (dict(cutoff=0.0), "cutoff"), (dict(cutoff=np.inf), "cutoff"), (dict(order=0.5), "order"),
    (dict(order=np.inf), "order"), (dict(alpha=3.0), "alpha"),
])
def test_gospa_refuses_bad_parameters(bad, match):
    kwargs = dict(cutoff=1.0, order=2.0, alpha=2.0) | bad
    with pytest.raises(ValueError, match=match):
        gospa([[0.0, 0.0]], [[1.0, 1.0]], **kwargs)


def test_gospa_refuses_bad_sets():
    with pytest.raises(ValueError, match="non-finite"):
        gospa([[np.nan, 0.0]], [[1.0, 1.0]], 1.0)
    with pytest.raises(ValueError, match="2-D points but truths 3-D"):
        gospa([[0.0, 0.0]], [[1.0, 1.0, 1.0]], 1.0)
    with pytest.raises(ValueError, match="set of points"):
        gospa([0.0, 0.0], [[1.0, 1.0]], 1.0)
    with pytest.raises(ValueError, match="two sets"):
        gospa(np.zeros((2, 3, 2)), [[1.0, 1.0]], 1.0)


# -------------------------------------------------------------------------------------- OSPA by brute force


@pytest.mark.parametrize("p", [1.0, 2.0, 3.0])
def test_ospa_equals_definition_by_brute_force(p):
    rng = np.random.default_rng(20 + int(p))
    for x, y in random_sets(rng):
        o = ospa(x, y, 3.0, order=p)
        assert (o.total, o.localisation, o.cardinality) == pytest.approx(ospa_by_definition(x, y, 3.0, p),
                                                                        rel=1e-12, abs=1e-12)
        assert o.total**p == pytest.approx(o.localisation**p + o.cardinality**p)
        assert 0.0 <= o.total <= 3.0 + 1e-12
        assert ospa(y, x, 3.0, order=p).total == pytest.approx(o.total, rel=1e-12, abs=1e-12)  # symmetric


def test_ospa_hand_made_cases():
    assert ospa(np.zeros((0, 2)), [], 5.0).total == 0.0
    assert ospa([[0.0, 0.0]], [], 5.0).total == pytest.approx(5.0)  # one point against none: c
    # one matched exactly, one extra: cardinality ((c^p * 1) / 2)^(1/p), no localisation
    o = ospa([[0.0, 0.0]], [[0.0, 0.0], [100.0, 0.0]], 5.0, order=2.0)
    assert (o.total, o.localisation, o.cardinality) == pytest.approx((np.sqrt(12.5), 0.0, np.sqrt(12.5)))
    # a rigid shift by (3, 4) of four points listed in another order: every matched distance is 5
    pts = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]])
    assert ospa(pts, pts[::-1] + [3.0, 4.0], 50.0).total == pytest.approx(5.0)
    assert ospa(np.zeros((4, 2)), np.full((4, 2), 1e6), 7.0).total == pytest.approx(7.0)  # bounded by c


def test_ospa_batched_over_leading_axes_equals_one_call_per_set_pair():
    """The call shape of paper 4's bench: (R, K, M, 4, 2) corner stacks -> (R, K, M); unequal sizes too."""
    rng = np.random.default_rng(6)
    x = rng.normal(scale=30.0, size=(2, 3, 4, 4, 2))
    y = x + rng.normal(scale=3.0, size=x.shape)
    out = ospa(x, y, 50.0)
    assert out.total.shape == (2, 3, 4)
    np.testing.assert_allclose(ospa(x, x, 50.0).total, 0.0, atol=1e-12)
    for idx in np.ndindex(2, 3, 4):
        assert out.total[idx] == pytest.approx(ospa_by_definition(x[idx], y[idx], 50.0, 2.0)[0], rel=1e-12)
    # permuting the points of either set changes nothing; y broadcasts against x's leading axes
    np.testing.assert_allclose(ospa(x[..., ::-1, :], y, 50.0).total, out.total, rtol=1e-12)
    unequal = ospa(x, y[0, 0, 0, :3], 50.0)
    assert unequal.total.shape == (2, 3, 4)
    assert unequal.total[1, 2, 3] == pytest.approx(ospa_by_definition(x[1, 2, 3], y[0, 0, 0, :3], 50.0, 2.0)[0])
    # a diverged estimate (NaN) scores NaN in its own entry only
    x[0, 1, 2, 0, 0] = np.nan
    bad = ospa(x, y, 50.0).total
    assert np.isnan(bad[0, 1, 2]) and np.isfinite(np.delete(bad.ravel(), np.ravel_multi_index((0, 1, 2), bad.shape))).all()


# ----------------------------------------------------------------------------------------------- Stone Soup


def stone_soup_states(points: np.ndarray, when: datetime.datetime) -> list:
    from stonesoup.types.array import StateVector
    from stonesoup.types.state import State
    return [State(StateVector(list(pt)), timestamp=when) for pt in points]


@pytest.mark.parametrize("p", [1.0, 2.0])
def test_gospa_agrees_with_stone_soup_gospametric(p):
    pytest.importorskip("stonesoup", reason="Stone Soup is in the bench extra (pip install '.[bench]')")
    from stonesoup.metricgenerator.ospametric import GOSPAMetric
    metric = GOSPAMetric(c=3.0, p=p)
    when = datetime.datetime(2026, 1, 1)
    rng = np.random.default_rng(30 + int(p))
    compared = 0
    for x, y in random_sets(rng, 80):
        if len(x) == 0 and len(y) == 0:
            continue  # Stone Soup needs a state to take the timestamp from
        value = metric.compute_gospa_metric(stone_soup_states(x, when), stone_soup_states(y, when))[0].value
        g = gospa(x, y, 3.0, order=p)
        assert (g.total, g.localisation, g.missed, g.false) == pytest.approx(
            (value["distance"], value["localisation"], value["missed"], value["false"]), rel=1e-9, abs=1e-12)
        compared += 1
    assert compared > 60


def test_stone_soup_ospa_differs_from_the_definition_for_p_not_1():
    """Stone Soup's OSPAMetric picks the assignment on the unpowered cut-off distances, then powers them.

    x1 = y1 at the origin, x2 and y2 on the circle of radius 2, 3 apart. Pairing (x1, y1), (x2, y2) has distances
    (0, 3): sum 3 but sum of squares 9; pairing (x1, y2), (x2, y1) has (2, 2): sum 4, squares 8. For p = 2 the
    definition takes the second: sqrt(8 / 2) = 2; Stone Soup the first: sqrt(9 / 2). For p = 1 they agree.
    """
    pytest.importorskip("stonesoup", reason="Stone Soup is in the bench extra (pip install '.[bench]')")
    from stonesoup.metricgenerator.ospametric import OSPAMetric
    half = np.arcsin(3.0 / 4.0)  # half the angle between x2 and y2 seen from the origin (chord 3, radius 2)
    x = np.array([[0.0, 0.0], [2 * np.cos(half), 2 * np.sin(half)]])
    y = np.array([[0.0, 0.0], [2 * np.cos(half), -2 * np.sin(half)]])
    np.testing.assert_allclose(dist(x, y), [[0.0, 2.0], [2.0, 3.0]], atol=1e-12)
    when = datetime.datetime(2026, 1, 1)

    def stone_soup(p):
        return OSPAMetric(c=10.0, p=p).compute_OSPA_distance(stone_soup_states(x, when),
                                                             stone_soup_states(y, when)).value

    assert ospa(x, y, 10.0, order=2.0).total == pytest.approx(2.0)
    assert ospa_by_definition(x, y, 10.0, 2.0)[0] == pytest.approx(2.0)
    assert stone_soup(2.0) == pytest.approx(np.sqrt(4.5))
    assert ospa(x, y, 10.0, order=1.0).total == pytest.approx(stone_soup(1.0)) == pytest.approx(1.5)


# ------------------------------------------------------------------------------ identity switches, fragments


def at(*xs: float) -> np.ndarray:
    return np.array([[v, 0.0] for v in xs])


def test_identity_switch_counted_when_the_assigned_track_changes():
    truths = [{"A": [0.0, 0.0]}] * 4
    tracks = [{1: [0.1, 0.0]}, {1: [0.1, 0.0]}, {2: [0.1, 0.0]}, {1: [0.1, 0.0]}]
    e = identity_switches_and_fragmentations(tracks, truths, cutoff=1.0)
    assert (e.switches, e.fragmentations) == (2, 0)
    assert e.switches_per_step.tolist() == [0, 0, 1, 1]


def test_crossing_targets_swapping_tracks_count_two_switches():
    truths = [(["A", "B"], at(0.0, 10.0)), (["A", "B"], at(4.0, 6.0)), (["A", "B"], at(6.0, 4.0))]
    tracks = [(["t1", "t2"], at(0.2, 9.8)), (["t1", "t2"], at(4.2, 5.8)), (["t1", "t2"], at(4.2, 5.8))]
    e = identity_switches_and_fragmentations(tracks, truths, cutoff=3.0)
    assert e.switches_per_step.tolist() == [0, 0, 2] and e.fragmentations == 0


def test_fragmentation_counted_when_coverage_resumes():
    truths = [{"A": [0.0, 0.0]}] * 6
    lost = {7: [100.0, 0.0]}  # a track far from the truth (beyond c): the truth is untracked
    tracks = [{7: [0.0, 0.0]}, lost, lost, {7: [0.0, 0.0]}, {}, {8: [0.0, 0.0]}]
    e = identity_switches_and_fragmentations(tracks, truths, cutoff=1.0)
    # resumed at step 3 by the same track (a fragmentation), at step 5 by another (a fragmentation and a switch)
    assert e.fragmentations_per_step.tolist() == [0, 0, 0, 1, 0, 1]
    assert e.switches_per_step.tolist() == [0, 0, 0, 0, 0, 1]


def test_no_fragmentation_for_late_start_coverage_ending_untracked_or_a_truth_absent_in_between():
    truths = [{"A": [0.0, 0.0]}, {"A": [0.0, 0.0]}, {}, {"A": [0.0, 0.0]}, {"A": [0.0, 0.0]}]
    tracks = [{}, {1: [0.0, 0.0]}, {1: [0.0, 0.0]}, {1: [0.0, 0.0]}, {}]
    e = identity_switches_and_fragmentations(tracks, truths, cutoff=1.0)
    assert (e.switches, e.fragmentations) == (0, 0)


def test_identity_inputs_refused_with_a_reason():
    with pytest.raises(ValueError, match="duplicate ids"):
        identity_switches_and_fragmentations([(["t", "t"], at(0.0, 1.0))], [{}], 1.0)
    with pytest.raises(ValueError, match="2 track steps but 1 truth steps"):
        identity_switches_and_fragmentations([{}, {}], [{}], 1.0)
    with pytest.raises(ValueError, match="3 ids but positions"):
        identity_switches_and_fragmentations([(["a", "b", "c"], at(0.0, 1.0))], [{}], 1.0)
    with pytest.raises(ValueError, match="a step is"):
        identity_switches_and_fragmentations([[0.0, 1.0]], [{}], 1.0)


def test_summarize_run_means_the_per_step_gospa():
    rng = np.random.default_rng(40)
    sets = list(random_sets(rng, 12))
    tracks = [(list(range(len(x))), x) for x, _ in sets]
    truths = [(list(range(len(y))), y) for _, y in sets]
    s = summarize_run(tracks, truths, cutoff=3.0)
    each = [gospa(x, y, 3.0) for x, y in sets]
    assert s.steps == 12 and s.gospa == pytest.approx(np.mean([g.total for g in each]))
    assert s.rms_gospa == pytest.approx(np.sqrt(np.mean([g.total**2 for g in each])))
    for part in ("localisation", "missed", "false", "n_missed", "n_false"):
        assert getattr(s, part) == pytest.approx(np.mean([getattr(g, part) for g in each]))
    alone = identity_switches_and_fragmentations(tracks, truths, 3.0)
    assert s.identity.switches_per_step.tolist() == alone.switches_per_step.tolist()
    assert s.identity.fragmentations_per_step.tolist() == alone.fragmentations_per_step.tolist()
    with pytest.raises(ValueError, match="at least one step"):
        summarize_run([], [], 3.0)
