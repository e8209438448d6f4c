"""Discretisation: Van Loan's method and the white-noise process-noise matrices."""

from __future__ import annotations

import contextlib
import doctest
import io
from math import factorial

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad_vec
from scipy.linalg import expm

import gaussfuse as gf
from gaussfuse.models import noise
from gaussfuse.models.noise import continuous_white_noise, piecewise_white_noise, van_loan


def chain(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Drift and noise gain of a chain of `order` integrators driven at the top."""
    A = np.diag(np.ones(order), k=1)
    L = np.zeros(order + 1)
    L[-1] = 1.0
    return A, L


CV_CLOSED = lambda dt, q: q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])  # noqa: E731
CA_CLOSED = lambda dt, q: q * np.array([  # noqa: E731
    [dt**5 / 20, dt**4 / 8, dt**3 / 6],
    [dt**4 / 8, dt**3 / 3, dt**2 / 2],
    [dt**3 / 6, dt**2 / 2, dt],
])


@pytest.mark.parametrize("dt", [0.01, 0.3, 1.0, 2.5, 10.0])
@pytest.mark.parametrize(("order", "closed"), [(1, CV_CLOSED), (2, CA_CLOSED)], ids=["cv", "ca"])
def test_van_loan_matches_closed_forms(order, closed, dt):
    q = 0.7
    A, L = chain(order)
    F, Q = van_loan(A, L, q, dt)
    np.testing.assert_allclose(F, expm(A * dt), rtol=1e-12, atol=0)
    np.testing.assert_allclose(Q, closed(dt, q), rtol=1e-12, atol=0)
    # The closed form of the library says the same.
    np.testing.assert_allclose(continuous_white_noise(order, dt, q), closed(dt, q), rtol=1e-14, atol=0)


@pytest.mark.parametrize("order", [0, 1, 2, 3, 4])
def test_continuous_white_noise_is_van_loan_of_the_integrator_chain(order):
    dt, q = 1.7, 0.4
    A, L = chain(order)
    F, Q = van_loan(A, L, q, dt)
    np.testing.assert_allclose(continuous_white_noise(order, dt, q), Q, rtol=1e-12, atol=0)
    # F is the Taylor series of the position: F_ij = dt^(j-i) / (j-i)!.
    expected = np.array([[dt ** (j - i) / factorial(j - i) if j >= i else 0.0
                          for j in range(order + 1)] for i in range(order + 1)])
    np.testing.assert_allclose(F, expected, rtol=1e-13, atol=0)


def test_random_walk_order_zero():
    np.testing.assert_array_equal(continuous_white_noise(0, 2.0, 3.0), [[6.0]])
    np.testing.assert_array_equal(piecewise_white_noise(0, 2.0, 3.0), [[12.0]])


def singer_gain(s, tau):
    """e^{As} [0, 0, 1]ᵀ for the Singer drift, in closed form: how an acceleration impulse propagates."""
    e = np.exp(-s / tau)
    return np.array([tau**2 * (np.expm1(-s / tau) + s / tau), -tau * np.expm1(-s / tau), e])


@pytest.mark.parametrize("tau", [1e-3, 0.05, 1.0, 30.0])
@pytest.mark.parametrize("dt", [0.1, 1.0, 4.0])
def test_van_loan_matches_numerical_integration_for_singer(tau, dt):
    sigma = 1.3
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau]])
    Qc = 2 * sigma**2 / tau
    F, Q = van_loan(A, [0.0, 0.0, 1.0], Qc, dt)
    np.testing.assert_allclose(F, expm(A * dt), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(F[:, 2], singer_gain(dt, tau), rtol=1e-12, atol=1e-15)

    def integrand(s):
        g = singer_gain(s, tau)
        return Qc * np.outer(g, g)

    # Fast transients (short tau) are at the start of the interval: tell quad_vec.
    points = [k * tau for k in (1, 5, 20) if k * tau < dt] or None
    ref, err = quad_vec(integrand, 0.0, dt, epsabs=1e-15, epsrel=1e-13, points=points)
    scale = np.max(np.abs(ref))
    assert err < 1e-12 * scale
    np.testing.assert_allclose(Q, ref, rtol=0, atol=1e-10 * scale)
    assert scale > 1e-6  # not trivially small


@pytest.mark.parametrize("seed", range(4))
def test_van_loan_general_sde_matches_numerical_integration(seed):
    rng = np.random.default_rng(seed)
    n, s = 4, 2
    A = rng.normal(size=(n, n))
    L = rng.normal(size=(n, s))
    C = rng.normal(size=(s, s))
    Qc = C @ C.T
    dt = 0.8
    F, Q = van_loan(A, L, Qc, dt)
    np.testing.assert_allclose(F, expm(A * dt), rtol=1e-11, atol=1e-13)
    # e^{As} by eigendecomposition (cheap for quad_vec's many evaluations).
    lam, V = np.linalg.eig(A)
    Vinv = np.linalg.inv(V)
    assert np.linalg.cond(V) < 1e3
    W = L @ Qc @ L.T

    def integrand(t):
        E = ((V * np.exp(lam * t)) @ Vinv).real
        return E @ W @ E.T

    ref, err = quad_vec(integrand, 0.0, dt, epsabs=1e-15, epsrel=1e-13)
    assert err < 1e-12 * np.max(np.abs(ref))
    np.testing.assert_allclose(Q, ref, rtol=0, atol=1e-10 * np.max(np.abs(ref)))
    np.testing.assert_array_equal(Q, Q.T)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    dt1=st.floats(0.01, 3.0),
    dt2=st.floats(0.01, 3.0),
)
def test_van_loan_is_a_semigroup(seed, dt1, dt2):
    """Two steps of the exact discretisation are one longer step: F = F2 F1, Q = F2 Q1 F2ᵀ + Q2."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 3))
    L = rng.normal(size=(3, 1))
    F1, Q1 = van_loan(A, L, 0.5, dt1)
    F2, Q2 = van_loan(A, L, 0.5, dt2)
    F, Q = van_loan(A, L, 0.5, dt1 + dt2)
    scale_F = max(1.0, np.max(np.abs(F)))
    scale_Q = max(1.0, np.max(np.abs(Q)))
    np.testing.assert_allclose(F2 @ F1, F, rtol=0, atol=1e-10 * scale_F)
    np.testing.assert_allclose(F2 @ Q1 @ F2.T + Q2, Q, rtol=0, atol=1e-10 * scale_Q)
    assert np.min(np.linalg.eigvalsh(Q)) > -1e-12 * scale_Q


def test_van_loan_accepts_scalar_and_column_forms():
    F1, Q1 = van_loan([[0, 1], [0, 0]], [0, 1], 2.0, 0.5)
    F2, Q2 = van_loan(np.array([[0.0, 1.0], [0.0, 0.0]]), [[0.0], [1.0]], [[2.0]], 0.5)
    np.testing.assert_array_equal(F1, F2)
    np.testing.assert_array_equal(Q1, Q2)


@pytest.mark.parametrize("dt", [0.1, 1.0, 3.0])
@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_piecewise_white_noise_is_g_gT(order, dt):
    var = 0.9
    Q = piecewise_white_noise(order, dt, var)
    g = np.array([dt ** (order + 1 - i) / factorial(order + 1 - i) for i in range(order + 1)])
    np.testing.assert_allclose(Q, var * np.outer(g, g), rtol=1e-15, atol=0)
    assert np.linalg.matrix_rank(Q, tol=1e-12 * np.max(Q)) == 1
    if order == 1:  # the textbook form for constant velocity
        np.testing.assert_allclose(Q, var * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]),
                                   rtol=1e-15)


