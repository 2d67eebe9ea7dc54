"""Paper 3 ship models: the exact turn integral against RK4, the constant-power step, analytic Jacobians."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.motion_ship import (
    SHIP_OBSERVATIONS,
    SHIP_P0,
    SHIP_TS,
    SHIP_X0,
    ShipConstantPower,
    ShipTurnCA,
    turn_coefficients,
    turn_displacement,
)


def rk4_turn(v: float, psi: float, a: float, w: float, t: float, steps: int = 2000) -> np.ndarray:
    """Integrate xdot = v sin psi (East), ydot = v cos psi (North), vdot = a, psidot = w; returns (Dx, Dy)."""

    def rhs(s: np.ndarray) -> np.ndarray:
        return np.array([s[2] * np.sin(s[3]), s[2] * np.cos(s[3]), a, w])

    s = np.array([0.0, 0.0, v, psi])
    h = t / steps
    for _ in range(steps):
        k1 = rhs(s)
        k2 = rhs(s + 0.5 * h * k1)
        k3 = rhs(s + 0.5 * h * k2)
        k4 = rhs(s + h * k3)
        s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s[:2]


def notes_formula(v: float, psi: float, a: float, w: float, t: float) -> np.ndarray:
    """The notes' closed form, literally (cancels badly for tiny w)."""
    dx = (w * (v * np.cos(psi) - (v + a * t) * np.cos(psi + w * t)) + a * (np.sin(psi + w * t) - np.sin(psi))) / w**2
    dy = (w * ((v + a * t) * np.sin(psi + w * t) - v * np.sin(psi)) + a * (np.cos(psi + w * t) - np.cos(psi))) / w**2
    return np.array([dx, dy])


def finite_difference_jacobian(fn, x: np.ndarray, h: float = 1e-5) -> np.ndarray:
    cols = []
    for j in range(x.shape[1]):
        dx = np.zeros_like(x)
        dx[:, j] = h
        cols.append((fn(x + dx) - fn(x - dx)) / (2 * h))
    return np.stack(cols, axis=-1)


CASES = [  # (v, psi, a, w, T)
    (10.0, np.pi / 4, 0.5, 1e-5, 1.0),  # the paper's scenario 1 (series branch)
    (10.0, np.pi / 4, 0.5, 0.0, 1.0),
    (7.0, 2.0, -0.3, 0.2, 1.0),
    (15.0, -2.5, 1.0, -0.5, 2.5),
    (3.0, 0.1, 0.0, 0.05, 1.0),
    (12.0, 4.0, 2.0, 0.999e-4, 1.0),  # just under the series switch
    (12.0, 4.0, 2.0, 1.001e-4, 1.0),  # just over it
    (20.0, 1.0, 0.7, -3e-3, 3.0),
]


@pytest.mark.parametrize("v, psi, a, w, t", CASES)
def test_turn_step_matches_rk4(v, psi, a, w, t):
    model = ShipTurnCA(ts=t, a_m=a, k_psi=w)
    x = np.array([[100.0, -50.0, 3.0, v, psi]])
    out = model.f(x)[0]
    np.testing.assert_allclose(out[:2] - x[0, :2], rk4_turn(v, psi, a, w, t), atol=1e-6, rtol=0)
    assert out[2] == 3.0
    assert out[3] == pytest.approx(v + a * t)
    assert out[4] == pytest.approx(psi + w * t)


