"""The linear algebra of covariances: factorisations, solves, log-densities, angles."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

import _oracle
import gaussfuse as gf
from gaussfuse import _linalg


def test_cholesky_names_the_matrix():
    with pytest.raises(np.linalg.LinAlgError, match=r"^`P` is not positive definite"):
        _linalg.cholesky(np.array([[1.0, 2.0], [2.0, 1.0]]), "`P`")
    L = _linalg.cholesky(np.array([[4.0, 2.0], [2.0, 5.0]]), "`P`")
    np.testing.assert_allclose(L @ L.T, [[4.0, 2.0], [2.0, 5.0]], rtol=1e-15)


@pytest.mark.parametrize("g", [[0.7, 0.1], [1.3, 1.7], [0.35, 0.4]])
def test_a_resolved_cholesky_refuses_a_pivot_of_round_off(g):
    """g gᵀ is singular, yet LAPACK factors these roundings of it, with a second pivot of 2e-9 to 2e-8 (√ε of
    the row, no digit right); with `resolved` that pivot is zero, as semidefinite_cholesky's test has it."""
    M = np.outer(g, g)
    L = _linalg.cholesky(M)
    assert 0.0 < L[1, 1] ** 2 <= 2 * np.finfo(float).eps * M[1, 1] and _linalg.roundoff_pivot(L, M)
    with pytest.raises(np.linalg.LinAlgError, match="S is not positive definite, so it cannot be factorised"):
        _linalg.cholesky(M, "S", resolved=True)
    near = M + np.diag([0.0, 1e-13 * M[1, 1]])  # a pivot² of 1e-13 of its row, ε of it off (0.2%)
    L = _linalg.cholesky(near, resolved=True)
    assert L[1, 1] ** 2 == pytest.approx(1e-13 * M[1, 1], rel=1e-2, abs=0.0)
    stack = np.stack([np.eye(2), M])
    assert _linalg.roundoff_pivot(_linalg.cholesky(stack), stack)
    with pytest.raises(np.linalg.LinAlgError):
        _linalg.cholesky(stack, resolved=True)


# ---------------------------------------------------------------------------
# predict
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# semidefinite_cholesky
# ---------------------------------------------------------------------------


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4), rank=st.integers(0, 4))
def test_semidefinite_cholesky(seed, n, rank):
    """L Lᵀ = cov, lower triangular, a column of round-off at most for each component that depends on earlier ones.

    A pivot of exactly 0 gives a zero column; one of round-off may stay, at
    about its square root (1e-7 here), which is harmless (see the next test).
    """
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((n, min(rank, n)))
    cov = B @ B.T
    L = _linalg.semidefinite_cholesky(cov)
    np.testing.assert_array_equal(L, np.tril(L))
    np.testing.assert_allclose(L @ L.T, cov, atol=1e-12 * max(1.0, np.abs(cov).max()))
    assert np.count_nonzero(np.diag(L) > 1e-6 * np.sqrt(np.diag(cov))) == min(rank, n)
    exact = np.diag(np.arange(n) % 2 * 1.0)  # every other component known exactly: exact zero columns
    np.testing.assert_array_equal(np.diag(_linalg.semidefinite_cholesky(exact)) > 0, np.diag(exact) > 0)
    # On a positive definite matrix it is the Cholesky factor.
    spd = cov + np.eye(n)
    np.testing.assert_allclose(_linalg.semidefinite_cholesky(spd), np.linalg.cholesky(spd), rtol=1e-12, atol=1e-12)