def test_piecewise_noise_is_the_effect_of_a_constant_highest_derivative():
    """Integrating a K-th derivative held at a over dt moves the state by g·a."""
    order, dt, a = 2, 0.7, 1.0
    A, L = chain(order + 1)  # augment the chain with the constant derivative
    x = expm(A * dt) @ np.r_[np.zeros(order + 1), a]
    Q = piecewise_white_noise(order, dt, 1.0)
    np.testing.assert_allclose(Q, np.outer(x[:-1], x[:-1]), rtol=1e-14)


def test_van_loan_is_exported():
    assert gf.van_loan is van_loan
    assert "van_loan" in gf.__all__


@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        (([[0, 1, 0]], [0, 1], 1.0, 1.0), ValueError, r"^`A` must be square, of shape \(n, n\); got shape \(1, 3\)\.$"),
        (([0, 1], [0, 1], 1.0, 1.0), ValueError, r"^`A` must have shape \(n, n\); got shape \(2,\)\.$"),
        ((np.zeros((2, 2, 2)), [0, 1], 1.0, 1.0), ValueError, r"^`A` must have shape \(n, n\)"),
        (([[0, 1], [0, 0]], [0, 1, 2], 1.0, 1.0), ValueError, r"^`L` must have shape \(2, s\); got shape \(3,\)\.$"),
        (([[0, 1], [0, 0]], [0, 1], [1.0, 2.0], 1.0), ValueError, r"^`Qc` must have shape \(1, 1\); got shape \(2,\)\.$"),
        (([[0, 1], [0, 0]], [0, 1], -1.0, 1.0), ValueError, r"^`Qc` must be positive semi-definite"),
        (([[0, 1], [0, 0]], [[0, 1], [1, 0]], [[1, 2], [0, 1]], 1.0), ValueError, r"^`Qc` must be symmetric"),
        (([[0, 1], [0, np.nan]], [0, 1], 1.0, 1.0), ValueError, r"^`A` must be finite"),
        (([[0, 1], [0, 0]], "L", 1.0, 1.0), TypeError, r"^`L` must be an array of numbers; got str\.$"),
        (([[0, 1], [0, 0]], [0, 1], 1.0, 0.0), ValueError, r"^`dt` must be a positive number; got 0\.0\.$"),
        (([[0, 1], [0, 0]], [0, 1], 1.0, -1), ValueError, r"^`dt` must be a positive number; got -1\.0\.$"),
        (([[0, 1], [0, 0]], [0, 1], 1.0, "1"), TypeError, r"^`dt` must be a positive number; got '1'\.$"),
    ],
)
def test_van_loan_validation(args, error, match):
    with pytest.raises(error, match=match):
        van_loan(*args)


