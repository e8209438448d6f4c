"""Exact diffuse initialisation against Koopman's analytic case, statsmodels' exact diffuse filter and the large-prior limit."""

import warnings

import numpy as np
import pytest
import statsmodels.api as sm

import gaussfuse as gf
from gaussfuse.datasets import nile

from _mp_oracle import smooth_50_digits, smooth_dense_50_digits

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


@pytest.mark.parametrize("F, H, variances, kfas, diffuse", [
    # KFAS's log-likelihoods at its estimates (R = the first variance, Q the rest) of US unemployment, as published
    # in statsmodels' tsa/statespace/tests/results/results_structural.py (from its test_ucm.R; BSD licence)
    (1.0, 1.0, [4.256647886e-06, 0.1182078808], -70.97242557, 1),
    ([[1, 1], [0, 1]], [1, 0], [1.339852549e-06, 0.01008704925, 0.0609176081], -31.15640107, 2),
], ids=["local level", "local linear trend"])
def test_kfas_reports_the_diffuse_log_likelihood_without_the_constant_of_its_diffuse_observations(
        F, H, variances, kfas, diffuse):
    """Audit Z2: the docs said the exact diffuse log-likelihood equals KFAS's. It is Durbin & Koopman's (eq. 7.4) and
    statsmodels', whose every observation carries -½ log 2π; KFAS leaves it out for the d observations that identify
    x₁, so it is d·½ log 2π higher."""
    unemployment = sm.datasets.macrodata.load_pandas().data["unemp"].to_numpy()
    model = gf.LinearModel(F=F, H=H, Q=np.diag(variances[1:]), R=variances[0])
    ours = gf.filter(model, "diffuse", unemployment, check="off").loglik
    assert ours + diffuse * 0.5 * np.log(2 * np.pi) == pytest.approx(kfas, abs=2e-7)  # KFAS's 10 digits
    ref = sm.tsa.UnobservedComponents(unemployment, "local level" if diffuse == 1 else "local linear trend",
                                      use_exact_diffuse=True).loglike(variances)
    assert ours == pytest.approx(ref, rel=1e-9)


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


def _trend_limit(zs, R, kappa=1e40, digits=200):
    """The smoothed moments of a local linear trend (Q = diag(1, 0)) with x_1 ~ N(0, κ I + Q), in `digits`:
    the prior on x_0 is N(0, κ F⁻¹ F⁻ᵀ) (see the test above), and κ = 1e40 is the diffuse limit to 1e-40."""
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    F_inv = np.linalg.solve(F, np.eye(2))
    return smooth_50_digits(F, [[1.0, 0.0]], np.diag([1.0, 0.0]), R, np.zeros(2), kappa * F_inv @ F_inv.T, zs,
                            digits=digits)


def _trend(Q, R):
    return gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=Q, R=R)


