"""Linear-algebra building blocks: both inverse paths, the Joseph update, information round trips."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion import linalg
from zentrack.fusion.linalg import (
    GaussianState,
    from_information,
    is_spd,
    joseph_update,
    lower_triangular_inverse,
    spd_inverse,
    to_information,
)


def random_spd(rng, b, n):
    a = rng.normal(size=(b, n, n))
    return a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(n)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6, 9, 12, 13])
@pytest.mark.parametrize("b", [3, linalg.CHOLESKY_INVERSE_MIN_BATCH + 5])
def test_spd_inverse_both_paths(rng, n, b):
    p = random_spd(rng, b, n)
    inv = spd_inverse(p)
    np.testing.assert_allclose(inv @ p, np.broadcast_to(np.eye(n), p.shape), atol=1e-9)
    np.testing.assert_array_equal(inv, np.swapaxes(inv, -1, -2))


def test_lower_triangular_inverse(rng):
    low = np.tril(rng.normal(size=(5, 7, 7))) + 3 * np.eye(7)
    np.testing.assert_allclose(lower_triangular_inverse(low), np.linalg.inv(low), atol=1e-12)


def test_non_spd_large_stack_raises(rng):
    p = random_spd(rng, linalg.CHOLESKY_INVERSE_MIN_BATCH, 6)
    p[3] = -np.eye(6)
    with pytest.raises(np.linalg.LinAlgError):
        spd_inverse(p)


def test_joseph_update_equals_textbook_update(rng):
    p = random_spd(rng, 4, 5)
    x = rng.normal(size=(4, 5))
    h = rng.normal(size=(4, 2, 5))
    r = random_spd(rng, 4, 2)
    nu = rng.normal(size=(4, 2))
    out = joseph_update(GaussianState(x, p), h, nu, r)
    for i in range(4):
        s = h[i] @ p[i] @ h[i].T + r[i]
        k = p[i] @ h[i].T @ np.linalg.inv(s)
        np.testing.assert_allclose(out.mean[i], x[i] + k @ nu[i])
        np.testing.assert_allclose(out.cov[i], p[i] - k @ s @ k.T, atol=1e-10)
    assert np.all(is_spd(out.cov))


def test_information_round_trip(rng):
    state = GaussianState(rng.normal(size=(3, 4)), random_spd(rng, 3, 4))
    back = from_information(to_information(state))
    np.testing.assert_allclose(back.mean, state.mean)
    np.testing.assert_allclose(back.cov, state.cov, atol=1e-12)


def test_is_spd_flags_bad_matrices():
    good = np.eye(3)
    asym = np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]])
    indefinite = np.diag([1.0, -1.0, 1.0])
    nan = np.full((3, 3), np.nan)
    assert is_spd(np.stack([good, asym, indefinite, nan])).tolist() == [True, False, False, False]