def test_semidefinite_cholesky_is_continuous_at_a_round_off_pivot():
    """A pivot of round-off, of either sign, moves one column by about its square root: nothing else."""
    base = np.array([[4.0, 2.0, 1.0], [2.0, 1.0, 0.5], [1.0, 0.5, 3.0]])  # x1 = x0 / 2: pivot 0
    for pivot in (0.0, -1e-16, 1e-16):
        cov = base.copy()
        cov[1, 1] += pivot
        try:
            L = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            L = _linalg.semidefinite_cholesky(cov)
        np.testing.assert_allclose(np.delete(L, 1, axis=1), np.delete(_linalg.semidefinite_cholesky(base), 1, axis=1),
                                   atol=1e-15)
        assert L[1, 1] < 1e-7 and np.all(np.abs(L[:, 1]) < 1e-7)
    with pytest.raises(np.linalg.LinAlgError, match="not positive semi-definite"):
        _linalg.semidefinite_cholesky(np.array([[1.0, 2.0], [2.0, 1.0]]))


def test_log_density_equals_scipy():
    rng = np.random.default_rng(1)
    C = _oracle.random_spd(rng, 3)
    mean, x = rng.normal(size=3), rng.normal(size=(4, 3))
    L = _linalg.cholesky(C)
    got = _linalg.log_density(_linalg.whiten(L, (x - mean).T).T, L)
    np.testing.assert_allclose(got, stats.multivariate_normal(mean, C).logpdf(x), rtol=1e-12)


def test_cho_solve_and_psd_solve():
    rng = np.random.default_rng(2)
    C, B = _oracle.random_spd(rng, 4), rng.normal(size=(4, 2))
    np.testing.assert_allclose(C @ _linalg.cho_solve(_linalg.cholesky(C), B), B, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(_linalg.psd_solve(C, B), np.linalg.solve(C, B), rtol=1e-10)
    stack = np.stack([C, 2 * C])
    np.testing.assert_allclose(_linalg.cho_solve(_linalg.cholesky(stack), B), np.linalg.solve(stack, B), rtol=1e-10)
    # singular: the minimum-norm solution on the range
    S = np.diag([2.0, 0.0])
    np.testing.assert_allclose(_linalg.psd_solve(S, np.array([[4.0], [0.0]])), [[2.0], [0.0]])


@pytest.mark.parametrize("seed", range(20))
def test_triangular_solves_keep_each_row_on_its_own_scale(seed):
    """whiten, back_substitute and cho_solve substitute row by row, as scipy's triangular solves do: they used
    LAPACK's LU solve, which exchanged rows where an entry below the diagonal was larger than the pivot; with
    rows on scales 1e17 apart (a factor [[2.2e-20, 0], [8.2e-18, 0.38]]) it lost every digit of the small one."""
    from scipy.linalg import solve_triangular
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 6))
    scales = 10.0 ** rng.uniform(-20, 20, size=n)
    L = np.tril(rng.standard_normal((n, n))) * scales[:, None]  # each row on its own scale
    L[np.diag_indices(n)] = np.abs(np.diag(L)) * 10.0 ** rng.uniform(-4, 0, size=n)  # pivots below the entries
    X = rng.standard_normal((n, 3)) * scales[:, None]
    want = solve_triangular(L, X, lower=True)
    np.testing.assert_allclose(_linalg.whiten(L, X), want, rtol=1e-10)
    np.testing.assert_allclose(_linalg.whiten(L, X[:, 0]), want[:, 0], rtol=1e-10)
    np.testing.assert_allclose(_linalg.whiten(np.stack([L, L]), np.stack([X, X]))[1], want, rtol=1e-10)
    back = solve_triangular(L, want, lower=True, trans="T")
    np.testing.assert_allclose(_linalg.back_substitute(L, want), back, rtol=1e-10)
    np.testing.assert_allclose(_linalg.cho_solve(L, X), back, rtol=1e-10)
    np.testing.assert_allclose(_linalg.cho_solve(np.stack([L, L]), np.stack([X, X]))[0], back, rtol=1e-10)
    # a stack of factors and one vector: each factor's solve (it was taken as one (k, r) matrix after the first)
    for T in (n, n + 1):
        stack = np.stack([L * (t + 1.0) for t in range(T)])
        np.testing.assert_allclose(_linalg.cho_solve(stack, X[:, 0]), [back[:, 0] / (t + 1.0) ** 2 for t in range(T)],
                                   rtol=1e-10)