@pytest.mark.parametrize("q0", [1e8, 1e16])
def test_the_noise_into_the_first_state_plays_no_part_at_any_size(q0):
    """Audit SS2-3: the augmentation took its free covariance P_* from Q_1, the noise into x_1, which the docs say
    plays no part; a user's Q_1 = 1e16 I (a wide guess, say) cost the smoothed variance of x_1 37% (1.0 for
    0.7255), as the runs lost ε P_* to cancellation. P_* is Q_2 now, the model's own."""
    T = 10
    zs = np.random.default_rng(4).normal(size=T).cumsum()
    zs[2] = np.nan
    Q = np.diag([1.0, 0.1])
    Qs = np.stack([q0 * np.eye(2)] + [Q] * (T - 1))
    wide, same = (gf.smooth(_trend(q, 1.0), "diffuse", zs) for q in (Qs, Q))
    assert wide.loglik == pytest.approx(same.loglik, rel=1e-13)
    np.testing.assert_allclose(wide.means, same.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(wide.covs, same.covs, rtol=1e-12, atol=1e-12)


def test_a_noisy_first_measurement_does_not_set_the_scale_of_the_runs():
    """Audit SS2-2: with a singular Q, P_* was widened by the largest variance of Q_1 and R_1, so a first
    measurement of variance 1e16 (a time-varying R) cost every smoothed covariance ε·1e16 (5.9 at step 0, for
    entries of 1.8 and below). It is widened on the process noise's scale now. Oracle: the κ → ∞ limit in 200
    digits."""
    T = 15
    zs = np.random.default_rng(4).normal(size=T).cumsum()
    R = np.ones((T, 1, 1))
    R[0] = 1e16
    means, covs = _trend_limit(zs, R)
    res = gf.smooth(_trend(np.diag([1.0, 0.0]), R), "diffuse", zs)
    np.testing.assert_allclose(res.means, means, rtol=0, atol=1e-13 * np.abs(means).max())
    np.testing.assert_allclose(res.covs, covs, rtol=0, atol=1e-14 * np.abs(covs).max())


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_a_noisy_first_measurement_without_process_noise_is_weighted_least_squares(engine):
    """Review R47: without process noise the widening still took R_1's variance, 1e16, and the smoothed level
    variance at step 0 was 4.9e-16 (compiled) for 0.714. Oracle: with Q = 0, x_k = F^k x_1 and x_1 given z is the
    weighted least-squares fit under a flat prior."""
    T = 8
    z = np.random.default_rng(5).normal(size=T).cumsum()
    F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    R = np.ones((T, 1, 1))
    R[0] = 1e16
    A = np.array([(H @ np.linalg.matrix_power(F, k))[0] for k in range(T)])
    C = np.linalg.inv((A.T / R[:, 0, 0]) @ A)
    x1 = C @ ((A.T / R[:, 0, 0]) @ z)
    res = gf.smooth(gf.LinearModel(F, H, np.zeros((2, 2)), R), "diffuse", z, engine=engine)
    powers = [np.linalg.matrix_power(F, k) for k in range(T)]
    np.testing.assert_allclose(res.means, [P @ x1 for P in powers], rtol=0, atol=1e-13)
    np.testing.assert_allclose(res.covs, [P @ C @ P.T for P in powers], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("Q, R", [(np.diag([1.0, 0.1]), 1.0), (np.diag([0.0, 0.1]), 0.0)], ids=["noisy", "exact"])
def test_smoother_gains_give_the_lag_one_covariances(Q, R):
    """Audit SS2-1: the gains were the augmentation's base run's (x_1 ~ N(·, P_*) given δ), not the model's, so
    ``G_k P^s_{k+1}``, the lag-one covariance the result documents, was 0.125 off at k = 0 and 0.005 at k = 6.
    Oracle: dense joint-Gaussian conditioning in 200 digits with x_1 ~ N(0, 1e40 I); the first gains are before
    the slope is identified (k = 0). The second model's sensor is exact, where the base run's gains happen to be
    the model's (review R47: that case passed before the fix); it holds the formula's singular solves."""
    T = 8
    zs = np.random.default_rng(4).normal(size=T).cumsum()
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    F_inv = np.linalg.solve(F, np.eye(2))
    means, covs, lag = smooth_dense_50_digits(F, [[1.0, 0.0]], Q, R, np.zeros(2), 1e40 * F_inv @ F_inv.T, zs,
                                             digits=200, lag_one=True)
    res = gf.smooth(_trend(Q, R), "diffuse", zs)
    scale = np.abs(covs).max()
    np.testing.assert_allclose(res.covs, covs, rtol=0, atol=1e-14 * scale)
    assert np.isnan(res.filtered.means[0]).all()  # x_1 is not identified after the first step
    np.testing.assert_allclose(res.gains @ res.covs[1:], lag, rtol=0, atol=1e-14 * scale)


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


def _statsmodels_diffuse(F, H, Q, R, zs):
    """statsmodels' exact diffuse filter of the model (F, H, Q, R): (loglik, filtered means, variances)."""
    from statsmodels.tsa.statespace.mlemodel import MLEModel

    n = F.shape[0]
    mod = MLEModel(zs, k_states=n, k_posdef=n)
    for name, value in dict(transition=F, design=np.atleast_2d(H), selection=np.eye(n), state_cov=Q,
                            obs_cov=np.atleast_2d(R)).items():
        mod.ssm[name] = value
    mod.ssm.initialize_diffuse()
    res = mod.ssm.filter()
    return res.llf_obs.sum(), res.filtered_state.T, np.diagonal(res.filtered_state_cov, axis1=0, axis2=1)


def _case_two_sensors():  # a coarse sensor (R = 1) beside a precise one (1e-13): identified at step 0
    return (np.eye(2), np.eye(2), np.zeros((2, 2)), np.diag([1.0, 1e-13]),
            np.array([[1.0, 2.0], [1.2, 2.0 + 3e-7], [0.9, 2.0 - 2e-7]]))


def _case_quadratic_trend():  # a deterministic quadratic trend over 3,000 steps: information T, T³, T⁵
    rng = np.random.default_rng(4)
    t = np.arange(3000)
    y = 0.5 + 0.01 * t + 1e-5 * t**2 + rng.standard_normal(t.size)
    return (np.array([[1.0, 1, 0], [0, 1, 1], [0, 0, 1]]), np.array([[1.0, 0, 0]]), np.zeros((3, 3)),
            np.eye(1), y[:, None])


def _case_noise_free_sensor_seen_late():  # the noise-free sensor first reports at step 1
    return (np.eye(2), np.eye(2), np.zeros((2, 2)), np.diag([1.0, 0.0]),
            np.array([[1.0, np.nan], [1.2, 3.0], [0.9, np.nan], [1.1, np.nan]]))


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("case", [_case_two_sensors, _case_quadratic_trend, _case_noise_free_sensor_seen_late])
def test_identification_does_not_depend_on_units_or_length(case, engine):
    """The identification test compared the information's eigenvalues with 1e-12 of the largest: a precise
    sensor beside a coarse one, a quadratic trend past 1,500 steps and a component in other units raised
    NotIdentified (so did fit), where statsmodels' exact diffuse filter gives the answer. A noise-free sensor
    first seen after step 0 gave a singular S "where the state is known exactly"; it is diffuse there."""
    F, H, Q, R, zs = case()
    loglik, means, variances = _statsmodels_diffuse(F, H, Q, R, zs)
    got = gf.filter(gf.LinearModel(F=F, H=H, Q=Q, R=R), "diffuse", zs, engine=engine)
    assert got.loglik == pytest.approx(loglik, rel=1e-9)
    last = slice(-2, None)
    assert np.all(np.abs(got.means[last] - means[last]) <= 1e-9 * np.abs(means[last]).max(axis=0))
    got_variances = np.diagonal(got.covs[last], axis1=1, axis2=2)
    assert np.all(np.abs(got_variances - variances[last]) <= 1e-7 * variances[last] + 1e-12 * variances.max())


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_a_component_in_other_units_is_identified_as_in_its_own(engine):
    """Two random walks, the second's state in units 1e6 smaller (H = diag(1, 1e-6), Q = diag(1, 1e12)):
    NotIdentified, where in its own units the same data identify it at step 0. With the flat prior on the
    scaled state, the filtered means are the unscaled ones times [1, 1e6], and the diffuse log-likelihood is
    theirs plus ½ log 1e12 (a flat prior diag(1, 1e-12) on the unscaled state; statsmodels' exact diffuse
    filter gives -20.09 here, where a 250-digit filter from κ = 1e80 gives ours, -6.0196). The unscaled model
    against statsmodels."""
    zs = np.random.default_rng(2).standard_normal((6, 2))
    plain = gf.filter(gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.eye(2), R=np.eye(2)), "diffuse", zs,
                      engine=engine)
    loglik, means, _ = _statsmodels_diffuse(np.eye(2), np.eye(2), np.eye(2), np.eye(2), zs)
    assert plain.loglik == pytest.approx(loglik, rel=1e-12)
    np.testing.assert_allclose(plain.means, means, rtol=1e-12, atol=1e-14)
    scaled = gf.filter(gf.LinearModel(F=np.eye(2), H=np.diag([1.0, 1e-6]), Q=np.diag([1.0, 1e12]), R=np.eye(2)),
                       "diffuse", zs, engine=engine)
    assert scaled.loglik == pytest.approx(plain.loglik + 0.5 * np.log(1e12), rel=1e-12)
    np.testing.assert_allclose(scaled.means, plain.means * [1.0, 1e6], rtol=1e-9)


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("q, r", [(1e-20, 1e-22), (2.11e-73, 1.08e-85)])
def test_a_constant_series_far_from_zero_in_units_of_tiny_noise(q, r, engine):
    """A stuck sensor reading 3.0 under a local level with noise far below it: the data are exact, so their
    diffuse likelihood is that of zeros. One recentring left innovations of 3 ε, 1e21 and 1e36 standard
    deviations: the loglik was 7.7e25 where it is 4053.93 (audit Y2; `fit` went there). The base run is
    recentred until it starts near the estimate."""
    model = gf.LinearModel(F=1.0, H=1.0, Q=q, R=r)
    stuck = gf.filter(model, "diffuse", np.full(50, 3.0), engine=engine, check="off")
    zero = gf.filter(model, "diffuse", np.zeros(50), engine=engine, check="off")
    assert stuck.loglik == pytest.approx(zero.loglik, rel=1e-12)
    np.testing.assert_allclose(stuck.covs, zero.covs, rtol=1e-9)
    np.testing.assert_array_equal(stuck.means[1:], 3.0)


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("level", [1e6, 1e8, 1e10])
def test_data_far_from_zero_keep_the_diffuse_likelihood(level, engine):
    """Under a flat x_1, adding a level to a local level's data (or a level and a slope to a local linear
    trend's) changes nothing: data ``z + level`` have the likelihood of ``(z + level) - level`` (exact, by
    Sterbenz), up to the round-off of innovations of the size of the level (about T eps level / noise, as in
    statsmodels). From x_0 = 0, the likelihood was a difference of two terms of size (level / noise)²: with
    unit noise it was off by 4.6e-4 at 1e6, 2.1 at 1e8 and +20480.24 for -189.16 at 1e10 (audit W), and
    ``fit`` learned Q = 0.55 for 0.82 at 1e8."""
    rng = np.random.default_rng(0)
    T = 100
    walk = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    z = np.cumsum(rng.normal(size=T)) + rng.normal(size=T)
    trend = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.5, 0.01]), R=1.0)
    y = np.cumsum(np.cumsum(0.1 * rng.normal(size=T))) + rng.normal(size=T) + 1e-3 * level * np.arange(T) / T
    y[[3, 10, 50]] = np.nan
    for model, data in ((walk, z + level), (trend, y + level)):
        near = data - level
        far_filter = gf.filter(model, "diffuse", data, engine=engine, check="off")
        near_filter = gf.filter(model, "diffuse", near, engine=engine, check="off")
        assert far_filter.loglik == pytest.approx(near_filter.loglik, abs=T * 1e-15 * level)
        far_smooth, near_smooth = gf.smooth(model, "diffuse", data, engine=engine), gf.smooth(model, "diffuse", near,
                                                                                                engine=engine)
        assert far_smooth.loglik == pytest.approx(near_smooth.loglik, abs=T * 1e-15 * level)
        np.testing.assert_allclose(far_smooth.means[:, 0] - level, near_smooth.means[:, 0], rtol=0, atol=1e-14 * level)
        np.testing.assert_allclose(far_smooth.covs, near_smooth.covs, rtol=1e-9)
    if level == 1e8:  # the likelihood is known to about 4e-8 there: the search may stop on precision loss
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", gf.ConvergenceWarning)
            learned = [gf.fit(walk, "diffuse", data, learn=("Q", "R"), method="mle", engine=engine).model
                       for data in (z + level, z)]
        np.testing.assert_allclose([learned[0].Q[0, 0], learned[0].R[0, 0]], [learned[1].Q[0, 0], learned[1].R[0, 0]],
                                   rtol=1e-3)