@pytest.mark.parametrize("fn", [continuous_white_noise, piecewise_white_noise])
@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        ((-1, 1.0, 1.0), ValueError, r"^`order` must be a non-negative integer; got -1\.$"),
        ((1.0, 1.0, 1.0), TypeError, r"^`order` must be a non-negative integer; got 1\.0\.$"),
        ((True, 1.0, 1.0), TypeError, r"^`order` must be a non-negative integer; got True\.$"),
        ((1, 0.0, 1.0), ValueError, r"^`dt` must be a positive number; got 0\.0\.$"),
        ((1, np.inf, 1.0), ValueError, r"^`dt` must be a positive number; got inf\.$"),
        ((1, None, 1.0), TypeError, r"^`dt` must be a positive number; got None\.$"),
    ],
)
def test_white_noise_validation(fn, args, error, match):
    with pytest.raises(error, match=match):
        fn(*args)


def test_white_noise_intensity_validation():
    with pytest.raises(ValueError, match=r"^`q` must be a non-negative number; got -1\.0\.$"):
        continuous_white_noise(1, 1.0, -1.0)
    with pytest.raises(ValueError, match=r"^`var` must be a non-negative number; got nan\.$"):
        piecewise_white_noise(1, 1.0, np.nan)
    with pytest.raises(TypeError, match=r"^`var` must be a non-negative number; got \[1\.0\]\.$"):
        piecewise_white_noise(1, 1.0, [1.0])


def test_docstring_examples():
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = doctest.testmod(noise, optionflags=doctest.NORMALIZE_WHITESPACE, report=True)
    assert result.attempted >= 3
    assert result.failed == 0, out.getvalue()