def test_observed_gram_over_the_observed_components():
    rng = np.random.default_rng(3)
    S = np.stack([_oracle.random_spd(rng, 3) for _ in range(3)])
    X = rng.normal(size=(3, 3, 2))
    observed = np.array([[True, True, True], [True, False, True], [False, False, False]])
    gram, logdet = _linalg.observed_gram(S, X, observed)
    np.testing.assert_allclose(gram[0], X[0].T @ np.linalg.solve(S[0], X[0]), rtol=1e-10)
    o = observed[1]
    np.testing.assert_allclose(gram[1], X[1][o].T @ np.linalg.solve(S[1][np.ix_(o, o)], X[1][o]), rtol=1e-10)
    np.testing.assert_array_equal(gram[2], 0.0)
    np.testing.assert_allclose(logdet[:2], [np.linalg.slogdet(S[0])[1], np.linalg.slogdet(S[1][np.ix_(o, o)])[1]])
    with pytest.raises(np.linalg.LinAlgError, match="at step 1: S is not positive definite"):
        bad = S.copy()
        bad[1] = -np.eye(3)
        _linalg.observed_gram(bad, X, observed, "S")


def test_wrap_angle_and_circular_mean():
    np.testing.assert_allclose(_linalg.wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi / 2])), [-np.pi, -np.pi, -np.pi / 2])
    # just below -π, (a + π) mod 2π rounded to 2π, which gave +π: outside [-π, π) (4.5% of such angles)
    below = -np.pi - np.random.default_rng(0).uniform(0.0, 1e-12, 10_000)
    below[0] = np.nextafter(-np.pi, -np.inf)
    for a in (below, below + 2 * np.pi, below - 4 * np.pi):
        w = _linalg.wrap_angle(a)
        assert (w >= -np.pi).all() and (w < np.pi).all()
        np.testing.assert_allclose(np.exp(1j * w), np.exp(1j * a), atol=1e-11)  # the same angle
    assert _linalg.wrap_angle(float(below[0])) == -np.pi
    assert _linalg.wrap_angle(np.float32([4.0, -np.pi])).dtype == np.float32  # (a float64 array, for a while)
    assert np.ndim(_linalg.wrap_angle(3.5)) == 0
    mean = _linalg.circular_mean(np.array([[np.pi - 0.1], [-np.pi + 0.1]]), np.array([0.5, 0.5]))
    assert abs(abs(mean[0]) - np.pi) < 1e-12  # the mean of 179° and -179° is 180°, not 0°


# ---------------------------------------------------------------------------
# tria
# ---------------------------------------------------------------------------


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(1, 6), st.integers(1, 9), st.integers(0, 2**32 - 1), st.sampled_from([1.0, 1e-150, 1e150]),
       st.booleans())
def test_tria_is_a_lower_triangular_root_of_M_Mt(n, k, seed, scale, zero_row):
    """L lower triangular, diagonal >= 0, L Lᵀ = M Mᵀ to round-off; fewer columns than rows, zero rows, any scale."""
    rng = np.random.default_rng(seed)
    M = scale * rng.normal(size=(n, k))
    if zero_row:
        M[rng.integers(n)] = 0.0
    L = _linalg.tria(M)
    assert L.shape == (n, n)
    assert np.array_equal(L, np.tril(L)) and (np.diagonal(L) >= 0).all()
    G = M @ M.T
    np.testing.assert_allclose(L @ L.T, G, rtol=0, atol=1e-13 * np.abs(G).max())


def test_tria_of_a_positive_definite_root_is_its_cholesky_factor():
    P = _oracle.random_spd(np.random.default_rng(1), 4)
    C = np.linalg.cholesky(P)
    Qm = np.linalg.qr(np.random.default_rng(2).normal(size=(4, 4)))[0]
    np.testing.assert_allclose(_linalg.tria(C @ Qm), C, rtol=1e-12, atol=1e-14)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(1, 6), st.integers(1, 3), st.integers(0, 2**32 - 1), st.sampled_from([1.0, 1e-150, 1e150]),
       st.floats(0.0, 0.95))
