"""The compiled regression (:mod:`gaussfuse._kernels._slr`) equals :func:`gaussfuse.linearize.sigma_points.slr`.

Points drawn through the Cholesky factor and through the readable path's
semi-definite root (a singular covariance), outputs with angles, and every
rule; compared with the readable regression to round-off relative to the
scale of its results.
"""

from __future__ import annotations

import numpy as np
import pytest

from gaussfuse._kernels._slr import Rule, draw, points, regress, regression
from gaussfuse._linalg import sqrt_cov
from gaussfuse.linearize import cubature, gauss_hermite, slr, unscented

TOL = 1e-10
RULES = {"unscented": lambda n: unscented(n, 0.5, 2.0, 0.0), "cubature": cubature,
         "gauss_hermite": lambda n: gauss_hermite(n, 3)}


def g(X):
    """A nonlinear map of 3 states to 2 outputs, the second an angle."""
    return np.stack([np.sin(X[:, 0]) + X[:, 1] * X[:, 2], np.arctan2(X[:, 1], X[:, 0] + 2.0)], axis=-1)


def rule_of(name, n):
    r = RULES[name](n)
    return Rule(np.ascontiguousarray(r.points), r.wm.copy(), r.wc.copy()), r


@pytest.mark.parametrize("name", list(RULES))
@pytest.mark.parametrize("cov_kind", ["definite", "singular", "tiny variance"])
def test_regress_is_slr(name, cov_kind):
    n, d = 3, 2
    rng = np.random.default_rng(len(name))
    mean = rng.standard_normal(n)
    B = rng.standard_normal((n, n))
    cov = B @ B.T / n + 0.1 * np.eye(n)
    if cov_kind == "singular":
        cov[2], cov[:, 2] = 0.0, 0.0
    elif cov_kind == "tiny variance":
        cov[2], cov[:, 2] = 0.0, 0.0
        cov[2, 2] = 1e-30
    rule, readable = rule_of(name, n)
    reg = regression(rule.points.shape[0], n, d)
    X = np.empty((rule.points.shape[0], n))
    if not draw(mean, cov, rule, reg, X):  # not positive definite: the readable path's root
        assert cov_kind != "definite"
        L, keep = sqrt_cov(cov)
        reg.L[...] = L
        reg.keep[...] = keep
        points(mean, rule, reg, X)
    np.testing.assert_allclose(X, mean + readable.points @ sqrt_cov(cov)[0].T, rtol=1e-14, atol=1e-14)
    angles = np.array([False, True])
    regress(g(X), d, rule, mean, angles, reg)
    A, b, omega = slr(g, readable, mean, cov, angles)
    # What the filters use: A's action on the spread of the belief (A L, the cross-covariance's
    # factor) and the mean A m + b. A itself is also compared where the belief determines it: along a
    # variance of 1e-30 the points differ by 1e-15, below the outputs' resolution, and A's column
    # there is round-off in both paths (it is multiplied by that spread wherever it is used).
    L = sqrt_cov(cov)[0]
    AL = A @ L
    np.testing.assert_allclose(reg.A @ L, AL, rtol=TOL, atol=TOL * max(1.0, np.abs(AL).max()), err_msg="A L")
    ym = A @ mean + b
    np.testing.assert_allclose(reg.A @ mean + reg.b, ym, rtol=TOL, atol=TOL * max(1.0, np.abs(ym).max()), err_msg="ȳ")
    if cov_kind != "tiny variance":
        scale = max(1.0, float(np.abs(A).max()))
        np.testing.assert_allclose(reg.A, A, rtol=TOL, atol=TOL * scale, err_msg="A")
    np.testing.assert_allclose(reg.noise, omega, rtol=TOL, atol=TOL * max(1.0, np.abs(omega).max()), err_msg="Ω")
    np.testing.assert_array_equal(reg.noise, reg.noise.T)


def test_a_component_known_exactly_keeps_zero_spread():
    """Centred means: an output that is the same at every point has exactly that mean and Ω = 0 there."""
    n = 2
    rule, _ = rule_of("unscented", n)
    reg = regression(rule.points.shape[0], n, n)
    X = np.empty((rule.points.shape[0], n))
    mean, cov = np.array([0.3, 1.7]), np.diag([0.04, 0.0])
    assert not draw(mean, cov, rule, reg, X)
    L, keep = sqrt_cov(cov)
    reg.L[...], reg.keep[...] = L, keep
    points(mean, rule, reg, X)
    regress(X * [2.0, 1.0], n, rule, mean, np.zeros(n, dtype=bool), reg)
    assert reg.noise[1, 1] == 0.0 and reg.b[1] + reg.A[1] @ mean == 1.7