def _mp_van_loan(A, w, dt, digits=60):
    """F and Q of dx = A x dt + w dβ (E dβ² = dt) from mpmath's exponential of Van Loan's block matrix, `digits` digits."""
    mp = pytest.importorskip("mpmath")
    with mp.workdps(digits):
        n = len(A)
        M = mp.zeros(2 * n, 2 * n)
        for i in range(n):
            for j in range(n):
                M[i, j] = -mp.mpf(A[i][j])
                M[i, n + j] = mp.mpf(w[i]) * mp.mpf(w[j])
                M[n + i, n + j] = mp.mpf(A[j][i])
        E = mp.expm(M * mp.mpf(dt))
        F = mp.matrix(n, n)
        G = mp.matrix(n, n)
        for i in range(n):
            for j in range(n):
                F[i, j] = E[n + j, n + i]
                G[i, j] = E[i, n + j]
        Q = F * G
        return (np.array([[float(F[i, j]) for j in range(n)] for i in range(n)]),
                np.array([[float(Q[i, j]) for j in range(n)] for i in range(n)]))


@pytest.mark.parametrize("sigma", [1.0, 1e8, 1e12, 1e20])
def test_a_large_noise_density_leaves_f_and_the_relative_accuracy_of_q(sigma):
    """The block matrix's exponential (scipy's expm) was accurate relative to its norm, which a large W set: Singer
    with sigma = 1e12 had F off by 1.7e-2, and at 1e20 Q[0, 0] = -8.4e47 for +3.8e38. F does not depend on W and Q
    is linear in it: against the 60-digit exponential at sigma = 1, every entry to 1e-14 of itself."""
    tau, dt = 2.0, 1.0
    A = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau]]
    F_ref, Q_ref = _mp_van_loan(A, [0.0, 0.0, np.sqrt(2.0 / tau)], dt)
    F, Q = gf.Singer(tau=tau, sigma=sigma).transition(dt)
    np.testing.assert_allclose(F, F_ref, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(Q / sigma**2, Q_ref, rtol=1e-14, atol=0)


@pytest.mark.parametrize("dt", [0.1, 0.01, 1e-3])
@pytest.mark.parametrize("order", [3, 5])
def test_a_short_step_keeps_every_entry_of_q(order, dt):
    """expm's low-degree Padé approximant (a norm below 0.015) lost Q's small entries: a chain of 4 integrators at
    dt = 0.01 had Q[0, 0] off by 2.5e-3 and the position's variance given the rest 1.2e-32 for 9.9e-20 (a negative
    eigenvalue). Against the closed form (a chain) and a damped chain's 60-digit exponential, entry by entry."""
    A, L = chain(order)
    F, Q = van_loan(A, L, 2.0, dt)
    np.testing.assert_allclose(Q, continuous_white_noise(order, dt, 2.0), rtol=1e-14, atol=0)
    damped = A.copy()
    damped[-1, -1] = -3.0
    F_ref, Q_ref = _mp_van_loan(damped.tolist(), L.tolist(), dt)
    F, Q = van_loan(damped, L, 1.0, dt)
    np.testing.assert_allclose(F, F_ref, rtol=1e-14, atol=0)
    np.testing.assert_allclose(Q, Q_ref, rtol=1e-13, atol=0)
    rest = slice(1, order + 1)  # the position's variance given the derivatives: a Schur complement
    given = Q[0, 0] - Q[0, rest] @ np.linalg.solve(Q[rest, rest], Q[rest, 0])
    want = Q_ref[0, 0] - Q_ref[0, rest] @ np.linalg.solve(Q_ref[rest, rest], Q_ref[rest, 0])
    assert given > 0 and abs(given - want) <= 1e-6 * want


def test_a_drift_past_2_to_the_1024_per_step_is_stepped():
    """dt / 2.0**halvings raised OverflowError (reported as a step too long) for ||A|| dt past 2**1024: a rate of
    1e200 over 1e109 s has F = exp(-1e309) = 0 and Q = q / (2 rate) (1 - exp(-2e309)) = q / 2e200. (It was Singer
    at tau = 1e-300, then at tau = 1e-200: Singer refuses tau below 1e-150 since review R46, and a Singer that
    takes this path has Q past float64 unless sigma is 0.)"""
    F, Q = van_loan([[-1e200]], [1.0], 1e100, 1e109)
    assert F[0, 0] == 0.0
    assert Q[0, 0] == pytest.approx(5e-101, rel=1e-12, abs=0.0)


def test_a_huge_density_over_a_step_whose_q_is_finite_is_not_refused():
    """q dt^5 was formed before dividing by 20: ConstantAcceleration(q=1e308) over 1.5 s was "a step too long",
    where Q[0, 0] = q 1.5^5 / 20 = 3.8e307."""
    Q = gf.ConstantAcceleration(q=1e308).transition(1.5)[1]
    assert Q[0, 0] == pytest.approx(1e308 * (1.5**5 / 20), rel=1e-14)


def test_a_tiny_intensity_over_a_huge_step_is_not_an_overflow():
    """q = 1e-300 over dt = 1e110: Q = q dt³/3 = 3.3e29 is finite, but dt³ was computed first and overflowed, and
    the error blamed the step (audit M); it is taken in logarithms there. 171! overflowing was blamed on dt = 1."""
    _, Q = gf.ConstantVelocity(q=1e-300).transition(1e110)[:2]
    np.testing.assert_allclose(Q, [[1e-300 * 1e110**2 * 1e110 / 3, 5e-81], [5e-81, 1e-190]], rtol=1e-13)
    assert np.array_equal(continuous_white_noise(1, 2.0, 3.0), [[8.0, 6.0], [6.0, 6.0]])  # exact where no overflow
    for fn in (continuous_white_noise, piecewise_white_noise):
        with pytest.raises(ValueError, match=r"^`order` must be at most 170"):
            fn(171, 1.0, 1.0)
    with pytest.raises(ValueError, match=r"a step of dt = 1e\+200 s is too long for ConstantVelocity"):
        gf.ConstantVelocity(q=1.0).transition(1e200)


@pytest.mark.parametrize("order, dt, q", [(100, 20.0, 1.0), (170, 10.0, 1.0), (99, 1.0, 1.0), (2, 1e-66, 1e60),
                                         (1, 2.5e-108, 1e300), (50, 1e-5, 1e100)])
def test_white_noise_chains_keep_entries_whose_factors_overflow_or_underflow(order, dt, q):
    """Order 100 gave Q = 0 for 1.8e-57: (K - i)! (K - j)! overflowed (past order 98, though orders to 170 are
    accepted); dt^5 = 1e-330 underflowed before q = 1e60 scaled it (audit S). Against exact rationals."""
    from fractions import Fraction

    Q = continuous_white_noise(order, dt, q)
    for i, j in ((0, 0), (0, 1), (order, order)):
        p = 2 * order + 1 - i - j
        exact = Fraction(q) * Fraction(dt) ** p / (p * factorial(order - i) * factorial(order - j))
        assert Q[i, j] == pytest.approx(float(exact), rel=1e-12, abs=0.0), (i, j)


@pytest.mark.parametrize("fn", [continuous_white_noise, piecewise_white_noise])
def test_white_noise_entries_are_correct_to_a_few_ulps_at_any_scale_and_exactly_symmetric(fn):
    """Entries rescued from an overflowing or underflowing factor were exp(log) of them, off by 1e-13 at
    q = 1e300 (about 2,000 ulps); order 22 was not symmetric by an ulp; q = 0 over a long step was NaN, "a step
    too long" (audit BB1). Against exact rationals, every entry of a grid of orders, steps and intensities."""
    from fractions import Fraction

    rng = np.random.default_rng(5)
    tiny = np.finfo(np.float64).tiny
    worst = 0.0
    for order in (0, 1, 2, 3, 7, 22, 60, 98, 170):
        for dt in (1e-100, 2.5e-8, 0.1, 1.0, 3.7, 1e4, 1e50):
            for q in (1e-300, 0.37, 1.0, 1e100, 1e300):
                dt_ = dt * (1.0 + 0.1 * rng.random())
                with contextlib.suppress(ValueError):  # a Q past 1e308: refused, as a step too long
                    Q = fn(order, dt_, q)
                    assert np.array_equal(Q, Q.T), (order, dt_, q)
                    for i, j in {(0, 0), (0, order), (order // 2, order), (order, order)}:
                        if fn is continuous_white_noise:
                            p = 2 * order + 1 - i - j
                            exact = Fraction(q) * Fraction(dt_) ** p / (p * factorial(order - i) * factorial(order - j))
                        else:
                            gi, gj = (Fraction(dt_) ** (order + 1 - k) / factorial(order + 1 - k) for k in (i, j))
                            exact = Fraction(q) * gi * gj
                        if exact >= Fraction(tiny) and exact < Fraction(1e308):  # (subnormal results: below)
                            worst = max(worst, abs(float((Fraction(Q[i, j]) - exact) / exact)))
                        elif exact < Fraction(tiny):
                            assert abs(Fraction(Q[i, j]) - exact) <= Fraction(5e-324) * 4, (order, dt_, q, i, j)
    assert worst < 1e-15, worst  # (it was 1.6e-13)
    assert np.array_equal(fn(2, 1e100, 0.0), np.zeros((3, 3)))


def _van_loan_in_digits(A, W, dt, digits=100):
    """F and Q of van_loan's block exponential in `digits` significant digits (mpmath), rounded to float64."""
    import mpmath as mp

    n = A.shape[0]
    with mp.workdps(digits):
        M = mp.matrix(2 * n, 2 * n)
        for i in range(n):
            for j in range(n):
                M[i, j] = -mp.mpf(A[i, j]) * dt
                M[i, n + j] = mp.mpf(W[i, j]) * dt
                M[n + i, n + j] = mp.mpf(A[j, i]) * dt
        E = mp.expm(M)
        Phi = mp.matrix([[E[n + j, n + i] for j in range(n)] for i in range(n)])
        G = mp.matrix([[E[i, n + j] for j in range(n)] for i in range(n)])
        Q = Phi * G
        return (np.array([[float(Phi[i, j]) for j in range(n)] for i in range(n)]),
                np.array([[float(Q[i, j]) for j in range(n)] for i in range(n)]))


@pytest.mark.parametrize("A, W, dt, was", [
    (np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1e-9]]), np.diag([0.0, 0.0, 2e-9]), 1e9, 7.4e-9),
    (np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1e-4]]), np.diag([0.0, 0.0, 2e-4]), 1e4, 1.2e-12),
    (np.array([[-1e-3, 1e6], [0.0, -2e-3]]), np.eye(2), 1e3, 1.5e-8),
    (np.array([[0.0, 1e3], [-4e-3, -0.1]]), np.diag([0.0, 1.0]), 10.0, 1.7e-12),
], ids=["singer-1e9", "singer-1e4", "triangular-mixed-units", "oscillator-mixed-units"])
def test_a_coupling_is_not_a_rate(A, W, dt, was):
    """The halvings were set by ||A||_1, which counts a coupling (an integrator's 1, a change of units) as a rate:
    Singer's model at tau = dt = 1e9 s was 7.4e-9 off in F and Q after 31 squarings (audit BB1). Al-Mohy and
    Higham's alpha (powers of A) leaves it to the rates. Against a 100-digit block exponential, entry by entry."""
    F, Q = van_loan(A, np.eye(A.shape[0]), W, dt)
    F_exact, Q_exact = _van_loan_in_digits(A, W, dt)
    worst = max(np.max(np.abs(got - exact)[exact != 0] / np.abs(exact[exact != 0]))
                for got, exact in ((F, F_exact), (Q, Q_exact)))
    assert worst < 5e-14, (worst, was)