def test_downdate_is_a_lower_triangular_root_of_L_Lt_minus_V_Vt(n, r, seed, scale, size):
    """Any scale; V taking away up to 95% of the smallest eigenvalue's worth; a zero variance is left exactly zero."""
    rng = np.random.default_rng(seed)
    L = _linalg.tria(scale * rng.normal(size=(n, n + 2)))
    P = L @ L.T
    # columns of V inside the ellipse: V Vᵀ ≤ size · P, so L Lᵀ - V Vᵀ stays positive definite
    V = L @ rng.normal(size=(n, r))
    V *= np.sqrt(size) / max(np.linalg.norm(np.linalg.solve(L, V), 2), 1e-300)
    D = _linalg.downdate(L, V)
    assert np.array_equal(D, np.tril(D)) and (np.diagonal(D) >= 0).all()
    G = P - V @ V.T
    np.testing.assert_allclose(D @ D.T, G, rtol=0, atol=1e-12 * np.abs(P).max())
    # (the oracle, a Cholesky factorisation of the difference, when it exists)
    if size < 0.9:
        np.testing.assert_allclose(D, np.linalg.cholesky(G), rtol=1e-6, atol=1e-9 * np.sqrt(np.abs(P).max()))


def test_downdate_leaves_untouched_components_and_refuses_an_indefinite_result():
    L = np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.3, 1.0]])  # the second component: exactly the first's half
    V = np.array([[1.0], [0.5], [0.2]])
    D = _linalg.downdate(L, np.array([[0.0], [0.0], [0.5]]))
    np.testing.assert_array_equal(D[:2], L[:2])
    np.testing.assert_allclose(D @ D.T, L @ L.T - np.diag([0.0, 0.0, 0.25]), atol=1e-15)
    D = _linalg.downdate(L, V)
    np.testing.assert_allclose(D @ D.T, L @ L.T - V @ V.T, atol=1e-15)
    with pytest.raises(np.linalg.LinAlgError, match="the predicted covariance is not positive semi-definite"):
        _linalg.downdate(L, 2.0 * V, "the predicted covariance")
    with pytest.raises(np.linalg.LinAlgError, match="not positive semi-definite"):
        _linalg.downdate(L, np.array([[0.0], [0.1], [0.0]]))  # a direction with no variance


@pytest.mark.parametrize("scale", [1.0, 1e-150, 1e150])
def test_a_downdate_to_a_singular_result_is_its_semidefinite_factor(scale):
    """A pivot of exactly zero (the rotation cannot go on) is a singular result, not an error: the difference's
    semi-definite factor, lower triangular, with a zero column where the result has no variance left."""
    L = scale * np.array([[1.0, 0.0], [1.0, 1.0]])
    V = scale * np.array([[0.0], [1.0]])  # takes away all of the second component's own variance
    D = _linalg.downdate(L, V)
    np.testing.assert_array_equal(D, scale * np.array([[1.0, 0.0], [1.0, 0.0]]))


def test_factor_solve_is_exact_on_the_range_of_a_singular_factor():
    L = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, 0.3, 1.0]])
    x = np.array([[1.0], [-2.0], [0.5]])
    np.testing.assert_allclose(L @ _linalg.factor_solve(L, L @ x), L @ x, atol=1e-14)
    full = np.tril(np.random.default_rng(3).normal(size=(3, 3))) + 3 * np.eye(3)
    np.testing.assert_allclose(_linalg.factor_solve(full, x), np.linalg.solve(full, x), rtol=1e-13)


def test_symmetrize_is_the_average_without_overflow():
    """``(P + Pᵀ) / 2`` to the last bit on normal numbers, and finite for entries above half the largest float."""
    rng = np.random.default_rng(0)
    for scale in (1e-300, 1.0, 1e300):
        P = rng.normal(size=(3, 4, 4)) * scale
        np.testing.assert_array_equal(_linalg.symmetrize(P), 0.5 * (P + P.swapaxes(-1, -2)))
    big = np.array([[1.5e308, 1.2e308], [1.0e308, 1.7e308]])
    np.testing.assert_array_equal(_linalg.symmetrize(big), [[1.5e308, 1.1e308], [1.1e308, 1.7e308]])


