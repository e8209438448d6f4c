"""gf.Gaussian and gf.fuse."""

from __future__ import annotations

import dataclasses
import warnings
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

import _oracle
import gaussfuse as gf

# ---------------------------------------------------------------------------
# Gaussian: construction and immutability
# ---------------------------------------------------------------------------


def test_arrays_are_read_only_copies():
    mean, cov = np.array([1.0, 2.0]), np.array([[2.0, 0.5], [0.5, 1.0]])
    g = gf.Gaussian(mean, cov)
    with pytest.raises(ValueError, match="read-only"):
        g.mean[0] = 5.0
    with pytest.raises(ValueError, match="read-only"):
        g.cov[0, 0] = 5.0
    # The caller's arrays are neither frozen nor aliased.
    mean[0] = 9.0
    cov[0, 0] = 9.0
    assert g.mean[0] == 1.0 and g.cov[0, 0] == 2.0
    assert g.mean.dtype == np.float64 and g.cov.dtype == np.float64


def test_attributes_cannot_be_assigned():
    g = gf.Gaussian([0.0], [[1.0]])
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.mean = np.array([1.0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.cov = np.array([[2.0]])
    with pytest.raises(AttributeError):
        g.extra = 1
    assert g.mean[0] == 0.0


def test_scalar_input_is_one_dimensional():
    g = gf.Gaussian(1.5, 4.0)
    assert g.dim == 1
    assert g.mean.shape == (1,) and g.cov.shape == (1, 1)
    assert g.mean[0] == 1.5 and g.cov[0, 0] == 4.0
    np.testing.assert_array_equal(g.std, [2.0])


def test_integer_lists_become_float64():
    g = gf.Gaussian([1, 2], [[2, 1], [1, 2]])
    assert g.mean.dtype == np.float64
    np.testing.assert_array_equal(g.cov, [[2.0, 1.0], [1.0, 2.0]])


def test_round_off_asymmetry_is_accepted_and_removed():
    g = gf.Gaussian([0.0, 0.0], [[1.0, 0.3 + 1e-13], [0.3, 1.0]])
    np.testing.assert_array_equal(g.cov, g.cov.T)
    assert g.cov[0, 1] == pytest.approx(0.3, abs=1e-12)


def test_singular_covariance_is_allowed():
    g = gf.Gaussian([1.0, 2.0], [[1.0, 1.0], [1.0, 1.0]])
    assert np.linalg.matrix_rank(g.cov) == 1


# Validation errors: the message names the argument, the expected and the received shape.


@pytest.mark.parametrize(
    ("mean", "cov", "error", "match"),
    [
        ([0.0, 0.0], [[1.0, 0.5], [0.0, 1.0]], ValueError, r"^`cov` must be symmetric; its entries \[0, 1\] and \[1, 0\] differ, 0\.5 and 0\.0\.$"),
        ([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]], ValueError,
         r"^`cov` must be positive semi-definite; its smallest eigenvalue is -1\.$"),
        ([0.0, np.nan], np.eye(2), ValueError,
         r"^`mean` must be finite; got a non-finite \(NaN or inf\) value at index \(1,\)\.$"),
        ([0.0, 0.0], [[1.0, np.inf], [np.inf, 1.0]], ValueError,
         r"^`cov` must be finite; got a non-finite \(NaN or inf\) value at index \(0, 1\)\.$"),
        ([0.0, 0.0], np.eye(3), ValueError, r"^`cov` must have shape \(2, 2\); got shape \(3, 3\)\.$"),
        ([0.0, 0.0], np.ones((3, 2, 2)), ValueError, r"^`cov` must have shape \(2, 2\); got shape \(3, 2, 2\)\.$"),
        ([0.0, 0.0], [1.0, 1.0], ValueError, r"^`cov` must have shape \(2, 2\); got shape \(2,\)\.$"),
        ([0.0, 0.0], 1.0, ValueError, r"^`cov` must have shape \(2, 2\); got shape \(\)\. A number is a 1 × 1 matrix "
                                      r"only; for 1 times the identity give 1 \* np\.eye\(2\)\.$"),
        ([[0.0, 0.0]], np.eye(2), ValueError, r"^`mean` must have shape \(n,\) with n >= 1; got shape \(1, 2\)\.$"),
        ([], np.zeros((0, 0)), ValueError, r"^`mean` must have shape \(n,\) with n >= 1; got shape \(0,\)\.$"),
        ("ab", np.eye(2), TypeError, r"^`mean` must be an array of numbers; got str\.$"),
        ([0.0], "1", TypeError, r"^`cov` must be an array of numbers; got str\.$"),
        ([0.0], None, TypeError, r"^`cov` must be an array of numbers; got NoneType\.$"),
        ([0.0], [[1 + 1j]], TypeError, r"^`cov` must be real; got complex values\.$"),
        ([0.0, "a"], np.eye(2), TypeError, r"^`mean` must be an array of numbers; got strings\."),
    ],
    ids=["non-symmetric", "not-psd", "nan-mean", "inf-cov", "cov-3x3", "cov-stack", "cov-vector",
         "cov-scalar", "mean-2d", "empty", "str-mean", "str-cov", "none-cov", "complex-cov", "mixed-mean"],
)
def test_invalid_gaussian(mean, cov, error, match):
    with pytest.raises(error, match=match):
        gf.Gaussian(mean, cov)


# ---------------------------------------------------------------------------
# logpdf and sample
# ---------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 4), st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_logpdf_matches_scipy(n, k, seed):
    rng = np.random.default_rng(seed)
    mean, cov = rng.normal(size=n), _oracle.random_spd(rng, n)
    g = gf.Gaussian(mean, cov)
    ref = multivariate_normal(mean, cov)
    xs = rng.normal(size=(k, n)) * 3
    batch = g.logpdf(xs)
    assert batch.shape == (k,)
    np.testing.assert_allclose(batch, np.atleast_1d(ref.logpdf(xs)), rtol=1e-12, atol=1e-12)
    single = g.logpdf(xs[0])
    assert isinstance(single, float)
    assert single == pytest.approx(float(ref.logpdf(xs[0])), rel=1e-12, abs=1e-12)


def test_logpdf_of_a_one_dimensional_gaussian():
    g = gf.Gaussian(1.0, 4.0)
    ref = multivariate_normal(1.0, 4.0)
    assert g.logpdf(3.0) == pytest.approx(ref.logpdf(3.0), rel=1e-14)
    assert g.logpdf([3.0]) == pytest.approx(ref.logpdf(3.0), rel=1e-14)
    xs = np.array([0.0, 1.0, 2.5])
    np.testing.assert_allclose(g.logpdf(xs), ref.logpdf(xs), rtol=1e-14)
    np.testing.assert_allclose(g.logpdf(xs[:, None]), ref.logpdf(xs), rtol=1e-14)


@pytest.mark.parametrize("x", [np.zeros(3), np.zeros((4, 3)), np.zeros((2, 4, 2))], ids=["(3,)", "(4,3)", "(2,4,2)"])
def test_logpdf_rejects_wrong_shapes(x):
    g = gf.Gaussian([0.0, 0.0], np.eye(2))
    shape = str(x.shape).replace("(", r"\(").replace(")", r"\)")
    with pytest.raises(ValueError, match=rf"^`x` must have shape \(2,\) or \(k, 2\); got shape {shape}\.$"):
        g.logpdf(x)


def test_logpdf_rejects_non_numeric_and_non_finite_points():
    g = gf.Gaussian([0.0, 0.0], np.eye(2))
    with pytest.raises(TypeError, match=r"^`x` must be an array of numbers; got str\.$"):
        g.logpdf("ab")
    with pytest.raises(ValueError, match=r"^`x` must be finite; got a non-finite \(NaN or inf\) value at index \(1, 0\)\.$"):
        g.logpdf([[0.0, 0.0], [np.nan, 0.0]])


def test_logpdf_of_a_singular_gaussian_names_cov():
    g = gf.Gaussian([0.0, 0.0], np.diag([1.0, 0.0]))
    with pytest.raises(np.linalg.LinAlgError, match=r"^`cov` is not positive definite"):
        g.logpdf([0.0, 0.0])


def test_sample_moments_with_fixed_seed():
    mean = np.array([1.0, -2.0, 0.5])
    cov = np.array([[2.0, 0.6, 0.0], [0.6, 1.0, -0.3], [0.0, -0.3, 0.5]])
    g = gf.Gaussian(mean, cov)
    N = 200_000
    x = g.sample(N, rng=12345)
    assert x.shape == (N, 3)
    # Mean within 5 standard errors, covariance within a few percent.
    np.testing.assert_array_less(np.abs(x.mean(axis=0) - mean), 5 * np.sqrt(np.diag(cov) / N))
    np.testing.assert_allclose(np.cov(x.T), cov, atol=0.03)
    # Reproducible with the same seed, different with another.
    np.testing.assert_array_equal(g.sample(5, rng=1), g.sample(5, rng=1))
    assert not np.array_equal(g.sample(5, rng=1), g.sample(5, rng=2))
    assert g.sample(rng=0).shape == (3,)
    generator = np.random.default_rng(0)
    assert g.sample(2, rng=generator).shape == (2, 3)


def test_sample_from_a_singular_gaussian_stays_on_its_support():
    # A belief certain along x1 - x2 = 0 (as fuse produces): every sample obeys it.
    g = gf.Gaussian([1.0, 1.0], [[1.0, 1.0], [1.0, 1.0]])
    x = g.sample(1000, rng=3)
    np.testing.assert_allclose(x[:, 0], x[:, 1], atol=1e-12)
    assert x[:, 0].std() == pytest.approx(1.0, rel=0.1)  # marginal variance 1
    certain = gf.Gaussian([4.0, -1.0], np.zeros((2, 2)))
    np.testing.assert_array_equal(certain.sample(3, rng=0), [[4.0, -1.0]] * 3)


def test_sample_from_a_singular_gaussian_of_inexact_entries_stays_on_its_support():
    """``a aᵀ`` rounded has eigenvalues of ±1e-17 where it has none: NumPy's eigendecomposition spread the samples
    by their square roots, 9e-9 off the line x = t a; the semi-definite factor has no such column."""
    a = np.array([1.0, 1 / 3, 0.1])
    x = gf.Gaussian(np.zeros(3), np.outer(a, a)).sample(200, rng=0)
    np.testing.assert_array_equal(x[:, 1], x[:, 0] * a[1])
    np.testing.assert_array_equal(x[:, 2], x[:, 0] * a[2])
    assert x[:, 0].std() == pytest.approx(1.0, rel=0.15)


def test_sample_of_a_covariance_accepted_to_the_round_off_of_its_largest_entry():
    """Gaussian accepts a variance within round-off of the largest entry on that entry's scale; the factor judges
    each component on its own and refused this one, so sample raised LinAlgError (review R35, 1 in 3000)."""
    C = np.array([
        [4.4564660182658544e-07, -1.6081024776311198e-07, -100.87441815341178, 8.209643152430204e-09,
         -3.319259209829767e-05],
        [-1.6081024776311198e-07, 5.802789849510166e-08, 36.400233068316005, -2.9624252574965144e-09,
         1.197744790582888e-05],
        [-100.87441815341178, 36.400233068316005, 22833447394.596058, -1.858295279373403, 7513.315265027584],
        [8.209643152430204e-09, -2.9624252574965144e-09, -1.858295279373403, 1.5123696738196848e-10,
         -6.114695709191198e-07],
        [-3.319259209829767e-05, 1.197744790582888e-05, 7513.315265027584, -6.114695709191198e-07,
         0.0024722463172328316]])
    x = gf.Gaussian(np.zeros(5), C).sample(20_000, rng=0)
    s = np.sqrt(np.diag(C))
    assert np.isfinite(x).all()
    np.testing.assert_allclose(np.cov(x.T) / np.outer(s, s), C / np.outer(s, s), atol=0.05)
    # the covariance's own eigendecomposition, exact only to its largest entry, drew this one's second component
    # with 1950 times its variance (review R36); that of its correlation matrix keeps each component's
    C = np.array([[9.99999999459451e+17, 93780492.3087803, 1.85843496432943e+16, -7.052108423294346e+17],
                  [93780492.3087803, 0.06098707194384359, 10363269.855348399, 27085298.330837682],
                  [1.85843496432943e+16, 10363269.855348399, 2756679276613026.5, -1309713022773643.0],
                  [-7.052108423294346e+17, 27085298.330837682, -1309713022773643.0, 6.76951792715343e+17]])
    x = gf.Gaussian(np.zeros(4), C).sample(20_000, rng=1)
    np.testing.assert_allclose(x.var(axis=0) / np.diag(C), 1.0, atol=0.05)
    # a zero variance's covariances, accepted to the largest entry's round-off, divided by 1 drew its neighbour
    # with 5e4 times its variance (review R37): its row and column are 0
    x = gf.Gaussian(np.zeros(3), [[1e40, 0, 0], [0, 1.0, 1e5], [0, 1e5, 0.0]]).sample(20_000, rng=1)
    np.testing.assert_allclose(x.var(axis=0)[:2] / [1e40, 1.0], 1.0, atol=0.05)
    assert np.all(x[:, 2] == 0.0)


def test_sample_of_a_positive_definite_gaussian_is_numpy_s_cholesky_draw():
    mean = np.array([1.0, -2.0, 0.5])
    cov = np.array([[2.0, 0.6, 0.0], [0.6, 1.0, -0.3], [0.0, -0.3, 0.5]])
    for size in (None, 7):
        want = np.random.default_rng(4).multivariate_normal(mean, cov, size=size, method="cholesky")
        np.testing.assert_array_equal(gf.Gaussian(mean, cov).sample(size, rng=4), want)


# ---------------------------------------------------------------------------
# fuse
# ---------------------------------------------------------------------------

_means = st.floats(-1e3, 1e3, allow_nan=False, allow_subnormal=False)
_variances = st.floats(1e-6, 1e6, allow_nan=False, allow_subnormal=False)


@settings(max_examples=200, deadline=None)
@given(_means, _variances, _means, _variances)
def test_fuse_one_dimensional_matches_textbook_formulas(mu1, v1, mu2, v2):
    # The textbook formulas evaluated exactly in rational arithmetic (the
    # variance formula cancels catastrophically in floating point).
    F1, F2, S1, S2 = map(Fraction, (mu1, mu2, v1, v2))
    mu = F1 + S1 * (F2 - F1) / (S1 + S2)
    var = S1 - S1 * S1 / (S1 + S2)
    fused = gf.fuse(gf.Gaussian(mu1, v1), gf.Gaussian(mu2, v2))
    # rtol 1e-12; the mean's absolute floor is set by the inputs' magnitude,
    # since mu1 + K (mu2 - mu1) can cancel to (nearly) zero.
    assert fused.mean[0] == pytest.approx(float(mu), rel=1e-12, abs=1e-12 * (abs(mu1) + abs(mu2)))
    assert fused.cov[0, 0] == pytest.approx(float(var), rel=1e-12, abs=0.0)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(0, 2**32 - 1))