@pytest.mark.parametrize("name", list(RULES))
@pytest.mark.parametrize("cov_kind", ["definite", "ill-conditioned", "tiny variance"])
@pytest.mark.parametrize("alpha", [1.0, 1e-2])
def test_regress_sqrt_is_slr_sqrt(name, cov_kind, alpha):
    """The square-root regression: A, b and the residual columns Ω₊, Ω₋ of slr_sqrt, to round-off of scale,
    on a factor that is well conditioned, ill conditioned (1e-6 and 1e6 at once) or has a variance of 1e-30;
    with alpha = 1e-2 the unscented centre weight is about -1e4."""
    from gaussfuse._kernels._slr import regress_sqrt
    from gaussfuse.linearize import slr_sqrt

    n, d = 3, 2
    rng = np.random.default_rng(len(name) + len(cov_kind))
    mean = rng.standard_normal(n)
    B = rng.standard_normal((n, n))
    cov = B @ B.T / n + 0.1 * np.eye(n)
    if cov_kind == "ill-conditioned":
        scale = np.array([1e-6, 1.0, 1e6])
        cov = cov * np.outer(scale, scale)
    elif cov_kind == "tiny variance":
        cov[2], cov[:, 2] = 0.0, 0.0
        cov[2, 2] = 1e-30
    readable = unscented(n, alpha, 2.0, 0.0) if name == "unscented" else RULES[name](n)
    rule = Rule(np.ascontiguousarray(readable.points), readable.wm.copy(), readable.wc.copy())
    L = np.linalg.cholesky(cov)
    k = rule.points.shape[0]
    reg = regression(k, n, d)
    reg.L[...] = L
    X = np.empty((k, n))
    points(mean, rule, reg, X)
    angles = np.array([False, True])
    E, At = np.empty((k, d)), np.empty((n, d))
    regress_sqrt(g(X), d, rule, mean, angles, reg, E, At)
    A, b, plus, minus = slr_sqrt(g, readable, mean, L, angles)
    AL = A @ L  # A along the belief's spread, as the filters use it (see test_regress_is_slr)
    np.testing.assert_allclose(reg.A @ L, AL, rtol=TOL, atol=TOL * max(1.0, np.abs(AL).max()), err_msg="A L")
    ym = A @ mean + b
    np.testing.assert_allclose(reg.A @ mean + reg.b, ym, rtol=TOL, atol=TOL * max(1.0, np.abs(ym).max()))
    wc = rule.wc
    got_plus = (E[wc > 0] * np.sqrt(wc[wc > 0])[:, None]).T
    np.testing.assert_allclose(got_plus, plus, rtol=TOL, atol=TOL * max(1.0, np.abs(plus).max()), err_msg="Ω₊")
    if minus is None:
        assert not (wc < 0).any()
    else:
        got_minus = (E[wc < 0] * np.sqrt(-wc[wc < 0])[:, None]).T
        np.testing.assert_allclose(got_minus, minus, rtol=TOL, atol=TOL * max(1.0, np.abs(minus).max()))


def test_regress_sqrt_of_a_linear_map_leaves_no_residual():
    """A linear g: every residual is at round-off and set to exactly 0, so nothing is downdated."""
    from gaussfuse._kernels._slr import regress_sqrt

    n = 3
    readable = unscented(n, 1e-2, 2.0, 0.0)
    rule = Rule(np.ascontiguousarray(readable.points), readable.wm.copy(), readable.wc.copy())
    M = np.random.default_rng(2).standard_normal((2, n))
    mean = np.array([1e6, -3.0, 2e-3])
    k = rule.points.shape[0]
    reg = regression(k, n, 2)
    L = np.linalg.cholesky(np.diag([1e4, 1.0, 1e-8]))
    reg.L[...] = L
    X = np.empty((k, n))
    points(mean, rule, reg, X)
    E = np.empty((k, 2))
    regress_sqrt(X @ M.T, 2, rule, mean, np.zeros(2, dtype=bool), reg, E, np.empty((n, 2)))
    assert (E == 0.0).all()
    ML = M @ L  # A along the spread (along the variance of 1e-8 the outputs of size 1e6 resolve A to 1e-5)
    np.testing.assert_allclose(reg.A @ L, ML, rtol=0, atol=1e-10 * np.abs(ML).max())