def test_a_chain_of_integrators_is_not_halved():
    """Its powers end: alpha is 0, and its series is summed over the whole step (the second zero power was not
    formed, and a chain of every order took log2(dt) + 1 halvings: review R19)."""
    for k in range(1, 9):
        assert noise._rate(np.diag(np.ones(k), 1)) == 0.0
    assert noise._rate(np.diag(np.ones(9), 1)) == 1.0  # its 10th power is 0: past the 9 formed
    assert noise._rate(np.zeros((3, 3))) == 0.0 and noise._rate(np.array([[-2.0]])) == 2.0
    # summed over the whole step, a term near the largest float overflowed before its division (review R20)
    from fractions import Fraction

    for order, dt, q in ((3, 1e30, 1e100), (1, 1e100, 2.9e7), (8, 1e17, 1e28)):
        F, Q = van_loan(*chain(order), q, dt)
        exact = Fraction(q) * Fraction(dt) ** (2 * order + 1) / ((2 * order + 1) * factorial(order) ** 2)
        assert float(exact) > 1e306 and Q[0, 0] == pytest.approx(float(exact), rel=1e-14), (order, Q[0, 0])


@pytest.mark.parametrize("A, dt", [(np.array([[0.0, 1.0], [-4.0, -0.4]]), 1e3), (np.array([[0.0, 1e8], [-1e-8, 0.0]]), 1e-3),
                                   (np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]), 1e3)])
