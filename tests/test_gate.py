"""The chi-square gate between correlated estimates (fusion/gate.py), and the tracker's use of it."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from zentrack.fusion.gate import ci_gate_passes, ci_gate_statistic, gate_threshold, information_mean_cov
from zentrack.fusion.rules import make_rule


def _spd(rng, n, scale=1.0):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T / n + 0.2 * np.eye(n))


def _brute(x_a, p_a, x_b, p_b):
    """d^T B(omega)^-1 d at the omega of the smallest det B over the same grid, by plain solves."""
    d = x_a - x_b
    best = min(np.linspace(0.02, 0.98, 49), key=lambda w: np.linalg.slogdet(p_a / w + p_b / (1 - w))[1])
    return float(d @ np.linalg.solve(p_a / best + p_b / (1 - best), d))


def test_statistic_is_the_ci_bound_at_the_smallest_volume_omega(rng):
    for _ in range(50):
        n = int(rng.integers(1, 13))
        p_a, p_b = _spd(rng, n), _spd(rng, n, scale=float(rng.uniform(0.1, 10)))
        x_a, x_b = rng.normal(size=n), rng.normal(size=n)
        q = ci_gate_statistic(x_a, p_a, x_b, p_b)
        assert q == pytest.approx(_brute(x_a, p_a, x_b, p_b), rel=1e-9)
        assert q == pytest.approx(ci_gate_statistic(x_b, p_b, x_a, p_a), rel=1e-9)  # symmetric
    assert ci_gate_statistic(x_a, p_a, x_a, p_b) == 0.0


@pytest.mark.parametrize("rho", [-0.99, -0.5, 0.0, 0.5, 0.99])
def test_an_honest_pair_is_refused_at_most_at_the_chosen_rate_whatever_the_correlation(rho):
    rng = np.random.default_rng(7)
    n, alpha, samples = 6, 0.01, 20_000
    p_a, p_b = _spd(rng, n), _spd(rng, n, scale=2.0)
    l_a, l_b = np.linalg.cholesky(p_a), np.linalg.cholesky(p_b)
    u, v = rng.normal(size=(samples, n)), rng.normal(size=(samples, n))
    e_a = u @ l_a.T
    e_b = (rho * u + np.sqrt(1 - rho**2) * v) @ l_b.T  # cross-covariance rho L_a L_b^T: any sign, any size
    threshold = gate_threshold(n, alpha)
    refused = np.mean([ci_gate_statistic(a, p_a, b, p_b) > threshold for a, b in zip(e_a, e_b)])
    assert refused <= alpha + 3 * np.sqrt(alpha / samples), refused


def test_a_kilometre_lie_is_refused_and_bad_inputs_never_pass(rng):
    p = np.diag([25.0, 25.0, 25.0, 4.0, 4.0, 4.0])  # 5 m, 2 m/s
    x = rng.normal(size=6)
    lie = x + np.array([1000.0, 0, 0, 0, 0, 0])
    assert ci_gate_statistic(x, p, lie, p) > gate_threshold(6, 1e-3)
    assert ci_gate_statistic(x, p, x + 3.0, p) < gate_threshold(6, 1e-3)
    assert ci_gate_statistic(x, p, x, -p) == np.inf
    assert ci_gate_statistic(x, p, x * np.nan, p) == np.inf
    assert information_mean_cov(-np.eye(2), np.zeros(2)) is None


def test_the_gate_passes_a_pair_exactly_when_the_half_omega_or_the_smallest_volume_bound_does(rng):
    passed = {True: 0, False: 0}
    for _ in range(400):
        n = int(rng.integers(1, 13))
        p_a, p_b = _spd(rng, n), _spd(rng, n, scale=float(rng.uniform(0.05, 20)))
        x_a, x_b = rng.normal(size=n) * 3, rng.normal(size=n) * 3
        t = gate_threshold(n, 1e-2)
        d = x_a - x_b
        half = float(d @ np.linalg.solve(2 * (p_a + p_b), d))
        expected = half <= t or _brute(x_a, p_a, x_b, p_b) <= t
        assert ci_gate_passes(x_a, p_a, x_b, p_b, t) == expected
        passed[expected] += 1
    assert min(passed.values()) > 40  # both verdicts are exercised
    p = np.eye(3)
    assert not ci_gate_passes(np.zeros(3), p, np.full(3, np.nan), p, 100.0)
    assert not ci_gate_passes(np.zeros(3), p, np.zeros(3), -p, 100.0)


def test_threshold_is_the_chi_square_quantile():
    for dim in (1, 6, 12):
        for alpha in (1e-2, 1e-3, 1e-6):
            assert gate_threshold(dim, alpha) == pytest.approx(chi2.ppf(1 - alpha, dim), rel=1e-9)
    with pytest.raises(ValueError, match="false-rejection"):
        gate_threshold(6, 0.0)


def test_rules_say_which_messages_are_estimates():
    y, v = np.eye(3), np.ones(3)
    assert make_rule("ci").message_estimate(1, {"state": (y, v)}) == (y, v)
    assert make_rule("ci3").message_estimate(3, {"state": (y, v)}) == (y, v)
    ici = make_rule("dce-ici", {"rounds": 3})
    assert ici.message_estimate(1, {"state": (y, v), "moment": (y, v)}) == (y, v)
    assert ici.message_estimate(2, {"state": (y, v), "moment": (y, v)}) is None
    fci = make_rule("dce-fci", {"rounds": 3})
    mat, vec = fci.message_estimate(1, {"state": (2 * y, 2 * v), "trace": (np.array([[2.0]]), np.array([2.0]))})
    np.testing.assert_allclose(mat, y)
    np.testing.assert_allclose(vec, v)
    for rule in ("eot-ci", "eot-cm", "local"):
        assert make_rule(rule).message_estimate(1, {"state": (y, v)}) is None


def test_bench_gate_counts_every_honest_neighbour_message_of_a_lockstep_run(tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "gate.json"
    done = subprocess.run([sys.executable, "-m", "zentrack", "bench", "gate", "--only", "1", "--steps", "30",
                           "--json", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    row = report["configs"][0]
    assert (row["scenario"], row["filter"], row["fusion"], row["nodes"]) == ("exp2", "teskf", "ci", 10)
    # a ring of 10: every node hears both neighbours at every step after the first
    assert 0.95 * 2 * 10 * 30 <= row["received"] <= 2 * 10 * 30
    assert report["rate"] == report["gated"] / report["received"] <= report["gate"]
    assert "honest neighbours' messages refused" in done.stdout