def test_an_overflow_of_the_assembled_beliefs_is_a_floating_point_error():
    """The Nile in units of 1e152: the innovation variance, 1e308 and more, overflows where the diffuse filter
    assembles its beliefs, past the checked runs; a ValueError named an internal `innovation_covs`, where filter
    and fit promise the FloatingPointError of an overflow (audit EE1)."""
    y = np.asarray(nile()[1], dtype=float) * 1e152
    model = gf.LinearModel(F=1, H=1, Q=1e3 * 1e304, R=1e4 * 1e304)
    message = r"^at step 1: the predicted measurement mean or covariance is not finite \(inf or NaN\)"
    with pytest.raises(FloatingPointError, match=message):
        gf.filter(model, "diffuse", y)
    with pytest.raises(FloatingPointError, match=message):
        gf.fit(model, "diffuse", y, method="mle")
    assert np.isfinite(gf.filter(gf.LinearModel(F=1, H=1, Q=1e3 * 1e296, R=1e4 * 1e296), "diffuse",
                                 y * 1e-4).innovation_covs[1:]).all()  # 1e300 is fine


def test_an_information_that_overflows_is_a_floating_point_error():
    """Audit SS2-4: at variances of 1e-308 the information about the diffuse state (1/variance, summed over steps)
    overflowed, and filter and smooth returned a log-likelihood of -inf and means 6% off with only NumPy's
    RuntimeWarnings. Down to 1e-300 the results scale exactly (the data by c, the variances by c²)."""
    z = np.random.default_rng(0).normal(size=10).cumsum()
    Q = np.diag([1.0, 0.1])
    unit = gf.smooth(_trend(Q, 1.0), "diffuse", z)
    c = 1e-150
    scaled = gf.smooth(_trend(Q * c**2, c**2), "diffuse", z * c)
    assert scaled.loglik == pytest.approx(unit.loglik - 8 * np.log(c), rel=1e-13)  # 10 observations, 2 diffuse
    np.testing.assert_allclose(scaled.means / c, unit.means, rtol=1e-13)
    c = np.sqrt(1e-308)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for run in (gf.filter, gf.smooth):
            with pytest.raises(FloatingPointError, match=r"^at step 4: the filtered mean, covariance or "
                                                         r"log-likelihood is not finite \(inf or NaN\)"):
                run(_trend(Q * c**2, c**2), "diffuse", z * c)