@pytest.mark.parametrize("q", [1e-320, 1e-310])
def test_a_subnormal_density_keeps_its_digits(A, dt, q):
    """A subnormal W lost digits in the series, which divides each term (80 ulps at q = 1e-320; 1e-10 relative
    on a normal Q = 3.3e-304: review R21). Q is linear in W: it is scaled by a power of 2 and back. Against a
    700-digit block exponential of the float W."""
    n = A.shape[0]
    W = np.zeros((n, n))
    W[-1, -1] = q
    Q = van_loan(A, np.eye(n), W, dt)[1]
    exact = _van_loan_in_digits(A, W, dt, digits=700)[1]  # (e^{1000} meets e^{-1000} in the block exponential)
    assert np.all(np.abs(Q - exact) <= 2 * 5e-324 + 1e-13 * np.abs(exact)), (Q, exact)


@pytest.mark.parametrize("a, dt, L, Qc", [(-0.01, 1.0, 1e250, 1e-310), (1.0, 600.0, 1.0, 1e-310),
                                         (0.5, 100.0, 1e-160, 1.0), (1e6, 5e-4, 1.0, 3e-308), (1e6, 5e-4, 1.0, 1e-320),
                                         (1.0, 700.0, 1e-165, 1.0), (1e25, 3e-23, 1.0, 1e-320),  # (review R23)
                                         (1000.0, 0.692706, 1e-175, 1.0), (1000.0, 0.692706, 1e-180, 1.0),
                                         (1.0, 700.0, 1e-180, 1.0), (1.0, 500.0, 1e-305, 1e-5),  # (review R24)
                                         (8.02e14, 7.97e-13, 1.0, 7e-306), (1e25, 6e-23, 1.0, 1e-310),
                                         (1494.6, 0.4729, -8.56e-106, 5.6e-97),  # (review R25)
                                         (1e3, 0.7025, 1.0, 1e-320), (1e3, 0.704, 1.0, 1e-320)])  # (review R26)
