"""Sigma-point rules and statistical linear regression."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gaussfuse as gf
from gaussfuse._linalg import sqrt_cov as _sqrt_cov
from gaussfuse.linearize import cubature, gauss_hermite, slr, slr_sqrt, unscented


def sqrt_cov(cov):
    return _sqrt_cov(cov)[0]


def _random_gaussian(rng, n):
    A = rng.standard_normal((n, n))
    return rng.standard_normal(n), A @ A.T + 0.5 * np.eye(n)


def _moments(rule, mean, cov):
    X = mean + rule.points @ sqrt_cov(cov).T
    m = rule.wm @ X
    d = X - m
    return m, (d * rule.wc[:, None]).T @ d


@pytest.mark.parametrize(
    "make", [lambda n: unscented(n), lambda n: unscented(n, 0.5, 2.0, 1.0), cubature,
             lambda n: gauss_hermite(n, 3), lambda n: gauss_hermite(n, 5)],
    ids=["ut", "ut-scaled", "cubature", "gh3", "gh5"],
)
@pytest.mark.parametrize("n", [1, 2, 4])
def test_rules_reproduce_mean_and_covariance(make, n):
    rng = np.random.default_rng(n)
    mean, cov = _random_gaussian(rng, n)
    rule = make(n)
    m, P = _moments(rule, mean, cov)
    np.testing.assert_allclose(rule.wm.sum(), 1.0, rtol=1e-14)
    np.testing.assert_allclose(m, mean, atol=1e-12)
    # The scaled UT's covariance weights carry 1 - alpha^2 + beta on the centre point,
    # which is zero for alpha=1, beta=0 only; the mean weights give the covariance exactly.
    d = mean + rule.points @ sqrt_cov(cov).T - mean
    np.testing.assert_allclose((d * rule.wm[:, None]).T @ d, cov, rtol=1e-12, atol=1e-12)


def test_rule_sizes_and_weights():
    assert unscented(3).points.shape == (7, 3)
    assert cubature(3).points.shape == (6, 3)
    assert gauss_hermite(3, 4).points.shape == (64, 3)
    rule = unscented(2)  # alpha=1, beta=0, kappa=3-n=1: lambda = 1
    np.testing.assert_allclose(rule.wm, [1 / 3] + [1 / 6] * 4)
    np.testing.assert_allclose(rule.wc, rule.wm)
    np.testing.assert_allclose(np.abs(rule.points).max(), np.sqrt(3))
    scaled = unscented(2, alpha=0.5, beta=2.0, kappa=0.0)
    lam = 0.25 * 2 - 2
    assert scaled.wc[0] == pytest.approx(lam / (2 + lam) + 1 - 0.25 + 2)


def test_gauss_hermite_is_exact_for_polynomials():
    """Order-p Gauss-Hermite integrates x^k under N(0,1) exactly for k <= 2p - 1."""
    rule = gauss_hermite(1, 4)
    x = rule.points[:, 0]
    double_factorial = {0: 1, 2: 1, 4: 3, 6: 15}
    for k in range(8):
        exact = double_factorial[k] if k % 2 == 0 else 0.0
        assert rule.wm @ x**k == pytest.approx(exact, abs=1e-12)


def test_unscented_rejects_degenerate_scaling():
    with pytest.raises(ValueError, match=r"alpha\*\*2 \* \(n \+ kappa\) > 0"):
        unscented(2, alpha=1.0, kappa=-2.0)
    with pytest.raises(ValueError, match="`order` must be a positive integer"):
        gauss_hermite(2, 0)
    with pytest.raises(ValueError, match="`order` must be at least 2: .* ignore every measurement"):
        gauss_hermite(2, 1)  # the mean alone: no slope (it used to filter, ignoring the data)


def test_julier_uhlmann_polar_to_cartesian():
    """Julier & Uhlmann's example: r ~ N(1, 0.02²), θ ~ N(90°, 15²) mapped to y = r sin θ.

    The true mean is E[r] E[sin θ] = exp(-σθ²/2) ≈ 0.96631; linearisation at the
    mean gives sin(90°) = 1.0. The unscented transform (kappa = 3 - n) gets it.
    """
    sigma_t = np.deg2rad(15.0)
    mean = np.array([1.0, np.pi / 2])
    cov = np.diag([0.02**2, sigma_t**2])

    def to_cartesian(X):
        return np.stack([X[:, 0] * np.cos(X[:, 1]), X[:, 0] * np.sin(X[:, 1])], axis=-1)

    A, b, _ = slr(to_cartesian, unscented(2), mean, cov)
    y_ut = A @ mean + b
    exact = np.exp(-sigma_t**2 / 2)
    assert exact == pytest.approx(0.96631, abs=5e-6)
    assert y_ut[1] == pytest.approx(0.96631, abs=5e-5)
    assert abs(y_ut[1] - exact) < 1e-3
    assert to_cartesian(mean[None])[0, 1] == pytest.approx(1.0)  # the linearised answer


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4), d=st.integers(1, 3))
def test_slr_of_an_affine_map_is_exact(seed, n, d):
    rng = np.random.default_rng(seed)
    mean, cov = _random_gaussian(rng, n)
    A_true, b_true = rng.standard_normal((d, n)), rng.standard_normal(d)
    for rule in (unscented(n), cubature(n), gauss_hermite(n, 3)):
        A, b, omega = slr(lambda X: X @ A_true.T + b_true, rule, mean, cov)
        np.testing.assert_allclose(A, A_true, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(b, b_true, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(omega, 0.0, atol=1e-9)


def test_slr_wraps_angle_outputs():
    """Bearings straddling ±π average to π, not 0, and their spread stays small."""
    mean, cov = np.array([np.pi]), np.array([[0.01**2]])
    A, b, omega = slr(lambda X: (X + np.pi) % (2 * np.pi) - np.pi, unscented(1), mean, cov,
                      angles=np.array([True]))
    assert abs(abs(A @ mean + b)[0] - np.pi) < 1e-9
    assert omega[0, 0] < 1e-8
    assert A[0, 0] == pytest.approx(1.0, rel=1e-9)


def test_sqrt_cov_of_singular_covariance():
    cov = np.array([[1.0, 1.0], [1.0, 1.0]])
    L = sqrt_cov(cov)
    np.testing.assert_allclose(L @ L.T, cov, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError, match="not positive semi-definite"):
        sqrt_cov(np.array([[1.0, 0.0], [0.0, -1.0]]))


def test_slr_with_a_round_off_variance_stays_of_the_size_of_the_slope():
    """A component whose variance is round-off (1e-32) at a mean of 2: its points are quantised to ulps.

    The regression in the unit points keeps A of the size of g's slope, and
    it equals the regression with that variance exactly 0 (where the points
    do not move along it). C P⁻¹ made an entry of order 1e15 here.
    """
    mean = np.array([0.1, 2.0])
    near_cov, exact_cov = np.array([[1.5, 1e-32], [1e-32, 6.6e-32]]), np.diag([1.5, 0.0])
    g = lambda X: np.stack([0.5 * X[:, 0] + 25 * X[:, 0] / (1 + X[:, 0] ** 2) + X[:, 1], X[:, 1]], axis=-1)
    for rule in (unscented(2), cubature(2), gauss_hermite(2, 3)):
        A, b, omega = slr(g, rule, mean, near_cov)
        A0, b0, omega0 = slr(g, rule, mean, exact_cov)
        assert np.abs(A).max() < 30.0
        assert abs(omega[0, 1]) < 1e-12 and omega[1, 1] > -1e-40
        # The prediction it gives is the one with the variance exactly 0.
        np.testing.assert_allclose(A @ mean + b, A0 @ mean + b0, rtol=1e-14)
        np.testing.assert_allclose(A @ near_cov @ A.T + omega, A0 @ exact_cov @ A0.T + omega0, rtol=1e-12, atol=1e-12)


def test_slr_of_a_component_known_exactly_has_no_spread():
    """An output constant over the points has exactly its value as mean and exactly zero variance."""
    mean, cov = np.array([0.3, 2.0, np.pi - 0.01]), np.diag([2.0, 0.0, 0.0])
    g = lambda X: np.stack([np.sin(X[:, 0]), X[:, 1], X[:, 2] + 0.02], axis=-1)  # the last: an angle
    for rule in (unscented(3), cubature(3), gauss_hermite(3, 3)):
        A, b, omega = slr(g, rule, mean, cov, angles=np.array([False, False, True]))
        y = A @ mean + b
        assert y[1] == 2.0 and y[2] == (np.pi - 0.01) + 0.02
        np.testing.assert_array_equal(omega[1:], 0.0)
        np.testing.assert_array_equal(A[1:], 0.0)


def test_gauss_hermite_refuses_rules_too_large_to_build():
    """order**n points beyond 10**6, or an order beyond 200, are refused before anything is allocated."""
    assert gauss_hermite(3, 100).points.shape == (10**6, 3)  # at the limit
    with pytest.raises(ValueError, match=r"^`order` = 101 in n = 3 dimensions would give order\*\*n = 1,030,301 "
                                         r"sigma points, more than the limit of 1,000,000; use a smaller `order`, or the "
                                         r"unscented or cubature rule \(2n \+ 1 or 2n points\)\.$"):
        gauss_hermite(3, 101)
    with pytest.raises(ValueError, match=r"order\*\*n = 1,594,323 sigma points"):
        gauss_hermite(13, 3)  # the default order, in 13 dimensions
    with pytest.raises(ValueError, match=r"order\*\*n = 5.15e\+47 sigma points"):
        gauss_hermite(100, 3)
    with pytest.raises(ValueError, match=r"^`order` must be at most 200 \(the 1-D Gauss–Hermite rule is not accurate "
                                         r"beyond\); got 1000000\.$"):
        gauss_hermite(1, 10**6)  # NumPy would build a 10**6 x 10**6 matrix: 8 TB
    with pytest.raises(TypeError, match=r"`order` must be a positive integer; got True"):
        gauss_hermite(1, True)
    rule = gauss_hermite(1, 200)
    assert rule.points.shape == (200, 1) and np.all(np.isfinite(rule.wm))
    assert rule.wm @ rule.points[:, 0] ** 2 == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("method", ["ghkf", "iplf"])
def test_filters_refuse_a_gauss_hermite_order_too_large(method):
    import gaussfuse as gf

    model = gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.eye(4), 1.0)
    prior = gf.Gaussian(np.zeros(4), np.eye(4))
    with pytest.raises(ValueError, match=r"^`order` must be at most 200 \(the 1-D Gauss–Hermite rule is not accurate "
                                         r"beyond\); got 1000000\.$"):
        gf.filter(model, prior, [1.0], method=method, order=10**6)
    with pytest.raises(ValueError, match=r"^`order` = 100 in n = 4 dimensions would give order\*\*n = 100,000,000 "
                                         r"sigma points"):
        gf.smooth(model, prior, [1.0], method=method, order=100)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 5), d=st.integers(1, 3), alpha=st.sampled_from([1.0, 0.5, 1e-2]))
def test_slr_on_a_factor_is_slr(seed, n, d, alpha):
    """slr_sqrt: the same A and b, and Ω = Ω₊Ω₊ᵀ - Ω₋Ω₋ᵀ, with Ω₋ exactly where a weight is negative."""
    rng = np.random.default_rng(seed)
    mean, cov = _random_gaussian(rng, n)
    W = rng.standard_normal((d, n))
    g = lambda X: np.sin(X @ W.T) + 0.1 * (X @ W.T) ** 2  # noqa: E731
    for rule in (unscented(n, alpha=alpha), cubature(n), gauss_hermite(n, 3)):
        A, b, omega = slr(g, rule, mean, cov)
        A2, b2, plus, minus = slr_sqrt(g, rule, mean, np.linalg.cholesky(cov))
        scale = max(1.0, np.abs(A).max())
        np.testing.assert_allclose(A2, A, rtol=1e-9, atol=1e-9 * scale)
        np.testing.assert_allclose(b2, b, rtol=1e-9, atol=1e-9 * scale)
        assert (minus is None) == bool((rule.wc >= 0).all())
        got = plus @ plus.T - (0.0 if minus is None else minus @ minus.T)
        np.testing.assert_allclose(got, omega, rtol=1e-7, atol=1e-9 * max(1.0, np.abs(plus).max() ** 2))


def test_slr_on_a_factor_of_an_affine_map_leaves_no_residual():
    """A linear g: residuals at round-off are zero, so nothing is downdated even with a negative weight."""
    rng = np.random.default_rng(5)
    mean, cov = 1e6 + rng.normal(size=4), np.diag([1e-6, 1.0, 1e6, 1.0])
    F = rng.normal(size=(3, 4))
    A, b, plus, minus = slr_sqrt(lambda X: X @ F.T + 2.0, unscented(4), mean, np.linalg.cholesky(cov))
    np.testing.assert_allclose(A, F, rtol=1e-6)  # points 1e-3 apart on 1e6 are quantised to 1e-10: 1e-7 of a slope
    assert not plus.any() and not minus.any()


def test_slr_on_a_singular_factor_regresses_on_its_range():
    """A factor with a zero on its diagonal (a component known exactly): A L = Ξᵀ still holds."""
    L = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 0.0, 2.0]])
    g = lambda X: np.stack([np.sin(X[:, 0]) * X[:, 2], X[:, 1] ** 2], axis=1)  # noqa: E731
    A, b, plus, minus = slr_sqrt(g, cubature(3), np.array([0.3, 1.0, -0.5]), L)
    A_ref, b_ref, omega = slr(g, cubature(3), np.array([0.3, 1.0, -0.5]), L @ L.T)
    np.testing.assert_allclose(A @ L, A_ref @ L, atol=1e-12)
    np.testing.assert_allclose(plus @ plus.T, omega, atol=1e-12)
    assert minus is None


@pytest.mark.parametrize("method", ["ukf", "ckf", "ghkf"])
@pytest.mark.parametrize("engine", ["python", "numba"])
def test_the_covariance_forms_regression_noise_keeps_a_precise_sensor(method, engine):
    """A linear h: the regression's Ω is 0, but S - ΞᵀΞ (terms of the prior's 1e12) left round-off larger than
    R = 1e-6 in it: means 270 (UKF) and 67 (compiled CKF) posterior standard deviations off, a variance of 3 for 1
    beside a prior of 1e16, and the engines apart. Oracle: a 50-digit Kalman filter."""
    from _mp_oracle import filter_50_digits

    F, H = np.array([[1.0, 0.1], [0.0, 1.0]]), np.eye(2)
    Q, R, P0 = 1e-6 * np.eye(2), 1e-6 * np.eye(2), np.diag([1e12, 1e-6])
    zs = np.array([[1.0, 0.5], [1.05, 0.51], [1.1, 0.49]])
    model = gf.NonlinearModel(lambda x: F @ x, lambda x: H @ x, Q, R)
    got = gf.filter(model, gf.Gaussian([0.0, 0.0], P0), zs, method=method, engine=engine, check="off")
    means, covs = filter_50_digits(F, H, Q, R, np.zeros(2), P0, zs)
    sd = np.sqrt(np.diagonal(covs, axis1=1, axis2=2))
    assert np.all(np.abs(got.means - means) <= 1e-5 * sd)  # (the KF: 3e-13; points 1e6 apart)
    np.testing.assert_allclose(got.covs, covs, rtol=1e-6, atol=1e-6 * sd.min() ** 2)
    one = gf.filter(gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.zeros((2, 2)), [[1.0]]),
                    gf.Gaussian([0.0, 0.0], [[1e16, 0.999e8], [0.999e8, 1.0]]), [[5.0]], method=method,
                    engine=engine, check="off")
    assert one.covs[0, 0, 0] == pytest.approx(1.0, rel=1e-12)  # 3.0 from the GHKF before
