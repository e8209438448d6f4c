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