def test_a_small_density_is_scaled_only_as_far_as_its_q_allows(a, dt, L, Qc):
    """A subnormal Qc was scaled up by 2**600 whatever L and the growth: Q = 9.9e189 and 7.1e210 overflowed
    ("a step too long"), while W subnormal by a tiny L, or a Qc just above the subnormals, lost 5e-4 and 1e-9
    (review R22). Against the closed form of a scalar drift, Q = W (e^{2 a dt} - 1) / (2 a), in 60 digits."""
    import mpmath as mp

    Q = van_loan([[a]], [[L]], Qc, dt)[1][0, 0]
    with mp.workdps(60):
        exact = mp.mpf(L) ** 2 * mp.mpf(Qc) * mp.expm1(2 * mp.mpf(a) * mp.mpf(dt)) / (2 * mp.mpf(a))
    assert Q == pytest.approx(float(exact), rel=1e-14 * max(1.0, 2 * abs(a) * dt), abs=0.0)  # (the Notes' eps alpha dt)


def test_a_density_and_a_growth_beyond_float64s_range_are_refused_not_zero():
    """W = 1e-330 grown to 5e309, or to 1e301 (more than float64 spans from W), came back as Q = 0, silently, from
    the retry without scaling, where W underflows (review R23); at fast rates, tries whose W h had underflowed
    gave 0 or 4.8% for Q = 1e265 to 1e288 (review R27)."""
    for dt in (7e34, 6.9e34):
        with pytest.raises(ValueError, match="too long for van_loan"):
            van_loan([[1e-32]], [[1e-165]], 1.0, dt)
    for a, dt, q in ((1e25, 7.0264e-23, 1e-320), (1e20, 7.0264e-18, 1e-320), (1e25, 7.0264e-23, 1e-305),
                     (1e20, 7.0264e-18, 1e-302)):
        with pytest.raises(ValueError, match="too long for van_loan"):
            van_loan([[a]], [[1.0]], q, dt)