def test_fuse_matches_information_form(n, seed):
    rng = np.random.default_rng(seed)
    a, A = rng.normal(size=n) * 3, _oracle.random_spd(rng, n)
    b, B = rng.normal(size=n) * 3, _oracle.random_spd(rng, n)
    # Information form with explicit inverses: Λ = A⁻¹ + B⁻¹, η = A⁻¹ a + B⁻¹ b.
    Ai, Bi = np.linalg.inv(A), np.linalg.inv(B)
    cov = np.linalg.inv(Ai + Bi)
    mean = cov @ (Ai @ a + Bi @ b)
    fused = gf.fuse(gf.Gaussian(a, A), gf.Gaussian(b, B))
    np.testing.assert_allclose(fused.mean, mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fused.cov, cov, rtol=1e-9, atol=1e-10)
    assert isinstance(fused, gf.Gaussian)
    # Commutative (up to round-off).
    swapped = gf.fuse(gf.Gaussian(b, B), gf.Gaussian(a, A))
    np.testing.assert_allclose(swapped.mean, fused.mean, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(swapped.cov, fused.cov, rtol=1e-10, atol=1e-11)


@pytest.mark.parametrize("ratio", [1e20, 1e24, 1e30, 1e50, 1e100, 1e200, 1e300])
def test_fuse_is_exact_and_symmetric_however_far_apart_the_variances(ratio):
    """The product's variance is v1 v2 / (v1 + v2), exactly in Fraction arithmetic; written as the update
    (1 - K) v1, it rounded to v1 ε² (4.9e68 for 1 at a ratio of 1e100) when `a` was the vaguer belief."""
    for v1, v2 in ((ratio, 1.0), (1.0, ratio), (3.7 * ratio, 0.3), (1e-300 * ratio, 1e-300)):
        exact = Fraction(v1) * Fraction(v2) / (Fraction(v1) + Fraction(v2))
        mean = (Fraction(v2) * Fraction(1.5) + Fraction(v1) * Fraction(-2.0)) / (Fraction(v1) + Fraction(v2))
        for a, b in ((gf.Gaussian(1.5, v1), gf.Gaussian(-2.0, v2)), (gf.Gaussian(-2.0, v2), gf.Gaussian(1.5, v1))):
            got = gf.fuse(a, b)
            assert got.cov[0, 0] == pytest.approx(float(exact), rel=1e-15, abs=0.0)
            assert got.mean[0] == pytest.approx(float(mean), rel=1e-15, abs=1e-300)
    # and a belief certain about the value keeps it, whatever the other's variance
    certain = gf.fuse(gf.Gaussian(1.0, ratio), gf.Gaussian(3.0, 0.0))
    assert certain.cov[0, 0] == 0.0 and certain.mean[0] == pytest.approx(3.0, rel=1e-15)


def _fuse_80_digits(a, A, b, B):
    """a + A (A+B)⁻¹ (b - a) and A - A (A+B)⁻¹ A in 80 digits (mpmath)."""
    import mpmath as mp

    with mp.workdps(80):
        A_, B_ = mp.matrix(np.asarray(A, float).tolist()), mp.matrix(np.asarray(B, float).tolist())
        a_, b_ = mp.matrix(np.asarray(a, float).tolist()), mp.matrix(np.asarray(b, float).tolist())
        K = A_ * mp.inverse(A_ + B_)
        mean, cov = a_ + K * (b_ - a_), A_ - K * A_
        return (np.array([float(v) for v in mean]),
                np.array([[float(cov[i, j]) for j in range(cov.cols)] for i in range(cov.rows)]))


@pytest.mark.parametrize("a, A, b, B", [
    # a singular belief 1e8 times wider than a positive definite one: the moments' check of their own
    # result refused it ("`cov` must be positive semi-definite; its smallest eigenvalue is -9.69e-09")
    ([0.0, 0.0], [[2.0, 1.0], [1.0, 1.0]], [1.0, 2.0], [[1e8, 3e8], [3e8, 9e8]]),
    # a belief certain along x0 = x1 beside one 1e17 wider: 15% off (every entry 0.575 for 0.5)
    ([0.0, 0.0], [[1.0, 0.0], [0.0, 1.0]], [1.0, 1.0], [[1e17, 1e17], [1e17, 1e17]]),
    # a positive definite belief of 1e-20 beside a singular one: refused as "both certain in a common direction"
    ([0.0, 0.0], [[1e-20, 0.0], [0.0, 1e-20]], [1.0, 1.0], [[1.0, 1.0], [1.0, 1.0]]),
])
def test_fuse_where_the_sum_of_the_covariances_is_ill_conditioned(a, A, b, B):
    mean, cov = _fuse_80_digits(a, A, b, B)
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    for first, second in ((gf.Gaussian(a, A), gf.Gaussian(b, B)), (gf.Gaussian(b, B), gf.Gaussian(a, A))):
        got = gf.fuse(first, second)
        np.testing.assert_allclose(got.cov, cov, rtol=0, atol=1e-12 * scale.max())
        np.testing.assert_allclose(got.mean, mean, rtol=1e-12, atol=1e-12 * np.abs(np.r_[a, b]).max())  # inputs' scale
    assert np.array_equal(gf.fuse(gf.Gaussian(a, A), gf.Gaussian(b, B)).cov,
                          gf.fuse(gf.Gaussian(b, B), gf.Gaussian(a, A)).cov)  # the same numbers, either order


def test_fuse_of_variances_near_the_largest_float():
    """A + B overflowed, and solves with its infinite factor gave N(0, 0) without an error."""
    fused = gf.fuse(gf.Gaussian(1.0, 1e308), gf.Gaussian(3.0, 1e308))
    assert fused.mean[0] == pytest.approx(2.0, rel=1e-15) and fused.cov[0, 0] == pytest.approx(5e307, rel=1e-15)


def _exact_fused_mean(a, A, b, B):
    """(A⁻¹ + B⁻¹)⁻¹ (A⁻¹ a + B⁻¹ b) in exact rationals (the information form), for n <= 2."""
    from fractions import Fraction as Q

    def inv(M):
        M = [[Q(x) for x in row] for row in M]
        if len(M) == 1:
            return [[1 / M[0][0]]]
        det = M[0][0] * M[1][1] - M[0][1] * M[1][0]
        return [[M[1][1] / det, -M[0][1] / det], [-M[1][0] / det, M[0][0] / det]]

    Ai, Bi = inv(A), inv(B)
    n = len(A)
    score = [sum(Ai[r][c] * Q(a[c]) + Bi[r][c] * Q(b[c]) for c in range(n)) for r in range(n)]
    cov = inv([[Ai[r][c] + Bi[r][c] for c in range(n)] for r in range(n)])
    return [float(sum(cov[r][c] * score[c] for c in range(n))) for r in range(n)]


@pytest.mark.parametrize("a, b, A, B", [
    ([9e307], [-9e307], [[1.0]], [[1.0]]), ([1e308], [-8e307], [[1.0]], [[3.0]]),
    ([1.7e308], [-1.7e308], [[2.0]], [[1.0]]), ([-1e308, 1e308], [1e308, -5e307], [[1.0, 0.2], [0.2, 1.0]], np.diag([4.0, 1.0])),
    # means 1e310 standard deviations apart: the whitened difference overflowed (audit H)
    ([1e308], [1.5e308], [[1e-5]], [[1e-5]]), ([1e300], [-1e300], [[1e-20]], [[1e-20]])])
def test_fuse_of_means_whose_difference_overflows(a, b, A, B):
    """b - a overflowed (FloatingPointError) though the fused belief is representable: the means are halved,
    fused and the mean doubled, exactly. Against the information form in exact rationals, to round-off of the
    inputs' size (as any formula with a gain that is not exactly 1/2)."""
    got = gf.fuse(gf.Gaussian(a, A), gf.Gaussian(b, B))
    exact = _exact_fused_mean(a, A, b, B)
    assert np.all(np.abs(got.mean - exact) <= 4e-16 * np.abs(np.r_[a, b]).max())
    assert np.isfinite(got.cov).all()


def test_a_tiny_variance_shows_in_the_repr():
    """The repr suppressed small numbers: a variance of 1e-300 showed as cov=[[0.]]."""
    assert "1.e-300" in repr(gf.Gaussian(1.7e308, 1e-300))


def test_fuse_doc_example():
    fused = gf.fuse(gf.Gaussian(0.0, 1.0), gf.Gaussian(2.0, 1.0))
    assert fused.mean[0] == pytest.approx(1.0) and fused.cov[0, 0] == pytest.approx(0.5)


def test_fusing_with_a_certain_belief_gives_its_value():
    rng = np.random.default_rng(8)
    other = gf.Gaussian(rng.normal(size=3), _oracle.random_spd(rng, 3))
    certain = gf.Gaussian([1.0, -2.0, 3.0], np.zeros((3, 3)))
    for fused in (gf.fuse(certain, other), gf.fuse(other, certain)):
        np.testing.assert_allclose(fused.mean, certain.mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fused.cov, np.zeros((3, 3)), atol=1e-12)


def test_fusing_with_a_belief_certain_in_one_direction():
    # a is certain about x1 only; the fused x1 is a's value, x2 the 1-D fusion.
    a = gf.Gaussian([1.0, 0.0], np.diag([0.0, 2.0]))
    b = gf.Gaussian([5.0, 3.0], np.diag([1.0, 1.0]))
    fused = gf.fuse(a, b)
    assert fused.mean[0] == pytest.approx(1.0, abs=1e-14)
    assert fused.mean[1] == pytest.approx(0.0 + 2.0 * 3.0 / 3.0)
    np.testing.assert_allclose(fused.cov, np.diag([0.0, 2.0 / 3.0]), atol=1e-14)


def test_fusing_beliefs_certain_in_complementary_directions():
    a = gf.Gaussian([1.0, 2.0], np.diag([0.0, 1.0]))
    b = gf.Gaussian([3.0, 4.0], np.diag([1.0, 0.0]))
    fused = gf.fuse(a, b)
    np.testing.assert_allclose(fused.mean, [1.0, 4.0], atol=1e-14)
    np.testing.assert_allclose(fused.cov, np.zeros((2, 2)), atol=1e-14)


def test_fuse_rejects_dimension_mismatch():
    with pytest.raises(ValueError, match=r"^`a` and `b` must have the same dimension; got 2 and 3\.$"):
        gf.fuse(gf.Gaussian([0.0, 0.0], np.eye(2)), gf.Gaussian([0.0, 0.0, 0.0], np.eye(3)))


@pytest.mark.parametrize("which", ["a", "b"])
def test_fuse_rejects_non_gaussian(which):
    g = gf.Gaussian([0.0, 0.0], np.eye(2))
    args = ((np.zeros(2), np.eye(2)), g) if which == "a" else (g, (np.zeros(2), np.eye(2)))
    with pytest.raises(TypeError, match=rf"^`{which}` must be a gaussfuse.Gaussian; got tuple\.$"):
        gf.fuse(*args)


@pytest.mark.parametrize("agree", [False, True])
def test_fuse_rejects_beliefs_both_certain_in_the_same_direction(agree):
    """Refused whether or not the means agree there; the message said "so their product is not a Gaussian", which
    is untrue where they agree (audit CC1)."""
    a = gf.Gaussian([1.0, 0.0], np.diag([0.0, 1.0]))
    b = gf.Gaussian([1.0 if agree else 2.0, 0.0], np.diag([0.0, 3.0]))
    with pytest.raises(ValueError, match=r"^`a\.cov \+ b\.cov` must be positive definite: the two beliefs are both certain"
                                         r" in a common direction, where their product is a point if their means agree"):
        gf.fuse(a, b)


def test_sample_size_must_be_none_or_a_non_negative_integer():
    g = gf.Gaussian([0.0, 1.0, 2.0], np.eye(3))
    assert g.sample(0, rng=0).shape == (0, 3)
    assert g.sample(np.int64(2), rng=0).shape == (2, 3)
    with pytest.raises(ValueError, match=r"^`size` must be None or a non-negative integer; got -1\.$"):
        g.sample(-1)
    for bad in (2.5, "3", True, (2, 3), 2.0):
        with pytest.raises(TypeError, match=r"^`size` must be None or a non-negative integer; got "):
            g.sample(bad)


def test_covariances_near_the_largest_float_do_not_overflow():
    """Symmetrising halves before adding: (P + Pᵀ) / 2 of 1e308 would overflow to inf."""
    g = gf.Gaussian([0.0, 1.0], [[1e308, 1e308], [1e308, 1.7e308]])
    assert np.isfinite(g.cov).all() and g.cov[1, 1] == 1.7e308
    assert gf.Gaussian(0.0, 1e308).cov[0, 0] == 1e308


def test_a_symmetric_covariance_is_kept_bit_for_bit():
    cov = np.array([[1e-310, 5e-324], [5e-324, 3.0]])
    assert np.array_equal(gf.Gaussian([0.0, 0.0], cov).cov, cov)


def test_std_of_a_variance_zero_to_round_off_is_zero():
    g = gf.Gaussian([0.0, 0.0], [[1.0, 0.0], [0.0, -1e-20]])  # valid: -1e-20 is 0 to round-off beside 1
    np.testing.assert_array_equal(g.std, [1.0, 0.0])


@pytest.mark.parametrize("rng, error", [("x", TypeError), (1.5, TypeError), (-1, ValueError), (True, TypeError)])
def test_sample_names_a_bad_rng(rng, error):
    """NumPy's own messages ("SeedSequence expects int or sequence of ints for entropy not x") named no
    argument; True was the seed 1. A negative seed is an integer of the wrong value: a ValueError (audit V)."""
    with pytest.raises(error, match=r"^`rng` must be None, a non-negative integer seed or a numpy.random.Generator; got "):
        gf.Gaussian(0.0, 1.0).sample(2, rng=rng)
    assert gf.Gaussian(0.0, 1.0).sample(2, rng=3).shape == (2, 1)
    # anything numpy.random.default_rng takes, as documented (audit DD2)
    for seeded in (np.random.SeedSequence(3), np.random.RandomState(3), np.random.default_rng(3)):
        assert gf.Gaussian(0.0, 1.0).sample(2, rng=seeded).shape == (2, 1)


def test_a_component_known_exactly_fuses_to_zero_or_to_round_off_as_documented():
    """Exactly 0 from the narrower belief (by trace), about ε² of the other's variance from the wider (audit DD2:
    the Notes said round-off in both cases)."""
    other = gf.Gaussian([0.0, 0.0], [[2.0, 0.5], [0.5, 1.0]])
    narrower = gf.Gaussian([1.0, 2.0], [[0.0, 0.0], [0.0, 1.0]])
    wider = gf.Gaussian([1.0, 2.0], [[0.0, 0.0], [0.0, 100.0]])
    for a, b in ((narrower, other), (other, narrower)):
        fused = gf.fuse(a, b)
        assert fused.cov[0, 0] == 0.0 and fused.mean[0] == 1.0
    fused = gf.fuse(wider, other)
    assert 0.0 <= fused.cov[0, 0] <= 4 * np.finfo(float).eps ** 2 * 2.0
    assert fused.mean[0] == pytest.approx(1.0, abs=1e-15)



def test_fuse_keeps_a_precise_measurement_beside_a_vague_belief_far_away():
    """fuse took its two beliefs in the order of their bytes: from the wider one the mean is a + K (b - a) with K
    near 1, and b was lost to the rounding of a (14.66 beside a vague 1.5e19 came out 0.0; 679 of 2000 random
    1-D fusions off by more than 0.01 sd). Against the exact rational answer on these float64 inputs."""
    from fractions import Fraction

    rng = np.random.default_rng(8)
    for _ in range(200):
        s = 10.0 ** rng.uniform(10, 25)
        a, A = s * rng.normal(), s * s
        B = 10.0 ** rng.uniform(-1, 1)
        b = np.sqrt(B) * rng.normal()
        exact = float((Fraction(B) * Fraction(a) + Fraction(A) * Fraction(b)) / (Fraction(A) + Fraction(B)))
        for first, second in ((gf.Gaussian(a, A), gf.Gaussian(b, B)), (gf.Gaussian(b, B), gf.Gaussian(a, A))):
            got = gf.fuse(first, second).mean[0]
            assert abs(got - exact) <= 1e-12 * np.sqrt(B)


def test_logpdf_far_in_the_tail_is_minus_infinity_without_a_warning():
    """The exact value, -5e399, is below float64's range: -inf is right, but NumPy's overflow warning leaked."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert gf.Gaussian([0.0], [[1.0]]).logpdf([1e200]) == -np.inf
        assert gf.Gaussian([0.0], [[1e-300]]).logpdf([1e10]) == -np.inf
        assert gf.Gaussian([0.0], [[1.0]]).logpdf([1e100]) == pytest.approx(-5e199)  # below that: a number


def test_the_repr_gives_mean_and_covariance_alike_on_one_line():
    """The mean printed to 6 digits and the covariance to 17, and a 50-dimensional belief's repr was 12,774
    characters (audit Y3)."""
    got = repr(gf.Gaussian([0.123456789, 1.0], [[2.0, 0.1], [0.1, 1 / 3]]))
    assert got == "Gaussian(mean=[0.123457, 1.      ], cov=[[2.      , 0.1     ], [0.1     , 0.333333]])"
    big = repr(gf.Gaussian(np.arange(50.0), np.eye(50)))
    assert "\n" not in big and len(big) < 1000 and "..." in big


@pytest.mark.parametrize("degrees", [(179.0, -179.0), (-179.0, 179.0), (180.0, -180.0), (90.0, -90.0 + 1e-13)])
def test_a_mixtures_circular_mean_is_wrapped_to_minus_pi_up_to_pi(degrees):
    """Audit Z1: atan2 gives +π for modes at ±179° (the mean of an IMM's heading), outside [-π, π)."""
    from gaussfuse.gaussian import moment_match
    means = np.array([[1.0, np.radians(degrees[0])], [3.0, np.radians(degrees[1])]])
    covs = np.stack([np.diag([1.0, 0.01])] * 2)
    mean, cov = moment_match(np.array([0.5, 0.5]), means, covs, np.array([False, True]))
    assert -np.pi <= mean[1] < np.pi and mean[0] == 2.0
    spread = gf.wrap_angle(means[:, 1] - mean[1])  # each mode's heading from the mean, the short way round
    assert cov[1, 1] == pytest.approx(0.01 + np.mean(spread ** 2), rel=1e-12)


def test_a_belief_the_filter_computed_is_taken_back_as_it_is():
    """Audit GG2: the covariance form's last covariance of a huge prior and a sharp sensor is indefinite by
    round-off (the form's documented limit), beyond the PSD test's tolerance for what users give: `res.last` and a
    forecast from `res` raised a ValueError about a `cov` the user never passed, and an online filter's belief
    pickled but did not unpickle. They take the filter's numbers as they are now."""
    import pickle

    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.zeros((2, 2)), R=1e-12)
    prior = gf.Gaussian([0.0, 0.0], 1e12 * np.eye(2))
    zs = 3.0 + np.arange(40.0) + 1e-6 * np.random.default_rng(0).standard_normal(40)
    res = gf.filter(model, prior, zs, check="off", engine="python")
    with pytest.raises(ValueError, match="positive semi-definite"):  # what the case is: refused from a user
        gf.Gaussian(res.last_mean, res.last_cov)
    last = res.last
    np.testing.assert_array_equal(last.mean, res.last_mean)
    np.testing.assert_array_equal(last.cov, res.last_cov)
    assert not last.cov.flags.writeable and res.last_cov.flags.writeable  # the result's own array is left as it was
    ahead = gf.forecast(model, res, steps=2)
    np.testing.assert_array_equal(ahead.means[0], gf.forecast(model, last, steps=1).means[0])
    kf = gf.KalmanFilter(model, prior)
    for z in zs:
        kf.predict()
        kf.update(z)
    for copied in (pickle.loads(pickle.dumps(kf.belief)), pickle.loads(pickle.dumps(kf.belief, 0))):
        np.testing.assert_array_equal(copied.cov, kf.belief.cov)
        assert isinstance(copied, gf.Gaussian) and not copied.cov.flags.writeable


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_a_zero_variance_with_round_off_covariances_is_fused_and_factored(engine):
    """Audit VV1: an exact measurement (R = 0) of x0 leaves P - K H P with a variance of 0 and covariances of
    round-off (-2.8e-17), which a Gaussian accepts; fuse refused it, blaming a direction both beliefs were certain
    in (a.cov + I has eigenvalues of at least 1), and so did the square-root filter as a prior or a Q: the factor's
    check divided the round-off by the zero variance. Oracle: the Kalman form C (C + I)⁻¹, C + I well conditioned."""
    C = np.array([[0.0, -2.7755575615628914e-17, 0.0],
                  [-2.7755575615628914e-17, 5.9757194235480018, 1.6996817095609580],
                  [0.0, 1.6996817095609580, 1.9261427498120187]])
    fused = gf.fuse(gf.Gaussian(np.zeros(3), C), gf.Gaussian(np.ones(3), np.eye(3)))
    K = np.linalg.solve((C + np.eye(3)).T, C.T).T
    np.testing.assert_allclose(fused.mean, K @ np.ones(3), rtol=0, atol=1e-15)
    np.testing.assert_allclose(fused.cov, C - K @ C, rtol=0, atol=1e-15)
    L = gf.kalman.cov_factor(C)
    np.testing.assert_allclose(L @ L.T, C, rtol=0, atol=1e-14)  # (round-off of entries of 6)
    zs = np.array([1.0, 2.0, 0.5, 1.5])
    for model, prior in ((gf.LinearModel(np.eye(3), [1, 0, 0], np.eye(3), 1.0), gf.Gaussian(np.zeros(3), C)),
                         (gf.LinearModel(np.eye(3), [1, 0, 0], C, 1.0), gf.Gaussian(np.zeros(3), np.eye(3)))):
        sqrt, cov = (gf.filter(model, prior, zs, form=form, engine=engine) for form in ("sqrt", "cov"))
        np.testing.assert_allclose(sqrt.means, cov.means, rtol=0, atol=1e-13)
        np.testing.assert_allclose(sqrt.covs, cov.covs, rtol=0, atol=1e-13)