def test_turn_axes_follow_north_to_east_heading():
    # heading 0 is due North, pi/2 due East: the displacement follows (sin psi, cos psi)
    d_north = turn_displacement(np.array(10.0), np.array(0.0), 0.0, 0.0, 1.0)
    d_east = turn_displacement(np.array(10.0), np.array(np.pi / 2), 0.0, 0.0, 1.0)
    np.testing.assert_allclose(d_north, [0.0, 10.0], atol=1e-12)
    np.testing.assert_allclose(d_east, [10.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("v, psi, a, w, t", [c for c in CASES if abs(c[3] * c[4]) > 1e-3])
def test_notes_formula_agrees_where_it_is_well_conditioned(v, psi, a, w, t):
    got = np.array(turn_displacement(np.array(v), np.array(psi), a, w, t))
    np.testing.assert_allclose(got, notes_formula(v, psi, a, w, t), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("t", [0.5, 1.0, 3.0])
def test_series_matches_closed_form_at_the_switch(t):
    w_switch = 1e-4 / t
    below = np.array(turn_coefficients(w_switch * (1 - 1e-12), t))
    above = np.array(turn_coefficients(w_switch * (1 + 1e-12), t))
    np.testing.assert_allclose(below[:3], above[:3], rtol=1e-9)
    np.testing.assert_allclose(below[3], above[3], rtol=1e-7)  # s2 ~ u^3/3: the closed form cancels (~1e-8)
    for v, psi, a in [(10.0, np.pi / 4, 0.5), (0.5, 3.0, 2.0), (25.0, -1.0, -1.0)]:
        lo = np.array(turn_displacement(np.array(v), np.array(psi), a, w_switch * (1 - 1e-12), t))
        hi = np.array(turn_displacement(np.array(v), np.array(psi), a, w_switch * (1 + 1e-12), t))
        np.testing.assert_allclose(lo, hi, rtol=1e-9, atol=1e-9 * np.hypot(*hi))
        # and the literal notes formula (cancellation ~eps/u^2 ~ 1e-8) within its own accuracy
        np.testing.assert_allclose(hi, notes_formula(v, psi, a, w_switch * (1 + 1e-12), t), rtol=0, atol=1e-6)


def test_turn_w_zero_is_the_straight_line():
    d = turn_displacement(np.array(10.0), np.array(0.3), 0.5, 0.0, 2.0)
    b = 10.0 * 2.0 + 0.5 * 0.5 * 4.0
    np.testing.assert_allclose(d, [np.sin(0.3) * b, np.cos(0.3) * b], rtol=1e-15)


def test_constant_power_step_matches_paper_formula(rng):
    p, eta, m, t = 2.4e5, 10.0, 1e4, 1.0
    model = ShipConstantPower(ts=t, power=p, eta=eta, mass=m)
    x = np.column_stack([rng.normal(0, 100, (6, 3)), rng.uniform(2.0, 30.0, 6), rng.uniform(-np.pi, np.pi, 6)])
    out = model.f(x)
    for xi, oi in zip(x, out, strict=True):
        v, psi = xi[3], xi[4]
        b = v * t + (p - eta * v**3) * t**2 / (2 * m * v)
        expected = [xi[0] + np.sin(psi) * b, xi[1] + np.cos(psi) * b, xi[2], v + (p - eta * v**3) * t / (m * v), psi]
        np.testing.assert_allclose(oi, expected, rtol=1e-14, atol=1e-12)
    # from the paper's x0: 2.3 m/s^2 of acceleration at 10 m/s, terminal speed (P/eta)^(1/3) ~ 28.8 m/s
    x1 = model.f(SHIP_X0[None])[0]
    assert x1[3] == pytest.approx(12.3)
    np.testing.assert_allclose(x1[:2], (10.0 + 1.15) * np.array([np.sin(np.pi / 4), np.cos(np.pi / 4)]))
    v_term = (p / eta) ** (1 / 3)
    np.testing.assert_allclose(model.f(np.array([[0, 0, 0, v_term, 0.0]]))[0, 3], v_term, rtol=1e-14)


MODELS = [
    ShipTurnCA(),
    ShipTurnCA(ts=2.0, a_m=-0.4, k_psi=0.1),
    ShipConstantPower(),
    ShipConstantPower(ts=0.5, power=1e5, eta=20.0, mass=5e3),
]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.name}-{m.ts}")
def test_jacobian_and_hessian_match_finite_differences(model, rng):
    x = np.column_stack([rng.normal(0, 200, (8, 3)), rng.uniform(3.0, 25.0, 8), rng.uniform(-np.pi, np.pi, 8)])
    jac = model.jacobian(x)
    fd = finite_difference_jacobian(model.f, x)
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-8)
    hess = model.hessian_diag(x)
    h = 1e-4
    for j in range(5):
        dx = np.zeros_like(x)
        dx[:, j] = h
        second = (model.jacobian(x + dx)[:, :, j] - model.jacobian(x - dx)[:, :, j]) / (2 * h)
        np.testing.assert_allclose(hess[:, :, j], second, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.name}-{m.ts}")
def test_shapes_and_batching(model, rng):
    x = np.column_stack([rng.normal(0, 50, (7, 3)), rng.uniform(5.0, 20.0, 7), rng.uniform(-3, 3, 7)])
    assert model.dim == 5 and model.lumped_dim == 0
    assert model.f(x).shape == (7, 5)
    assert model.jacobian(x).shape == (7, 5, 5)
    assert model.A.shape == (5, 5) and model.B.shape == (5, 0)
    np.testing.assert_allclose(model.A, model.jacobian(SHIP_X0[None])[0])
    np.testing.assert_allclose(model.Q, np.diag([1.0, 1.0, 1.0, 0.01, 1e-10]))
    np.testing.assert_allclose(model.noise_factor @ model.noise_factor.T, model.Q)
    assert model.lumped_nominal(x) is None
    assert model.true_lumped(x, 3).shape == (7, 0)
    batched = model.f(x)
    for i in range(7):
        np.testing.assert_array_equal(batched[i], model.f(x[i : i + 1])[0])
        np.testing.assert_array_equal(model.jacobian(x)[i], model.jacobian(x[i : i + 1])[0])
    before = x.copy()
    model.f(x)
    np.testing.assert_array_equal(x, before)  # f does not modify its input


def test_scenario_constants():
    np.testing.assert_allclose(SHIP_X0, [0, 0, 0, 10, np.pi / 4])
    np.testing.assert_allclose(np.diag(SHIP_P0), [41, 41, 1, 1, 1e-4])
    assert SHIP_TS == 1.0 and SHIP_OBSERVATIONS == 20
    assert ShipTurnCA().name == "ship-turn" and ShipConstantPower().name == "ship-power"
    with pytest.raises(ValueError):
        ShipTurnCA(q_diag=(1.0, 1.0))