def test_a_stiff_drift_loses_its_slow_mode_as_documented():
    """van_loan's Notes: rates 1e9 and 1e-3 over 1e4 s leave the slow mode's F 4.5e-8 off; rates 1e12 and 1e-4
    over 1e5 s lose it (F = 1 for 4.5e-5, Q = 1e5 for 5000). A rate is a rate: alpha is the fastest one here."""
    F = van_loan(np.diag([-1e9, -1e-3]), np.eye(2), np.eye(2), 1e4)[0]
    assert abs(F[1, 1] / np.exp(-10.0) - 1) == pytest.approx(4.5e-8, rel=0.01)
    F, Q = van_loan(np.diag([-1e12, -1e-4]), np.eye(2), np.eye(2), 1e5)
    assert (F[1, 1], Q[1, 1]) == (1.0, 1e5)


def test_piecewise_noise_keeps_entries_whose_g_g_t_underflows():
    """g gᵀ = (dt³/6)² underflowed before var = 1e100 scaled it: 0 for 2.8e-262 (audit S); g itself underflowed
    (dt = 1e-100), or overflowed before a tiny var scaled it (dt = 1e100, var = 1e-300: a "step too long" for an
    exact 2.5e99), audit R5."""
    from fractions import Fraction

    for K, dt, var in ((2, 1e-60, 1e100), (3, 1e-100, 1e200), (1, 1e100, 1e-300), (3, 1e50, 1e-100)):
        Q = piecewise_white_noise(K, dt, var)
        g = [Fraction(dt) ** (K + 1 - i) / factorial(K + 1 - i) for i in range(K + 1)]
        for i in range(K + 1):
            for j in range(K + 1):
                exact = float(Fraction(var) * g[i] * g[j])
                assert Q[i, j] == pytest.approx(exact, rel=1e-12, abs=1e-320), (K, dt, var, i, j)
    assert np.array_equal(piecewise_white_noise(1, 2.0, 0.5), [[2.0, 2.0], [2.0, 2.0]])  # exact where nothing underflows


def test_a_fast_rate_before_an_integrator_loses_the_integrators_variance_as_documented():
    """van_loan's notes: with A = [[0, 1], [0, -1e110]] and W = 1 over 1 s the position variance, W/a² (1 - ...)
    about 1e-220, comes out 0 (its sub-step's W h³ underflows), while the velocity's entries are exact; at a rate
    of 1e50 it is exact too."""
    a = 1e110
    F, Q = gf.van_loan(np.array([[0.0, 1.0], [0.0, -a]]), [0.0, 1.0], 1.0, 1.0)
    assert Q[0, 0] == 0.0
    np.testing.assert_allclose([Q[0, 1], Q[1, 1]], [0.5 / a**2, 0.5 / a], rtol=1e-14)
    a = 1e50
    F, Q = gf.van_loan(np.array([[0.0, 1.0], [0.0, -a]]), [0.0, 1.0], 1.0, 1.0)
    np.testing.assert_allclose(Q, [[(1.0 - 1.5 / a) / a**2, 0.5 / a**2], [0.5 / a**2, 0.5 / a]], rtol=1e-14)
