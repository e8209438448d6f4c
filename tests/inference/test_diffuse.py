"""Exact diffuse initialisation against Koopman's analytic case, statsmodels' exact diffuse filter and the large-prior limit."""

import numpy as np
import pytest
import statsmodels.api as sm

import gaussfuse as gf
from gaussfuse.datasets import nile

SIG_EPS, SIG_ETA = 15099.0, 1469.1


def _local_level():
    return gf.LinearModel(F=1, H=1, Q=SIG_ETA, R=SIG_EPS)


def test_local_level_first_observation_koopman():
    """After y_1 the filtered state is y_1 with variance σ²_ε; the next prediction has σ²_ε + σ²_η."""
    _, flow = nile()
    res = gf.filter(_local_level(), "diffuse", flow)
    assert res.means[0, 0] == pytest.approx(flow[0], rel=1e-14)
    assert res.covs[0, 0, 0] == pytest.approx(SIG_EPS, rel=1e-12)
    assert res.predicted_covs[1, 0, 0] == pytest.approx(SIG_EPS + SIG_ETA, rel=1e-12)
    assert np.isnan(res.predicted_means[0, 0]) and np.isnan(res.innovations[0, 0])
    assert np.isfinite(res.means).all()


def test_nile_against_statsmodels_exact_diffuse():
    _, flow = nile()
    ref = sm.tsa.UnobservedComponents(flow, "local level", use_exact_diffuse=True).smooth([SIG_EPS, SIG_ETA])
    res = gf.filter(_local_level(), "diffuse", flow)
    sm_res = gf.smooth(_local_level(), "diffuse", flow)
    assert res.loglik == pytest.approx(ref.llf, rel=1e-12)
    np.testing.assert_allclose(res.means[:, 0], ref.filtered_state[0], rtol=1e-11)
    np.testing.assert_allclose(res.covs[:, 0, 0], ref.filtered_state_cov[0, 0], rtol=1e-10)
    np.testing.assert_allclose(res.predicted_means[1:, 0], ref.predicted_state[0, 1:-1], rtol=1e-11)
    np.testing.assert_allclose(sm_res.means[:, 0], ref.smoothed_state[0], rtol=1e-11)
    np.testing.assert_allclose(sm_res.covs[:, 0, 0], ref.smoothed_state_cov[0, 0], rtol=1e-10)


def test_local_linear_trend_with_missing_data_against_statsmodels():
    rng = np.random.default_rng(3)
    T = 60
    level = np.cumsum(np.cumsum(0.1 * rng.standard_normal(T)) + 0.5)
    y = level + rng.standard_normal(T)
    y[[0, 5, 6, 30]] = np.nan
    s_eps, s_level, s_trend = 1.2, 0.3, 0.05
    ref = sm.tsa.UnobservedComponents(y, "local linear trend", use_exact_diffuse=True).smooth(
        [s_eps, s_level, s_trend])
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([s_level, s_trend]), R=s_eps)
    res = gf.smooth(model, "diffuse", y)
    assert res.loglik == pytest.approx(ref.llf, rel=1e-11)
    np.testing.assert_allclose(res.means, ref.smoothed_state.T, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.covs, np.moveaxis(ref.smoothed_state_cov, -1, 0), rtol=1e-8, atol=1e-9)
    identified = np.isfinite(res.filtered.means[:, 0])
    np.testing.assert_allclose(res.filtered.means[identified], ref.filtered_state.T[identified], rtol=1e-9, atol=1e-9)
    assert not identified[:2].any() and identified[2:].all()  # y_1 is missing; y_2, y_3 identify level and slope


def test_diffuse_is_the_limit_of_a_wide_prior():
    """ℓ_κ + (n/2) log κ → ℓ_d, and the beliefs converge, as a prior N(0, κ I) on x_1 widens.

    x_1 is the diffuse state: a prior on x_0 of N(0, κ F⁻¹ F⁻ᵀ) gives x_1 a
    covariance κ I + Q, whatever F.
    """
    rng = np.random.default_rng(0)
    F = np.array([[1, 0.5], [0, 0.9]])
    model = gf.LinearModel(F=F, H=[[1, 0], [0.3, 1]], Q=np.diag([0.2, 0.1]), R=np.eye(2), B=[[0.5], [1.0]])
    zs, us = rng.standard_normal((25, 2)), rng.standard_normal((25, 1))
    zs[3, 1] = np.nan
    exact = gf.smooth(model, "diffuse", zs, us)
    kappa = 1e7
    F_inv = np.linalg.solve(F, np.eye(2))
    x0 = gf.Gaussian(-F_inv @ model.B[:, 0] * us[0, 0], kappa * F_inv @ F_inv.T)
    wide = gf.smooth(model, x0, zs, us)
    assert wide.loglik + np.log(kappa) == pytest.approx(exact.loglik, abs=1e-5)
    np.testing.assert_allclose(wide.means, exact.means, atol=1e-5)
    np.testing.assert_allclose(wide.covs, exact.covs, atol=1e-5)
    np.testing.assert_allclose(wide.filtered.means[1:], exact.filtered.means[1:], atol=1e-5)