@pytest.mark.parametrize("q", [0.3, 1.0, 7.1e-5, 3.3e40])
def test_a_matrix_singular_in_exact_arithmetic_gets_a_zero_column_not_round_off_noise(q):
    """q g gᵀ (piecewise white acceleration, dt = 1): Cholesky can succeed with a pivot of round-off, whose root
    (about 1e-8 of the scale) drew noise in a direction the process cannot move; it is a zero pivot."""
    g = np.array([0.5, 1.0])
    Q = q * np.outer(g, g)
    L, keep = _linalg.sqrt_cov(Q)
    assert L[1, 1] == 0.0 and keep.tolist() == [True, False]
    np.testing.assert_allclose(L @ L.T, Q, rtol=0, atol=4e-16 * q)



def test_sqrt_cov_names_the_covariance_it_cannot_root():
    """The sigma-point filters' error said only "the covariance is not positive semi-definite"; the filter
    now says which (the filtered one that f's points are drawn from, or the predicted one, h's)."""
    with pytest.raises(np.linalg.LinAlgError, match=r"^the filtered covariance is not positive semi-definite"):
        _linalg.sqrt_cov(np.array([[1.0, 0.0], [0.0, -1.0]]), None, "the filtered covariance")


def test_pivot_order_is_column_pivoting_and_in_pivot_order_says_when_rows_already_are():
    """pivot_order takes each next the row with the largest part orthogonal to those before (by binade, ties in
    order); in_pivot_order reads that off a triangular factor, with plain floats below 9 rows and NumPy above."""
    from gaussfuse._linalg import in_pivot_order, pivot_order, tria

    B = np.array([[1e50, 0.0, 1.0, 0.0, 0.0], [1e50, 0.0, 0.0, 1.0, 0.0], [0.0, 1e50, 0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(pivot_order(B), [0, 2, 1])  # after the first, the second is 1e50 times smaller
    assert not in_pivot_order(tria(B)) and in_pivot_order(tria(B[[0, 2, 1]]))
    rng = np.random.default_rng(3)
    for k in (2, 5, 8, 9, 16):
        for _ in range(20):
            M = rng.standard_normal((k, k + 3)) * 10.0 ** rng.integers(-30, 30, size=(k, 1))
            order = pivot_order(M)
            assert sorted(order) == list(range(k))
            L = tria(M[order])
            assert in_pivot_order(L)
            big = max(16, k)  # the same rule through the other path: a factor padded past 8 rows with zero rows
            padded = np.zeros((big + 1, big + 1))
            padded[:k, :k] = L
            assert in_pivot_order(padded) == in_pivot_order(L)
            assert in_pivot_order(tria(M)) == (list(order) == list(range(k)))


def test_clip_variances_zeroes_round_off_below_zero_only_matrix_by_matrix():
    """A variance below 0 whose row is all within the round-off of the terms it was computed from (their sizes t)
    is 0 with its row and column; one further below, or with a covariance that is not round-off, is kept (an
    indefinite result the checks must see: judged on the largest variance, -2e-3 beside 1e12 and
    [[1, .5], [.5, -1e-17]] were made to look PSD, audit R4); a stack is clipped matrix by matrix (the smoother's
    step back to the prior's time takes all series at once: the diagonal was read along the wrong axes)."""
    from gaussfuse._linalg import clip_variances

    sizes = lambda: np.ones(2)  # noqa: E731
    covs = np.array([[[1.0, 1e-17], [1e-17, -1e-17]], [[-1e-17, 1e-18], [1e-18, 2.0]], [[1.0, 0.0], [0.0, -0.5]],
                     [[1.0, 0.5], [0.5, -1e-17]]])
    want = np.array([[[1.0, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 2.0]], [[1.0, 0.0], [0.0, -0.5]],
                     [[1.0, 0.5], [0.5, -1e-17]]])
    np.testing.assert_array_equal(clip_variances(covs, sizes), want)
    for cov, expected in zip(covs, want):
        np.testing.assert_array_equal(clip_variances(cov, sizes), expected)
    indefinite = np.diag([1e12, 1.0, -1e-3])
    assert clip_variances(indefinite, lambda: np.array([1e12, 1.0, 1.0])) is indefinite  # the same array
    assert clip_variances(indefinite, lambda: np.array([1e12, 1.0, 1e12]))[2, 2] == 0.0  # its terms were 1e12
    with_nan = np.array([[np.nan, 0.0], [0.0, -1e-17]])
    assert clip_variances(with_nan, sizes) is with_nan  # an overflow upstream is not hidden


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("dt, scale, T", [(0.1, 1.0, 30), (0.37, 1e12, 25)])
def test_smoothed_variances_of_round_off_stay_zero_through_large_gains(engine, dt, scale, T):
    """Constant acceleration, position measured exactly (R = diag(0, 0.5)) (audit R5): judged on the filtered
    covariance, a smoothed variance of -1e-18 was kept and the smoother's gains (about 14) magnified it step by
    step, to -3.5e-5 at step 0 on the compiled engine with a unit prior (exactly 1.44e-6 and 1.72e-3 there), and
    to -4.4e-4 on the readable one with a prior of 1e12. Judged on the size of the terms each entry is computed
    from, no smoothed variance is negative and the first beliefs are valid Gaussians."""
    F = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    model = gf.LinearModel(F, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], gf.piecewise_white_noise(2, dt, 0.3),
                           np.diag([0.0, 0.5]))
    sm = gf.smooth(model, gf.Gaussian(np.zeros(3), scale * np.eye(3)), np.zeros((T, 2)), engine=engine, check="off")
    assert (np.diagonal(sm.covs, axis1=1, axis2=2) >= 0.0).all()
    for P in sm.covs[:2]:
        gf.Gaussian(np.zeros(3), P)  # refused where indefinite


@pytest.mark.parametrize("scale", [1e-200, 1e-170, 1.0, 1e150, 1e160, 1e300])
def test_the_compiled_clip_decides_as_the_readable_one_at_every_scale(scale):
    """The compiled mirror took √(t_i t_j), which overflows past 1e154 and underflows below 1e-154: at 1e160 it
    zeroed a variance of -3.5 s of a negative sigma-point weight (the smoother's check then saw nothing), and at
    1e-170 it kept the round-off the readable path clips (audit R6)."""
    from gaussfuse._kernels import _dense
    from gaussfuse._linalg import clip_variances

    rng = np.random.default_rng(0)
    for _ in range(200):
        G = rng.standard_normal((3, 2))
        P = scale * (G @ G.T)
        P[2, 2] = -scale * 10.0 ** rng.uniform(-18, 0)
        P[2, :2] = P[:2, 2] = scale * 10.0 ** rng.uniform(-20, -14, size=2) * rng.choice([-1.0, 1.0], 2)
        t = scale * np.abs(G) ** 2 @ np.ones(2) + scale
        compiled = P.copy()
        _dense.clip_variances(compiled, t, 3)
        np.testing.assert_array_equal(compiled, clip_variances(P, lambda: t))


def test_a_matrix_with_an_infinite_entry_is_not_positive_definite():
    """NumPy's Cholesky of [[inf, 1], [1, 2]] succeeds, with NaN in its factor: the test said positive definite,
    and an infinite information reached an eigenvalue routine that failed (audit EE1)."""
    assert not _linalg.is_positive_definite(np.array([[np.inf, 1.0], [1.0, 2.0]]))
    assert not _linalg.is_positive_definite(np.array([[1.0, np.nan], [np.nan, 2.0]]))
    assert _linalg.is_positive_definite(np.array([[1.0, 0.5], [0.5, 2.0]]))
