"""The tracker's single-matrix linear algebra (numpy's LAPACK gufuncs, no SciPy): the verdicts and bits of the
public numpy functions they replace, no warnings on a failure, and bit for bit the batched code where the
batched simulator computes the same thing."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

from zentrack.fusion import linalg
from zentrack.fusion.estimates import GaussianEstimate
from zentrack.fusion.linalg import (
    GaussianState,
    cholesky_one,
    inverse,
    small_inverse,
    spd_mean_cov_one,
    spd_quadratic_form_one,
    to_information,
)


def matrices(rng: np.random.Generator, n: int, count: int = 60):
    """SPD, indefinite, singular, and NaN/inf-holding symmetric matrices, in turn."""
    for i in range(count):
        a = rng.standard_normal((n, n))
        m = a @ a.T + rng.choice([1e-3, 1.0, -0.5 * n]) * np.eye(n)
        kind = i % 5
        if kind == 3:
            m.flat[rng.integers(m.size)] = rng.choice([np.nan, np.inf, -np.inf])
        elif kind == 4 and n > 1:
            m[:, 0] = m[:, 1] = m[0] = m[1] = 1.0  # two equal rows and columns: singular
        yield m


def numpy_cholesky(m: np.ndarray) -> np.ndarray | None:
    try:
        return np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return None


@pytest.mark.parametrize("n", [1, 2, 3, 6, 12, 14])
def test_cholesky_one_gives_numpys_verdict_and_factor_without_a_warning(n):
    rng = np.random.default_rng(n)
    verdicts = set()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for m in matrices(rng, n):
            ours, ref = cholesky_one(m), numpy_cholesky(m)
            assert (ours is None) == (ref is None or np.isnan(m[0, 0]))  # a NaN first pivot is refused too
            if ours is not None:
                assert np.array_equal(ours, ref, equal_nan=True)
            verdicts.add(ref is None)
    assert verdicts == {True, False}
    assert cholesky_one(-np.eye(n)) is None and cholesky_one(np.full((n, n), np.nan)) is None


@pytest.mark.parametrize("n", [1, 2, 5, 12])
def test_inverse_is_numpys_inv_bit_for_bit_and_raises_on_a_singular_matrix(n):
    rng = np.random.default_rng(20 + n)
    stack = rng.standard_normal((4, n, n)) + n * np.eye(n)
    assert np.array_equal(inverse(stack), np.linalg.inv(stack))
    assert np.array_equal(inverse(stack[1]), np.linalg.inv(stack[1]))
    with pytest.raises(np.linalg.LinAlgError):
        inverse(np.zeros((n, n)))
    with pytest.raises(np.linalg.LinAlgError):
        linalg.spd_inverse(np.zeros((2, n, n)))


@pytest.mark.parametrize("n", [1, 2, 6, 12])
def test_spd_mean_cov_and_quadratic_form_refuse_what_is_not_positive_definite(n):
    rng = np.random.default_rng(40 + n)
    seen = set()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for m in matrices(rng, n):
            v = rng.standard_normal(n)
            pd = numpy_cholesky(m) is not None and not np.isnan(m[0, 0])
            mc, q = spd_mean_cov_one(m, v), spd_quadratic_form_one(m, v)
            assert (mc is None) == (q is None) == (not pd)
            seen.add(pd)
            if pd and np.isfinite(m).all():
                ref = np.linalg.inv(m)
                scale = np.abs(ref).max()
                assert np.allclose(mc[1], ref, rtol=1e-9, atol=1e-12 * scale)
                assert np.allclose(mc[0], ref @ v, rtol=1e-8, atol=1e-10 * scale * np.abs(v).max())
                assert np.isclose(q, v @ np.linalg.solve(m, v), rtol=1e-8)
    assert seen == {True, False}


def test_the_2x2_inverse_of_one_matrix_is_its_row_of_the_stacked_formula():
    rng = np.random.default_rng(5)
    stack = rng.standard_normal((300, 2, 2)) * 10.0 ** rng.integers(-6, 6, size=(300, 1, 1))
    stack[7] = [[1.0, 2.0], [2.0, 4.0]]  # det 0: infinities as numpy's formula gives them
    stack[8] = [[np.nan, 0.0], [0.0, 1.0]]
    with np.errstate(divide="ignore", invalid="ignore"):
        full = small_inverse(stack)
        for i in range(stack.shape[0]):
            assert np.array_equal(small_inverse(stack[i]), full[i], equal_nan=True)
    assert not np.isfinite(full[7]).any()


def test_a_gaussian_estimates_information_pair_is_its_row_of_the_batched_pair():
    rng = np.random.default_rng(6)
    for n in (2, 6, 12, 13):
        a = rng.standard_normal((1, 10, n, n))
        state = GaussianState(rng.standard_normal((1, 10, n)), a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(n))
        full = to_information(state)
        for i in range(10):
            pair = GaussianEstimate(state.mean[0, i], state.cov[0, i]).information_blocks()["state"]
            assert pair.matrix.shape == (n, n) and pair.vector.shape == (n,)
            assert np.array_equal(pair.matrix, full.matrix[0, i]) and np.array_equal(pair.vector, full.vector[0, i])


def test_a_tracker_step_of_the_fusion_code_loads_no_scipy_lapack():
    """Local update, prediction, information export, the gate and CI of one node, as a tracker runs them:
    SciPy's LAPACK extension (and with it SciPy's OpenBLAS) is never loaded."""
    script = """
        import json, sys
        import numpy as np
        from zentrack.config.scenario_config import builtin_spec
        from zentrack.truth.simulation.simulate import simulate
        from zentrack.fusion.filters.base import FilterContext
        from zentrack.fusion.filters.gaussian_node import make_node_filter
        from zentrack.fusion.gate import ci_gate_passes, information_mean_cov
        from zentrack.fusion.linalg import cholesky_one
        from zentrack.fusion.rules import make_rule
        from zentrack.fusion.scan import Scan
        scn = simulate(builtin_spec("exp2", 3, 5), runs=1, seed=0)
        f = make_node_filter("teskf", FilterContext.from_scenario(scn))
        rule = make_rule("ci", {})
        before = "scipy.linalg._flapack" in sys.modules
        est = f.initial(scn.x0_estimate[0])
        passed = []
        for k in range(5):
            scan = Scan(k, 0, scn.measurements[0, k, 0][None], scn.sensors[0], scn.noise_cov[0])
            post = f.update(est, [scan])
            assert cholesky_one(f.kinematic(post).cov) is not None
            pred = f.predict(post)
            blocks = {n: (p.matrix, p.vector) for n, p in rule.share(1, f.blocks(pred)).blocks.items()}
            mine = information_mean_cov(*blocks["state"])
            passed.append(ci_gate_passes(mine[0], mine[1], mine[0] + 0.1, mine[1], 30.0))
            est = f.from_fused(rule.combine_one(1, np.array([0.5, 0.25, 0.25]), [blocks] * 3), pred)
        print(json.dumps({"before": before, "after": "scipy.linalg._flapack" in sys.modules, "passed": passed}))
    """
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result == {"before": False, "after": False, "passed": [True] * 5}