@pytest.mark.parametrize("ar", [[0.5], [2.0], [-1.3], [0.0], [0.5, 0.2], [0.3, 0.0]])
def test_first_state_is_diffuse_as_in_statsmodels_for_every_f(ar):
    """x_1 is diffuse: the log-likelihood equals statsmodels' exact diffuse one whether
    |det F| is 1 or not, and for a singular F (an AR(p) in companion form, φ_p = 0 or p = 1, φ = 0)."""
    rng = np.random.default_rng(1)
    y = np.cumsum(rng.standard_normal(120)) * 0.1 + rng.standard_normal(120)
    y[[4, 50]] = np.nan
    p, r, q = len(ar), 0.6, 1.0
    ref = sm.tsa.SARIMAX(y, order=(p, 0, 0), measurement_error=True, initialization="diffuse")
    F = np.zeros((p, p))
    F[:, 0], F[:-1, 1:] = ar, np.eye(p)[:-1, :-1]
    Q = np.zeros((p, p))
    Q[0, 0] = q
    model = gf.LinearModel(F=F, H=np.eye(p)[0], Q=Q, R=r)
    assert gf.filter(model, "diffuse", y).loglik == pytest.approx(ref.loglike([*ar, r, q]), rel=1e-10)
    # the transition into x_1 plays no part
    changed = gf.LinearModel(F=np.ones((120, p, p)) * F, H=model.H, Q=np.ones((120, p, p)) * Q, R=r)
    first = np.array(changed.F)
    first[0] = 7 * np.eye(p)
    again = gf.LinearModel(F=first, H=model.H, Q=changed.Q, R=r)
    assert gf.filter(again, "diffuse", y).loglik == pytest.approx(gf.filter(model, "diffuse", y).loglik,
                                                                  rel=1e-12)


def test_noise_free_first_measurement():
    """R = 0 and no noise into the measured state: the first innovation covariance of the
    augmented runs would be singular; the result still equals statsmodels'."""
    rng = np.random.default_rng(4)
    y = np.cumsum(np.cumsum(0.1 * rng.standard_normal(40)))
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([0.0, 0.1]), R=0.0)
    ref = sm.tsa.UnobservedComponents(y, "smooth trend", use_exact_diffuse=True)
    sm_res = gf.smooth(model, "diffuse", y)
    assert sm_res.loglik == pytest.approx(ref.loglike([0.0, 0.1]), rel=1e-10)
    np.testing.assert_allclose(sm_res.means[:, 0], y, rtol=1e-9, atol=1e-9)


def test_nis_is_that_of_the_filter_restarted_from_the_identified_belief():
    """Markov property: once x is identified at step d, the rest of the diffuse filter is the proper
    filter started from the belief after step d, NIS included (NaN before, and where nothing is observed).
    The NIS was None for a diffuse prior, which broke the command's per-series filter."""
    rng = np.random.default_rng(5)
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[[1, 0]], Q=np.diag([0.3, 0.05]), R=1.2)
    y = np.cumsum(np.cumsum(0.1 * rng.standard_normal(40))) + rng.standard_normal(40)
    y[[0, 7, 8]] = np.nan
    res = gf.filter(model, "diffuse", y)
    d = 2  # y_2 and y_3 identify level and slope
    assert np.isnan(res.nis[:d + 1]).all()
    rest = gf.filter(model, gf.Gaussian(res.means[d], res.covs[d]), y[d + 1:], check="off")
    np.testing.assert_allclose(res.nis[d + 1:], rest.nis, rtol=1e-9, equal_nan=True)
    assert np.isnan(res.nis[[7, 8]]).all() and np.isfinite(np.delete(res.nis, [0, 1, 2, 7, 8])).all()
    smoothed = gf.smooth(model, "diffuse", y)
    np.testing.assert_array_equal(smoothed.filtered.nis, res.nis)


def test_divergence_check_runs_with_a_diffuse_prior():
    _, flow = nile()
    wrong = gf.LinearModel(F=1, H=1, Q=SIG_ETA / 100, R=SIG_EPS / 100)  # noise 100 times too small
    for run in (gf.filter, gf.smooth):
        with pytest.raises(gf.DivergenceWarning, match="over steps"):
            run(wrong, "diffuse", flow, check="raise")
        run(_local_level(), "diffuse", flow, check="raise")  # the fitted model passes


def test_batch_and_keep():
    _, flow = nile()
    zs = np.stack([flow, flow[::-1]])[:, :, None]
    batch = gf.filter(_local_level(), "diffuse", zs, keep="means")
    single = gf.filter(_local_level(), "diffuse", flow[::-1])
    np.testing.assert_allclose(batch.means[1], single.means, rtol=1e-13)
    assert batch.covs is None and batch.loglik.shape == (2,)
    last = gf.filter(_local_level(), "diffuse", flow, keep="last")
    assert last.means is None and last.last_cov[0, 0] > 0


def test_not_identified_and_wrong_uses():
    # the velocity of a state that never moves position is invisible
    model = gf.LinearModel(F=np.eye(2), H=[1, 0], Q=np.eye(2), R=1.0)
    with pytest.raises(ValueError, match="the diffuse initial state is not identified by the measurements"):
        gf.filter(model, "diffuse", np.ones(5))
    with pytest.raises(ValueError, match="the diffuse initial state is not identified"):
        gf.filter(_local_level(), "diffuse", np.full(3, np.nan))
    nonlinear = gf.NonlinearModel(lambda x: x, lambda x: x, 1.0, 1.0)
    with pytest.raises(TypeError, match=r"`prior` must be a gaussfuse.Gaussian\(mean, cov\); got 'diffuse'"):
        gf.filter(nonlinear, "diffuse", np.ones(3))
