"""Unit tests of the Kalman equations in gaussfuse.kalman."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import _oracle
import gaussfuse as gf
from gaussfuse import kalman


def _belief_and_sensor(seed: int, n: int, m: int):
    rng = np.random.default_rng(seed)
    mean = rng.normal(size=n)
    cov = _oracle.random_spd(rng, n)
    H = rng.normal(size=(m, n))
    R = _oracle.random_spd(rng, m)
    z = H @ mean + rng.normal(size=m)
    return mean, cov, z, H, R


# ---------------------------------------------------------------------------
# update
# ---------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5), st.integers(1, 4), st.integers(0, 2**32 - 1))
def test_joseph_form_equals_standard_form_for_the_optimal_gain(n, m, seed):
    mean, cov, z, H, R = _belief_and_sensor(seed, n, m)
    post = kalman.update(mean, cov, z, H, R)

    # Textbook form with an explicit inverse (fine in a test).
    S = H @ cov @ H.T + R
    K = cov @ H.T @ np.linalg.inv(S)
    standard = (np.eye(n) - K @ H) @ cov
    scale = np.abs(cov).max()
    np.testing.assert_allclose(post.cov, standard, rtol=1e-10, atol=1e-12 * scale)
    np.testing.assert_allclose(post.mean, mean + K @ (z - H @ mean), rtol=1e-10, atol=1e-12 * max(1.0, np.abs(z).max()))
    np.testing.assert_allclose(post.innovation, z - H @ mean, rtol=1e-12, atol=1e-12 * np.abs(z).max())
    np.testing.assert_allclose(post.innovation_cov, S, rtol=1e-12, atol=1e-13 * np.abs(S).max())
    # The Joseph form is kept exactly symmetric and positive semi-definite.
    np.testing.assert_array_equal(post.cov, post.cov.T)
    np.testing.assert_array_equal(post.innovation_cov, post.innovation_cov.T)
    assert np.linalg.eigvalsh(post.cov)[0] > 0
    # The log-likelihood is log N(z; H m, S), constant included.
    sign, logdet = np.linalg.slogdet(S)
    v = z - H @ mean
    expected = -0.5 * (v @ np.linalg.solve(S, v) + logdet + m * np.log(2 * np.pi))
    assert post.loglik == pytest.approx(expected, rel=1e-10, abs=1e-10)


def test_joseph_form_stays_symmetric_psd_with_a_nearly_exact_measurement():
    # A very precise measurement of one component: (I - KH)P loses symmetry and
    # definiteness to round-off, the Joseph form does not.
    cov = np.array([[4.0, 1.999999], [1.999999, 1.0]])
    H = np.array([[1.0, 0.0]])
    post = kalman.update(np.zeros(2), cov, np.array([1.0]), H, np.array([[1e-12]]))
    np.testing.assert_array_equal(post.cov, post.cov.T)
    assert np.linalg.eigvalsh(post.cov)[0] >= -1e-15
    assert post.cov[0, 0] == pytest.approx(1e-12, rel=1e-3, abs=0.0)


def test_all_missing_update_returns_the_prediction_and_zero_loglik():
    mean, cov, _, H, R = _belief_and_sensor(1, 3, 2)
    post = kalman.update(mean, cov, np.array([np.nan, np.nan]), H, R)
    np.testing.assert_array_equal(post.mean, mean)
    np.testing.assert_array_equal(post.cov, cov)
    assert post.loglik == 0.0
    assert np.isnan(post.innovation).all()
    np.testing.assert_allclose(post.innovation_cov, H @ cov @ H.T + R, rtol=1e-13)


def test_partially_missing_update_uses_only_the_observed_rows():
    mean, cov, z, H, R = _belief_and_sensor(2, 3, 3)
    R = np.diag(np.diag(R))  # so that dropping a row is the same as not having it
    z_missing = z.copy()
    z_missing[1] = np.nan
    post = kalman.update(mean, cov, z_missing, H, R)
    keep = [0, 2]
    reduced = kalman.update(mean, cov, z[keep], H[keep], R[np.ix_(keep, keep)])
    np.testing.assert_allclose(post.mean, reduced.mean, rtol=1e-13)
    np.testing.assert_allclose(post.cov, reduced.cov, rtol=1e-13, atol=1e-15)
    assert post.loglik == pytest.approx(reduced.loglik, rel=1e-13)
    assert np.isnan(post.innovation[1]) and not np.isnan(post.innovation[keep]).any()
    assert post.innovation_cov.shape == (3, 3)  # full S, all m components


def test_update_with_offset_d():
    mean, cov, z, H, R = _belief_and_sensor(3, 2, 2)
    d = np.array([0.5, -1.0])
    with_d = kalman.update(mean, cov, z, H, R, d)
    shifted = kalman.update(mean, cov, z - d, H, R)
    np.testing.assert_allclose(with_d.mean, shifted.mean, rtol=1e-13)
    np.testing.assert_allclose(with_d.innovation, shifted.innovation, rtol=1e-13)
    assert with_d.loglik == pytest.approx(shifted.loglik, rel=1e-13)


def test_non_positive_definite_innovation_covariance_raises_naming_S():
    # A certain belief measured without noise: S = 0.
    with pytest.raises(np.linalg.LinAlgError, match=r"innovation covariance S = H P Hᵀ \+ R is not positive definite"):
        kalman.update(np.zeros(2), np.zeros((2, 2)), np.array([1.0]), np.array([[1.0, 0.0]]), np.zeros((1, 1)))


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_a_noise_free_sensor_on_a_known_state_says_why(engine, form):
    """R = 0 on a component the prior knows exactly (S = 0 exactly, not to round-off, so every path raises at
    step 0): the error says why and what to change."""
    model = gf.LinearModel(F=np.eye(2), H=[[1.0, 0.0]], Q=np.diag([0.0, 1.0]), R=0.0)
    with pytest.raises(np.linalg.LinAlgError, match=r"^at step 0: the innovation covariance S .* give R a "
                                                    r"variance above round-off\.\)$"):
        gf.filter(model, gf.Gaussian([0.0, 0.0], np.diag([0.0, 1.0])), [1.0, 2.0], engine=engine, form=form,
                  check="off")


def test_filter_names_the_step_of_a_singular_innovation_covariance():
    # The prior is certain about x1, and H measures x1; R is 0 only at step 2.
    model = gf.LinearModel(
        F=np.eye(2), H=[1.0, 0.0], Q=np.diag([0.0, 1.0]),
        R=np.array([1.0, 1.0, 0.0, 1.0]).reshape(4, 1, 1),
    )
    prior = gf.Gaussian([0.0, 0.0], np.diag([0.0, 1.0]))
    with pytest.raises(np.linalg.LinAlgError, match=r"^at step 2: the innovation covariance S"):
        gf.filter(model, prior, [1.0, 1.0, 1.0, 1.0])
    # The same step missing is no error: nothing is conditioned on.
    res = gf.filter(model, prior, [1.0, 1.0, np.nan, 1.0])
    assert np.isfinite(res.loglik)


def test_predict_is_affine_propagation():
    rng = np.random.default_rng(4)
    mean, cov = rng.normal(size=3), _oracle.random_spd(rng, 3)
    A, Q, b = rng.normal(size=(3, 3)), _oracle.random_spd(rng, 3), rng.normal(size=3)
    m_pred, P_pred = kalman.predict(mean, cov, A, Q, b)
    np.testing.assert_allclose(m_pred, A @ mean + b, rtol=1e-14)
    np.testing.assert_allclose(P_pred, A @ cov @ A.T + Q, rtol=1e-13)
    np.testing.assert_array_equal(P_pred, P_pred.T)
    m0, _ = kalman.predict(mean, cov, A, Q)
    np.testing.assert_allclose(m0, A @ mean, rtol=1e-14)


# ---------------------------------------------------------------------------
# rts_step
# ---------------------------------------------------------------------------


def test_rts_step_matches_explicit_formulas():
    rng = np.random.default_rng(5)
    n = 3
    m_f, P_f = rng.normal(size=n), _oracle.random_spd(rng, n)
    F, Q = _oracle.random_transition(rng, n), _oracle.random_spd(rng, n)
    m_p, P_p = F @ m_f, F @ P_f @ F.T + Q
    m_next, P_next = rng.normal(size=n), _oracle.random_spd(rng, n)
    mean, cov, G = kalman.rts_step(m_f, P_f, m_p, P_p, m_next, P_next, P_f @ F.T)
    G_ref = P_f @ F.T @ np.linalg.inv(P_p)
    np.testing.assert_allclose(G, G_ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(mean, m_f + G_ref @ (m_next - m_p), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cov, P_f + G_ref @ (P_next - P_p) @ G_ref.T, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(cov, cov.T)


def test_rts_step_with_singular_prediction_uses_a_least_squares_gain():
    # P_pred singular: the gain is the minimum-norm solution of G P_pred = C.
    P_f = np.diag([1.0, 0.0])
    F = np.eye(2)
    P_p = F @ P_f @ F.T
    mean, cov, G = kalman.rts_step(
        np.zeros(2), P_f, np.zeros(2), P_p, np.array([2.0, 0.0]), np.diag([0.5, 0.0]), P_f @ F.T
    )
    np.testing.assert_allclose(G, np.diag([1.0, 0.0]), atol=1e-14)
    np.testing.assert_allclose(mean, [2.0, 0.0], atol=1e-14)
    np.testing.assert_allclose(cov, np.diag([0.5, 0.0]), atol=1e-14)


# ---------------------------------------------------------------------------
# fuse_moments
# ---------------------------------------------------------------------------


def test_fuse_moments_is_the_update_with_identity_measurement():
    """To round-off (it writes I - K as B (A + B)⁻¹), and the same whichever belief comes first."""
    rng = np.random.default_rng(6)
    a, A = rng.normal(size=2), _oracle.random_spd(rng, 2)
    b, B = rng.normal(size=2), _oracle.random_spd(rng, 2)
    mean, cov = kalman.fuse_moments(a, A, b, B)
    post = kalman.update(a, A, b, np.eye(2), B)
    np.testing.assert_allclose(mean, post.mean, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(cov, post.cov, rtol=1e-14, atol=1e-15)
    swapped = kalman.fuse_moments(b, B, a, A)
    np.testing.assert_allclose(swapped[0], mean, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(swapped[1], cov, rtol=1e-14, atol=1e-15)


# ---------------------------------------------------------------------------
# step: the steady state is exact
# ---------------------------------------------------------------------------


class _Plain:
    """A strategy without `invariant`: every step computes its covariances."""

    def __init__(self, lin):
        self.lin = lin

    def transition(self, *args):
        return self.lin.transition(*args)

    def measurement(self, *args):
        return self.lin.measurement(*args)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 4), st.integers(1, 3), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.02, 0.3]))
def test_steady_state_reuse_agrees_with_the_full_step_to_round_off(n, m, seed, missing):
    """Once the covariances stop changing to round-off, step() reuses them: the results agree to round-off.

    F = 0.9 × an orthogonal matrix contracts the covariance recursion by at
    least 0.81 per step, so the kept fixed point is within about
    kalman.SETTLED / 0.19 of the exact one (see kalman.SteadyState).
    """
    from gaussfuse.inference.drivers import run_filter
    from gaussfuse.linearize import Exact

    rng = np.random.default_rng(seed)
    F = 0.9 * np.linalg.qr(rng.normal(size=(n, n)))[0]
    model = gf.LinearModel(F, rng.normal(size=(m, n)), _oracle.random_spd(rng, n), _oracle.random_spd(rng, m),
                           B=rng.normal(size=(n, 1)))
    zs, us = rng.normal(size=(400, m)), rng.normal(size=(400, 1))
    zs[rng.random(zs.shape) < missing] = np.nan
    zs[150:170] = np.nan
    prior = gf.Gaussian(rng.normal(size=n), np.eye(n))
    lin = Exact(model, us)
    assert lin.invariant
    fast, slow = run_filter(lin, prior, zs)[0], run_filter(_Plain(lin), prior, zs)[0]
    for name in ("means", "covs", "predicted_means", "predicted_covs", "innovations", "innovation_covs"):
        a, b = getattr(fast, name), getattr(slow, name)
        scale = np.nanmax(np.abs(b))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * scale, err_msg=name)
    np.testing.assert_allclose(fast.loglik, slow.loglik, rtol=1e-13)


def test_steady_state_is_reached_and_used():
    """W1's model reaches a fixed point within about a hundred steps, then steps reuse it."""
    from gaussfuse.linearize import Exact

    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    lin, steady = Exact(model), kalman.SteadyState()
    mean, cov = np.zeros(4), np.eye(4)
    for k in range(300):
        st_ = kalman.step(lin, k, mean, cov, np.array([0.1 * k, 0.0]), steady=steady)
        mean, cov = st_.update.mean, st_.update.cov
    assert steady.cov is cov  # the fixed point, reused (the same object every step)
    assert not Exact(gf.LinearModel(np.ones((3, 1, 1)), 1.0, 1.0, 1.0)).invariant


