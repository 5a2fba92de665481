"""Minimum-time minimum-jerk references (aerohrl.datagen.reference, thesis Alg. 1)."""

import math

import numpy as np
import pytest

from aerohrl.datagen import reference as ref
from aerohrl.datagen.goals import sample_goals
from aerohrl.errors import UserError

A_MAX = 5.0
PEAK = 10.0 / math.sqrt(3.0)  # rest-to-rest min-jerk peak |a| = PEAK * dp / T^2


def goal_states(n, seed, **kw):
    g = sample_goals(np.random.default_rng(seed), n, **kw)
    x0 = np.zeros((n, 3, 3))
    xf = np.stack([g["pos"], g["vel"], g["acc"]], axis=-1)
    return x0, xf


@pytest.fixture(scope="module")
def batch():
    """250 goals from rho_D and their closed-form minimum-time references."""
    x0, xf = goal_states(250, 11)
    T, c, f = ref.min_time(x0, xf)
    return x0, xf, T, c, f


def scaled(c, T):
    """Coefficients in normalised time divided by a_max T^2 (the QP's own units)."""
    return ref._to_tau(c, T) / (A_MAX * T[:, None, None] ** 2)


# ------------------------------------------------------------------ closed form


def test_closed_form_meets_all_boundary_conditions():
    rng = np.random.default_rng(0)
    n = 64
    x0 = rng.normal(size=(n, 3, 3)) * [1.0, 2.0, 4.0]  # arbitrary start states too
    xf = rng.normal(size=(n, 3, 3)) * [1.0, 2.0, 4.0]
    T = rng.uniform(0.2, 4.0, size=n)
    c = ref.min_jerk_closed_form(x0, xf, T)
    assert c.shape == (n, 3, 6)
    for order in range(3):
        np.testing.assert_allclose(ref.evaluate(c, 0.0, order), x0[..., order], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(ref.evaluate(c, T, order), xf[..., order], rtol=1e-9, atol=1e-9)


def test_closed_form_matches_mhd_alpha_and_is_jerk_optimal():
    rng = np.random.default_rng(1)
    x0 = rng.normal(size=(8, 3, 3))
    xf = rng.normal(size=(8, 3, 3))
    T = rng.uniform(0.5, 3.0, size=8)
    c = ref.min_jerk_closed_form(x0, xf, T)
    Tb = T[:, None]
    p0, v0, a0 = x0[..., 0], x0[..., 1], x0[..., 2]
    dp = xf[..., 0] - p0 - v0 * Tb - 0.5 * a0 * Tb**2
    dv = xf[..., 1] - v0 - a0 * Tb
    da = xf[..., 2] - a0
    alpha = (60 * Tb**2 * da - 360 * Tb * dv + 720 * dp) / Tb**5  # MHD 2015, fully fixed end
    np.testing.assert_allclose(120 * c[..., 5], alpha, rtol=1e-9)
    # perturbing by a polynomial that keeps all boundary conditions only raises the cost
    cost = ref.jerk_cost(c, T)
    for eps in (-1e-2, 1e-2):
        bump = np.zeros((8, 3, 8))
        bump[..., :6] = c
        # tau^3 (1 - tau)^3 = tau^3 - 3 tau^4 + 3 tau^5 - tau^6, in t
        for k, w in zip(range(3, 7), (1.0, -3.0, 3.0, -1.0)):
            bump[..., k] += eps * w / T[:, None] ** k
        assert (ref.jerk_cost(bump, T) > cost).all()


def test_evaluate_shapes_and_derivatives():
    x0, xf = goal_states(5, 2)
    T = np.full(5, 2.0)
    c = ref.min_jerk_closed_form(x0, xf, T)
    assert ref.evaluate(c, 0.3).shape == (5, 3)
    assert ref.evaluate(c, np.full(5, 0.3)).shape == (5, 3)
    tk = np.linspace(0, 2, 7)[None].repeat(5, 0)
    assert ref.evaluate(c, tk, 3).shape == (5, 7, 3)
    np.testing.assert_array_equal(ref.evaluate(c, tk[:, 2], 1), ref.evaluate(c, tk, 1)[:, 2])
    h = 1e-5
    for order in range(3):
        fd = (ref.evaluate(c, tk + h, order) - ref.evaluate(c, tk - h, order)) / (2 * h)
        np.testing.assert_allclose(ref.evaluate(c, tk, order + 1), fd, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(ref.evaluate(c, tk, 6), 0.0)


def test_max_acceleration_is_exact():
    x0, xf = goal_states(40, 3)
    T = np.random.default_rng(3).uniform(1.0, 3.0, 40)
    grid = np.linspace(0, 1, 20001)[None] * T[:, None]
    c5 = ref.min_jerk_closed_form(x0, xf, T)
    c7, _ = ref.min_jerk_qp(x0[:6], xf[:6], T[:6], degree=7, a_max=50.0)
    c7 = c7 + np.random.default_rng(4).normal(scale=1e-2, size=c7.shape) / T[:6, None, None] ** np.arange(8)
    for c, TT, g in ((c5, T, grid), (c7, T[:6], grid[:6])):
        dense = np.abs(ref.evaluate(c, g, 2)).max(axis=1)
        exact = ref.max_acceleration(c, TT)
        assert (exact >= dense - 1e-9).all()
        np.testing.assert_allclose(exact, dense, rtol=1e-6)


# --------------------------------------------------------------- minimum time


def test_min_time_bracket_property(batch):
    x0, xf, T, c, f = batch
    assert f.all() and T.shape == (250,) and c.shape == (250, 3, 6)
    # T is on Alg. 1's grid (4 / 2^8 steps from 0) and is the feasible end of the bracket
    np.testing.assert_array_equal(T * 64, np.round(T * 64))
    assert (ref.max_acceleration(c, T).max(axis=1) <= A_MAX * (1 + 1e-9)).all()
    np.testing.assert_array_equal(c, ref.min_jerk_closed_form(x0, xf, T))
    below = T - ref.TOL
    too_fast = ref.max_acceleration(ref.min_jerk_closed_form(x0, xf, below), below).max(axis=1)
    assert (too_fast > A_MAX).all()


@pytest.mark.parametrize("solver", ["closed-form", "qp"])
def test_rest_to_rest_matches_analytic_minimum(solver):
    dp = np.array([0.3, 1.0, 1.7, 2.0, 3.0, 5.0])
    n = len(dp)
    xf = np.zeros((n, 3, 3))
    xf[:, 0, 0] = dp  # x moves, y, z small moves that never bind
    xf[:, 1, 0] = -0.5 * dp
    xf[:, 2, 0] = 0.1
    T, c, f = ref.min_time(np.zeros((n, 3, 3)), xf, solver=solver)
    expect = np.sqrt(PEAK * dp / A_MAX)  # 5.774 |dp| / a_max under the root
    assert f.all()
    lo = expect - (ref.TOL if solver == "qp" else 0.0)  # sampled bound may cut it one step short
    assert ((T >= lo - 1e-12) & (T <= expect + ref.TOL)).all(), (T, expect)


def test_qp_matches_closed_form_for_degree_5(batch):
    x0, xf, T, c, f = batch
    k = slice(0, 24)
    cq, fq = ref.min_jerk_qp(x0[k], xf[k], T[k])
    assert fq.all() and cq.shape == (24, 3, 6)
    # same polynomial: normalised coefficients within OSQP's tolerance (1e-6 of a_max T^2)
    np.testing.assert_allclose(scaled(cq, T[k]), scaled(c[k], T[k]), atol=1e-6)
    tk = np.linspace(0, 1, 50)[None] * T[k, None]
    for order in range(3):
        np.testing.assert_allclose(ref.evaluate(cq, tk, order), ref.evaluate(c[k], tk, order), atol=1e-5)
    # minimum time: equal, or one bisection step shorter (the QP bounds a at samples only)
    Tq, cq2, fq2 = ref.min_time(x0[k], xf[k], solver="qp")
    assert fq2.all()
    d = T[k] - Tq
    assert ((d == 0) | (np.abs(d - 0.015625) < 1e-12)).all(), d
    assert (d == 0).mean() >= 0.9
    exceed = ref.max_acceleration(cq2, Tq).max() / A_MAX - 1
    assert exceed < 1.2e-3  # Markov bound for 100 samples (module docstring)


def test_degree_7_is_no_worse_and_respects_samples(batch):
    x0, xf, T, c, f = batch
    k = slice(0, 6)
    c7, f7 = ref.min_jerk_qp(x0[k], xf[k], T[k], degree=7)
    assert f7.all() and c7.shape == (6, 3, 8)
    assert (ref.jerk_cost(c7, T[k]) <= ref.jerk_cost(c[k], T[k]) * (1 + 1e-6) + 1e-9).all()
    tau = np.arange(1, ref.N_SAMPLES + 1) / (ref.N_SAMPLES + 1)
    a = ref.evaluate(c7, tau[None] * T[k, None], 2)
    assert np.abs(a).max() <= A_MAX * (1 + 1e-5)
    for order in range(3):
        np.testing.assert_allclose(ref.evaluate(c7, T[k], order), xf[k][..., order], atol=1e-9)
        np.testing.assert_allclose(ref.evaluate(c7, 0.0, order), 0.0, atol=1e-12)
    # more freedom -> never slower; the answer is on Alg. 1's grid and feasible. (No claim
    # that T7 - tol is infeasible: near the minimum, degree-7 QPs can need more than
    # max_iter ADMM iterations, and a time-out counts as infeasible, as in Alg. 1.)
    T7, c7m, f7m = ref.min_time(x0[k], xf[k], solver="qp", degree=7)
    assert f7m.all() and (T7 <= T[k]).all() and (T7 < T[k]).any()
    np.testing.assert_array_equal(T7 * 64, np.round(T7 * 64))
    _, again = ref.min_jerk_qp(x0[k], xf[k], T7, degree=7)
    assert again.all()
    a = ref.evaluate(c7m, tau[None] * T7[:, None], 2)
    assert np.abs(a).max() <= A_MAX * (1 + 1e-5)


def test_infeasible_at_t_max_is_flagged_and_batch_independent():
    x0, xf = goal_states(4, 5)
    far = np.zeros((1, 3, 3))
    far[0, 0, 0] = 20.0  # rest-to-rest T_min = sqrt(5.774 * 20 / 5) = 4.8 s > 4 s
    hard = xf[:1].copy()
    hard[0, 1, 2] = 6.0  # end acceleration above a_max: infeasible at every T
    xs = np.concatenate([xf[:2], far, hard, xf[2:]])
    x0s = np.zeros_like(xs)
    for solver in ("closed-form", "qp"):
        T, c, f = ref.min_time(x0s, xs, solver=solver)
        np.testing.assert_array_equal(f, [True, True, False, False, True, True])
        assert (T[~f] == 4.0).all()
        # infeasible entries carry the unconstrained quintic at t_hi (meets the boundary conditions)
        np.testing.assert_allclose(ref.evaluate(c[~f], T[~f], 0), xs[~f][..., 0], atol=1e-9)
        # a reference's result does not depend on its batch (resampling relies on this)
        T1, c1, f1 = ref.min_time(x0[:1], xf[3:4], solver=solver)
        assert f1[0] and T1[0] == T[5]
        np.testing.assert_array_equal(c1[0], c[5])
    _, fq = ref.min_jerk_qp(x0s, xs, np.full(6, 4.0))
    np.testing.assert_array_equal(fq, [True, True, False, False, True, True])


def test_bad_inputs_raise_one_line_errors():
    x0, xf = goal_states(3, 6)
    c = ref.min_jerk_closed_form(x0, xf, 1.0)
    bad = [
        (lambda: ref.min_jerk_closed_form(x0[:, :2], xf, 1.0), "shape"),
        (lambda: ref.min_jerk_closed_form(x0, xf[:2], 1.0), "shape"),
        (lambda: ref.min_jerk_closed_form(x0 * np.nan, xf, 1.0), "NaN"),
        (lambda: ref.min_jerk_closed_form(x0, xf, 0.0), "positive"),
        (lambda: ref.min_jerk_closed_form(x0, xf, np.ones(2)), "shape"),
        (lambda: ref.min_jerk_qp(x0, xf, 1.0, degree=4), "degree"),
        (lambda: ref.min_jerk_qp(x0, xf, 1.0, n_samples=0), "n_samples"),
        (lambda: ref.min_jerk_qp(x0, xf, 1.0, a_max=-1.0), "a_max"),
        (lambda: ref.min_time(x0, xf, solver="ipopt"), "solver"),
        (lambda: ref.min_time(x0, xf, degree=7), "closed-form solver exists for degree 5"),
        (lambda: ref.min_time(x0, xf, t_lo=3.0, t_hi=2.0), "t_lo < t_hi"),
        (lambda: ref.min_time(x0, xf, tol=0.0), "tol"),
        (lambda: ref.evaluate(c, np.ones((2, 4))), "t must be"),
        (lambda: ref.evaluate(c, 0.0, order=-1), "order"),
        (lambda: ref.evaluate(c[0], 0.0), "coefficients"),
    ]
    for fn, match in bad:
        with pytest.raises(UserError, match=match) as e:
            fn()
        assert "\n" not in str(e.value)


def test_empty_batch():
    T, c, f = ref.min_time(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)))
    assert T.shape == (0,) and c.shape == (0, 3, 6) and f.shape == (0,)