def test_settled_is_relative_to_each_entrys_variances():
    """settled() does not depend on the states' units, needs a zero variance to stay exactly zero, rejects NaN."""
    eps = kalman.SETTLED
    P = np.array([[4.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    assert kalman.settled(P, P)
    step = np.zeros((3, 3))
    step[0, 1] = step[1, 0] = 0.9 * eps * 2.0  # within SETTLED * sqrt(4 * 1)
    assert kalman.settled(P + step, P)
    assert not kalman.settled(P + 1.2 * step, P)
    for D in (np.diag([1e-6, 1e6, 1.0]), np.diag([1e150, 1e-150, 1.0])):  # the same decisions in other units
        assert kalman.settled(D @ (P + step) @ D, D @ P @ D)
        assert not kalman.settled(D @ (P + 1.2 * step) @ D, D @ P @ D)
    zero_moved = P.copy()
    zero_moved[2, 2] = 1e-300
    assert not kalman.settled(zero_moved, P)  # a zero variance has no round-off to allow
    nan = P.copy()
    nan[0, 0] = np.nan
    assert not kalman.settled(nan, P) and not kalman.settled(P, nan)


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("q", [1e-2, 1e-4, 1e-6])
def test_a_slowly_converging_fixed_point_is_kept_within_its_round_off_bound(q, engine):
    """A random walk whose covariance contracts slowly, against its analytic fixed point.

    For x_k = x_{k-1} + w, w ~ N(0, q), z = x + v, v ~ N(0, 1), the predicted
    variance's fixed point solves p² = q p + q, and the recursion contracts
    by ρ = 1/(1 + p) per step (1 - ρ ≈ √q). The covariance is kept once a
    step changes it by at most SETTLED, so it is within about
    SETTLED / (1 - ρ) of the fixed point: the bound asserted, with a factor 4
    for the round-off of the steps themselves.
    """
    p = (q + np.sqrt(q * q + 4.0 * q)) / 2.0
    exact = p / (1.0 + p)
    rho = 1.0 / (1.0 + p)
    T = int(40 / (1.0 - rho))  # about 40 time constants
    model = gf.LinearModel(1.0, 1.0, q, 1.0)
    zs = np.zeros((T, 1))
    res = gf.filter(model, gf.Gaussian([0.0], [[1.0]]), zs, engine=engine, keep="all")
    covs = res.covs[:, 0, 0]
    assert covs[-1] == covs[-2] == covs[-int(5 / (1.0 - rho))]  # kept: not computed again for the last steps
    assert abs(covs[-1] - exact) <= 4.0 * kalman.SETTLED / (1.0 - rho) * exact


# ---------------------------------------------------------------------------
# Accuracy against a 50-digit reference
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_a_huge_prior_and_a_precise_sensor_stay_within_2e_9_of_a_50_digit_filter(engine):
    """P⁻ shrinks by 10⁸ at the first update: the covariance form's hard case, still within reach.

    Measured: 1.5e-10 relative in the variances, 8.9e-10 standard deviations
    in the means, on both engines. Cheaper forms fail here: the symmetrised
    conventional P - K H P gives 1.7e-8 and 7.5e-8, the Joseph form expanded
    into P + G Kᵀ + K Gᵀ (G = K S/2 - P Hᵀ) 5.9e-9 and 8.2e-9. With
    P0 = 1e12·I and R = 1e-6 the Joseph form too is off by 74%: that needs the
    square-root form.
    """
    from _mp_oracle import filter_50_digits

    F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    Q, R = 1e-3 * np.eye(2), np.array([[1e-2]])
    prior = gf.Gaussian(np.zeros(2), 1e6 * np.eye(2))
    rng = np.random.default_rng(3)
    zs = np.cumsum(rng.standard_normal(60))[:, None] + 0.1 * rng.standard_normal((60, 1))
    means, covs = filter_50_digits(F, H, Q, R, prior.mean, prior.cov, zs)
    got = gf.filter(gf.LinearModel(F, H, Q, R), prior, zs, engine=engine)
    variances = np.diagonal(covs, axis1=1, axis2=2)
    assert np.max(np.abs(np.diagonal(got.covs, axis1=1, axis2=2) - variances) / variances) < 2e-9
    assert np.max(np.abs(got.means - means) / np.sqrt(variances)) < 2e-9
    assert np.array_equal(got.covs, np.swapaxes(got.covs, 1, 2))


# ---------------------------------------------------------------------------
# The gain: any gain's covariance is the Joseph form; the optimal gain minimises its trace
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_the_joseph_form_is_the_error_covariance_of_any_gain(seed):
    """update(..., gain=K): the estimator m⁻ + K v and its exact error covariance, from the joint Gaussian.

    The error ``(I - K H)(x - m⁻) - K v_noise`` is a linear map M of (x - m⁻,
    v_noise) ~ N(0, blockdiag(P⁻, R)), so its covariance is M blockdiag(P⁻, R) Mᵀ.
    """
    from scipy.linalg import block_diag

    rng = np.random.default_rng(seed)
    n, m = 4, 2
    P, R, H = _oracle.random_spd(rng, n), _oracle.random_spd(rng, m), rng.normal(size=(m, n))
    mean, z, K = rng.normal(size=n), rng.normal(size=m), rng.normal(size=(n, m))
    post = kalman.update(mean, P, z, H, R, gain=K)
    M = np.hstack([np.eye(n) - K @ H, -K])
    np.testing.assert_allclose(post.cov, M @ block_diag(P, R) @ M.T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(post.mean, mean + K @ (z - H @ mean), rtol=1e-13)
    np.testing.assert_array_equal(post.gain, K)
    # the log-likelihood is the measurement's predictive density, whatever the gain
    assert post.loglik == pytest.approx(kalman.update(mean, P, z, H, R).loglik, rel=1e-13)
    # a missing component: its column of K is not used
    z[1] = np.nan
    part = kalman.update(mean, P, z, H, R, gain=K)
    M1 = np.hstack([np.eye(n) - K[:, :1] @ H[:1], -K[:, :1]])
    np.testing.assert_allclose(part.cov, M1 @ block_diag(P, R[:1, :1]) @ M1.T, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_the_optimal_gain_minimises_the_trace_of_the_posterior_covariance(seed):
    """tr P(K* + εΔ) = tr P(K*) + ε² tr(Δ S Δᵀ): a minimum, and no other gain does better."""
    rng = np.random.default_rng(seed)
    n, m = 3, 2
    P, R, H = _oracle.random_spd(rng, n), _oracle.random_spd(rng, m), rng.normal(size=(m, n))
    mean, z = rng.normal(size=n), rng.normal(size=m)
    best = kalman.update(mean, P, z, H, R)
    S = H @ P @ H.T + R
    np.testing.assert_allclose(best.gain, P @ H.T @ np.linalg.inv(S), rtol=1e-12)
    for _ in range(20):
        D = rng.normal(size=(n, m))
        for eps in (1e-3, 0.1, 1.0):
            other = kalman.update(mean, P, z, H, R, gain=best.gain + eps * D)
            excess = np.trace(other.cov) - np.trace(best.cov)
            assert excess > 0
            assert excess == pytest.approx(eps**2 * np.trace(D @ S @ D.T), rel=1e-6, abs=1e-13)


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_a_variance_near_the_largest_float_is_finite_on_both_engines(engine):
    """Q = 1e308: P⁻ = 1 + 1e308 and S are finite, and the filtered variance is R's, 1 (the readable path's
    symmetrisation used to overflow, (P + Pᵀ) = 2e308, and raise where the compiled one did not)."""
    model = gf.LinearModel(F=1.0, H=1.0, Q=1e308, R=1.0)
    res = gf.filter(model, gf.Gaussian(1.0, 1.0), [1.0, 2.0, 3.0], engine=engine, check="off")
    np.testing.assert_array_equal(res.predicted_covs.ravel(), 1e308)
    np.testing.assert_allclose(res.covs.ravel(), 1.0, rtol=1e-15)
    np.testing.assert_allclose(res.means.ravel(), [1.0, 2.0, 3.0], rtol=1e-15)


@pytest.mark.parametrize("cov", [np.diag([np.inf, 1.0]), np.array([[np.nan]]),
                                 np.array([[1e12, 0, 0], [0, 1.0, 2.0], [0, 2.0, 1.0]]),
                                 np.array([[1.0, 0.9], [0.0, 1.0]])],
                         ids=["inf", "nan", "indefinite block", "not symmetric"])
def test_cov_factor_refuses_what_has_no_factor(cov):
    """An infinite variance became a zero one (a sensor with R = inf taken for a perfect one), NaN passed, an
    indefinite block beside 1e12 had a variance of 1 altered to 4, and a non-symmetric matrix was read from its
    lower triangle (audit O)."""
    with pytest.raises(np.linalg.LinAlgError, match=r"^the noise "):
        kalman.cov_factor(cov, "the noise")


def test_cov_factor_takes_every_rank_deficient_covariance_a_model_accepts():
    """Q = G Gᵀ of rank 2 in 3-D, which LinearModel accepts: the semi-definite Cholesky factorisation's last pivot
    was -1.2e-13 for 0 (56 ε of its variance, after a nearly dependent leading block), and simulate, the
    square-root filter and sample_posterior refused Q (audit V: about 1 random G in 80 in 3-D, 1 in 25 in
    6-D). Each such matrix has a factor to round-off on its components' scales; the indefinite block stays
    refused (test above)."""
    G = np.array([[1.0, -0.6], [-1.2, 0.8], [-0.6, -1.3]])
    Q = G @ G.T
    L = kalman.cov_factor(gf.LinearModel(F=np.eye(3), H=[1.0, 0.0, 0.0], Q=Q, R=1.0).Q, "Q")
    d = np.sqrt(np.diag(Q))
    assert np.array_equal(L, np.tril(L)) and np.all(np.abs(L @ L.T - Q) <= 1e-14 * np.outer(d, d))
    rng = np.random.default_rng(0)
    for n, rank in [(3, 2)] * 300 + [(6, 3)] * 100 + [(4, 1)] * 100:
        G = rng.standard_normal((n, rank)) * 10.0 ** rng.integers(-3, 4, size=(n, 1))  # rows on their own scales
        Q = gf.Gaussian(np.zeros(n), G @ G.T).cov
        L = kalman.cov_factor(Q)
        d = np.sqrt(np.diag(Q))
        assert np.array_equal(L, np.tril(L)) and np.all(np.abs(L @ L.T - Q) <= 1e-13 * np.outer(d, d)), (n, rank)


def test_cov_factor_refuses_a_block_that_is_indefinite_beside_a_large_variance():
    """[[1e12, 0, 0], [0, 1, c], [0, c, -1e-3]] (smallest eigenvalue -0.62 for c = 1): judging the -1e-3 on the
    1e12 scale accepted a factor whose L Lᵀ gives that component a variance of c² (audit R5)."""
    for c in (1.0, 10.0, 30.0, 1e-2, 1e-3):
        with pytest.raises(np.linalg.LinAlgError):
            kalman.cov_factor(np.array([[1e12, 0.0, 0.0], [0.0, 1.0, c], [0.0, c, -1e-3]]))
    # a correlation of 32 beside a variance of 1e-6, and a variance below 0 by more than the round-off check_psd
    # allows (8 n ε of 1e12 is 5.3e-3): a Gaussian refuses both, and so does the factor (review R7)
    for cov in (np.array([[1e12, 0.0, 0.0], [0.0, 1e-6, 1e-3], [0.0, 1e-3, -1e-3]]), np.diag([1e12, 1.0, -8e-3])):
        with pytest.raises(ValueError):
            gf.Gaussian(np.zeros(3), cov)
        with pytest.raises(np.linalg.LinAlgError):
            kalman.cov_factor(cov)


def test_cov_factor_takes_a_variance_below_zero_that_a_gaussian_accepts_as_round_off():
    """diag(1e12, 1, -1e-3): a Gaussian and a model accept the -1e-3 as a zero variance to the round-off of the
    1e12, and simulate and the square-root filter then refused that prior or Q (LinAlgError: no factor)."""
    P = np.diag([1e12, 1.0, -1e-3])
    P[0, 2] = P[2, 0] = 1e-4  # a covariance as small as the variance beside it
    prior, Q = gf.Gaussian(np.zeros(3), P), gf.LinearModel(F=np.eye(3), H=np.eye(3), Q=P, R=np.eye(3)).Q
    for cov in (prior.cov, Q):
        L = kalman.cov_factor(cov)
        np.testing.assert_array_equal(L @ L.T, np.diag([1e12, 1.0, 0.0]))
    model = gf.LinearModel(F=np.eye(3), H=np.eye(3), Q=Q, R=np.eye(3))
    sim = gf.simulate(model, prior, 4, rng=0)
    assert np.all(np.diff(np.asarray(sim.states)[:, 2]) == 0.0)  # a component of zero variance does not move
    zs = np.ones((3, 3))
    sqrt, cov = gf.filter(model, prior, zs, form="sqrt").means, gf.filter(model, prior, zs).means
    np.testing.assert_allclose(sqrt[:, :2], cov[:, :2], rtol=1e-12)
    assert np.all(sqrt[:, 2] == 0.0)  # the covariance form moves it by the -1e-3, a round-off of the 1e12's


def test_cov_factor_keeps_valid_singular_and_graded_covariances():
    for cov in (np.diag([1e300, 1e-300, 0.0]), np.ones((2, 2)), np.zeros((3, 3))):
        L = kalman.cov_factor(cov)
        np.testing.assert_allclose(L @ L.T, cov, rtol=1e-15, atol=0)


def test_an_empty_measurement_observes_nothing():
    """Audit OO3: m = 0 raised an IndexError from the Cholesky wrapper in `update` and `cov_factor`, and
    `update_sqrt` reported nis = 0 and loglik = -0.0 where an all-missing z gives NaN and 0."""
    mean, cov = np.array([1.0, 2.0]), np.array([[2.0, 0.5], [0.5, 1.0]])
    z, H, R = np.zeros(0), np.zeros((0, 2)), np.zeros((0, 0))
    missing = kalman.update(mean, cov, np.array([np.nan]), np.eye(1, 2), np.eye(1))
    for got in (kalman.update(mean, cov, z, H, R), kalman.update_sqrt(mean, kalman.cov_factor(cov), z, H, R)):
        np.testing.assert_array_equal(got.mean, mean)
        assert got.loglik == missing.loglik == 0.0 and np.isnan(got.nis) and np.isnan(missing.nis)
    assert kalman.cov_factor(np.zeros((0, 0))).shape == (0, 0)


def test_with_nothing_observed_the_posterior_is_the_callers_prediction_as_documented():
    """`update` and `update_sqrt` say their posterior is `mean` and `cov` (or `factor`) themselves when nothing is
    observed (audit OO5: it was undocumented)."""
    mean, cov = np.zeros(2), np.eye(2)
    got = kalman.update(mean, cov, np.array([np.nan]), np.eye(1, 2), np.eye(1))
    assert got.mean is mean and got.cov is cov
    got = kalman.update_sqrt(mean, cov, np.array([np.nan]), np.eye(1, 2), np.eye(1))
    assert got.mean is mean and got.factor is cov


@pytest.mark.parametrize("args, error, match", [
    ((1.5,), ValueError, r"^`probability` must be a probability in \(0, 1\), such as 0\.99; got 1\.5\.$"),
    (("0.99",), TypeError, r"^`probability` must be a probability in \(0, 1\), such as 0\.99; got str '0\.99'\.$"),
    ((True,), TypeError, r"^`probability` must be a probability .* got bool True\.$"),
    ((0.9, "x"), ValueError, r"^`by` must be 'measurement' or 'component'; got 'x'\.$"),
])
def test_a_gate_names_its_own_arguments(args, error, match):
    """Audit OO4: `Gate(1.5)` said "`gate` must be ..." and `Gate(0.9, "x")` "`gate_by` ...", the front functions'
    names, and a string was a ValueError. Through the front functions the names are theirs."""
    with pytest.raises(error, match=match):
        kalman.Gate(*args)
    with pytest.raises(error, match=match.replace("`probability`", "`gate`").replace("`by`", "`gate_by`")):
        kalman.Gate.of(*args)
    assert kalman.Gate(np.int64(0) + 0.5).probability == 0.5 and kalman.Gate.of(None) is None


def test_correct_with_nothing_observed_returns_the_callers_prediction_as_documented():
    """Review R45: `correct` and `correct_sqrt` hand back the caller's own arrays too; their docstrings say so now."""
    model = gf.LinearModel(F=np.eye(2), H=[[1.0, 0.0]], Q=np.eye(2), R=1.0)
    lin = gf.METHODS["kf"].strategy(model, None)  # the Kalman filter's linearisation: the model itself
    mean, cov = np.zeros(2), np.eye(2)
    post = kalman.correct(lin, 0, mean, cov, np.array([np.nan]))[0]
    assert post.mean is mean and post.cov is cov
    post = kalman.correct_sqrt(lin, 0, mean, cov, np.array([np.nan]), kalman.Factors())
    assert post.mean is mean and post.factor is cov
