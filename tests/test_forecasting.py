"""gf.forecast: against statsmodels' get_forecast, the closed form of a linear forecast, and the sigma-point path."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import statsmodels.api as sm

import gaussfuse as gf


def _local_linear_trend():
    rng = np.random.default_rng(3)
    T = 60
    level = np.cumsum(np.cumsum(0.1 * rng.standard_normal(T)) + 0.5)
    y = level + rng.standard_normal(T)
    y[[0, 5, 6, 30, 59]] = np.nan  # the last one missing too: the forecast starts from a prediction
    return y, (1.2, 0.3, 0.05)


@pytest.mark.parametrize("steps", [1, 12])
def test_forecast_equals_statsmodels_get_forecast(steps):
    """Local linear trend, exact diffuse start, missing values: means, variances and 95% intervals to 1e-9."""
    y, (s_eps, s_level, s_trend) = _local_linear_trend()
    ref = sm.tsa.UnobservedComponents(y, "local linear trend", use_exact_diffuse=True).smooth(
        [s_eps, s_level, s_trend]).get_forecast(steps=steps)
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([s_level, s_trend]), R=s_eps)
    fc = gf.forecast(model, gf.filter(model, "diffuse", y), steps)
    np.testing.assert_allclose(fc.measurement_means[:, 0], ref.predicted_mean, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(fc.measurement_covs[:, 0, 0], ref.var_pred_mean, rtol=1e-10)
    lower, upper = fc.interval(0.95)
    np.testing.assert_allclose(np.column_stack([lower[:, 0], upper[:, 0]]), ref.conf_int(alpha=0.05), rtol=1e-10)
    # states: the level is the measurement's mean, its variance that of the measurement less R
    np.testing.assert_allclose(fc.means[:, 0], fc.measurement_means[:, 0], rtol=1e-14)
    np.testing.assert_allclose(fc.covs[:, 0, 0] + s_eps, fc.measurement_covs[:, 0, 0], rtol=1e-12)


def test_forecast_with_controls_is_the_closed_form():
    """k steps of x = F x + B u + w from N(m, P): F^k m + Σ F^(k-j) B u_j and F^k P F^kᵀ + Σ F^(k-j) Q F^(k-j)ᵀ."""
    rng = np.random.default_rng(0)
    F = np.array([[1.0, 0.5, 0.0], [0.0, 0.9, 0.2], [0.0, 0.0, 0.7]])
    B, H = rng.normal(size=(3, 2)), rng.normal(size=(2, 3))
    Q, R = np.diag([0.1, 0.0, 0.3]), np.array([[0.5, 0.1], [0.1, 0.2]])
    model = gf.LinearModel(F, H, Q, R, B)
    belief = gf.Gaussian(rng.normal(size=3), np.eye(3) + 0.1)
    us = rng.normal(size=(5, 2))
    fc = gf.forecast(model, belief, 5, us)
    mean, cov = belief.mean, belief.cov
    for k in range(5):
        Fk = np.linalg.matrix_power(F, k + 1)
        mean_k = Fk @ belief.mean + sum(np.linalg.matrix_power(F, k - j) @ B @ us[j] for j in range(k + 1))
        cov_k = Fk @ belief.cov @ Fk.T + sum(np.linalg.matrix_power(F, k - j) @ Q @ np.linalg.matrix_power(F, k - j).T
                                             for j in range(k + 1))
        np.testing.assert_allclose(fc.means[k], mean_k, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fc.covs[k], cov_k, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fc.measurement_means[k], H @ mean_k, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fc.measurement_covs[k], H @ cov_k @ H.T + R, rtol=1e-12, atol=1e-12)
    assert np.array_equal(fc.covs, np.swapaxes(fc.covs, 1, 2))
    lower, upper = fc.interval(0.5, of="states")
    np.testing.assert_allclose(upper - fc.means, 0.6744897501960817 * np.sqrt(np.diagonal(fc.covs, 0, 1, 2)))
    with pytest.raises(ValueError, match="read-only"):
        fc.means[0, 0] = 1.0


@pytest.mark.parametrize("method", ["ukf", "ckf", "ekf", "iekf"])
def test_a_linear_model_forecast_through_a_nonlinear_method_is_exact(method):
    """f and h linear, as a NonlinearModel: the regression (or the Jacobian) is exact, so is the forecast."""
    F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    Q, R = np.array([[0.25, 0.5], [0.5, 1.0]]), np.array([[4.0]])
    belief = gf.Gaussian([3.0, -1.0], [[2.0, 0.3], [0.3, 1.0]])
    exact = gf.forecast(gf.LinearModel(F, H, Q, R), belief, 7)
    curved = gf.NonlinearModel(lambda x: F @ x, lambda x: H @ x, Q, R)
    fc = gf.forecast(curved, belief, 7, method=method)
    for name in ("means", "covs", "measurement_means", "measurement_covs"):
        np.testing.assert_allclose(getattr(fc, name), getattr(exact, name), rtol=1e-10, atol=1e-10, err_msg=name)


def test_a_forecast_of_an_angle_is_wrapped():
    """A bearing measurement of a target turning past ±π: the predicted bearing stays in [-π, π)."""
    model = gf.NonlinearModel(lambda x: np.array([x[0], x[1] + 0.5]), lambda x: np.array([x[1]]),
                              0.01 * np.eye(2), np.array([[0.01]]), state_angles=[False, True],
                              measurement_angles=[True])
    fc = gf.forecast(model, gf.Gaussian([1.0, 3.0], 0.01 * np.eye(2)), 4)
    assert np.all(fc.means[:, 1] >= -np.pi) and np.all(fc.means[:, 1] < np.pi)
    np.testing.assert_allclose(fc.measurement_means[:, 0], fc.means[:, 1], atol=1e-9)


@pytest.mark.parametrize("call, error, message", [
    (lambda m, b: gf.forecast(m, b, 0), ValueError, "`steps` must be a positive integer"),
    (lambda m, b: gf.forecast(m, b, True), TypeError, "`steps` must be a positive integer"),
    (lambda m, b: gf.forecast(m, [0.0, 1.0], 3), TypeError, "`belief` must be a gaussfuse.Gaussian"),
    (lambda m, b: gf.forecast(m, gf.Gaussian([0.0], [[1.0]]), 3), ValueError, "dimension 2"),
    (lambda m, b: gf.forecast(m, gf.filter(m, b, np.zeros((2, 4, 1))), 3), ValueError, "one series"),
    (lambda m, b: gf.forecast(m, b, 3, [[1.0]] * 3), ValueError, "no control input"),
    (lambda m, b: gf.forecast(gf.LinearModel(np.ones((2, 2, 2)), [1, 0], np.eye(2), 1.0), b, 3), ValueError,
     "fewer than `steps`"),
    (lambda m, b: gf.forecast(m, b, 3).interval(1.0), ValueError, "`level` must be a number in"),
    (lambda m, b: gf.forecast(m, b, 3).interval(0.9, of="state"), ValueError, "`of` must be"),
    (lambda m, b: gf.forecast(m, b, 3, method="ukf"), TypeError, "does not apply to a LinearModel"),
    (lambda m, b: gf.forecast(gf.LinearModel([[1e200, 0], [0, 1]], [1, 0], np.eye(2), 1.0), b, 3),
     FloatingPointError, "at step 0: the predicted mean or covariance is not finite"),
])
def test_bad_arguments_are_named(call, error, message):
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0)
    with pytest.raises(error, match=message):
        call(model, gf.Gaussian([0.0, 1.0], np.eye(2)))


def test_errors_name_forecasts_own_arguments():
    """They named `prior` and "matching `zs`", which forecast does not have."""
    with pytest.raises(ValueError, match=r"^`belief` must have dimension 1 \(the model's state\); got 2\.$"):
        gf.forecast(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0), gf.Gaussian([0.0, 0.0], np.eye(2)), 2)
    with pytest.raises(ValueError, match=r"`us` must have shape \(T, p\) = \(2, 1\) .*matching `steps`; got shape"):
        gf.forecast(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0, B=1.0), gf.Gaussian(0.0, 1.0), 2, us=np.ones((3, 1)))


def test_an_interval_of_a_variance_that_is_zero_to_round_off_is_its_mean():
    """A rank-1 belief rotated onto an axis: the variance there is 0 (computed -1.4e-18), and the interval was
    NaN. Oracle: exact arithmetic, x ~ N(0, P0) with P0 = v vᵀ lands on the second axis after F."""
    x, y = 0.3, 0.7
    P0 = np.array([[x * x, x * y], [x * y, y * y]])
    model = gf.LinearModel(F=[[y, -x], [0.0, 1.0]], H=np.eye(2), Q=np.zeros((2, 2)), R=np.zeros((2, 2)))
    fc = gf.forecast(model, gf.Gaussian([0.0, 0.0], P0), 1)
    lower, upper = fc.interval(of="states")
    assert abs(fc.covs[0, 0, 0]) < 1e-16
    assert lower[0, 0] == upper[0, 0] == fc.means[0, 0]
    np.testing.assert_allclose(upper[0, 1], 1.959963984540054 * y, rtol=1e-12)


def test_a_level_just_below_one_has_its_quantile():
    """0.5 + level / 2 rounds to 1 for a level within 1e-16 of 1 (StatisticsError); the oracle is SciPy's
    normal quantile of the tail (1 - level) / 2."""
    from scipy.stats import norm

    fc = gf.forecast(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0), gf.Gaussian(0.0, 1.0), 1)
    level = np.nextafter(1.0, 0.0)
    lower, upper = fc.interval(level)
    sigma = np.sqrt(fc.measurement_covs[0, 0, 0])
    np.testing.assert_allclose(upper[0, 0], norm.isf((1.0 - level) / 2.0) * sigma, rtol=1e-12)
    np.testing.assert_allclose(lower[0, 0], -upper[0, 0])


@pytest.mark.parametrize("model", ["x", None, 3.0])
def test_a_model_of_the_wrong_kind_is_named(model):
    with pytest.raises(TypeError, match=r"`model` must be a gaussfuse.LinearModel, NonlinearModel or TimedModel"):
        gf.forecast(model, gf.Gaussian(0.0, 1.0), 2)


# ---------------------------------------------------------------------------
# to_pandas (audit Y3: a Forecast had none, and a forecast of a dated Series lost its dates)
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("index, labels", [
    (pd.date_range("2024-01-01", periods=4, freq="D"), pd.date_range("2024-01-05", periods=3, freq="D")),
    (pd.DatetimeIndex(["2024-01-31", "2024-02-29", "2024-03-31", "2024-04-30"]),  # (a month end, inferred)
     pd.date_range("2024-05-31", periods=3, freq="ME")),
    (pd.timedelta_range("0s", periods=4, freq="2s"), pd.timedelta_range("8s", periods=3, freq="2s")),
    (pd.period_range("1871", periods=4, freq="Y"), pd.period_range("1875", periods=3, freq="Y")),
    (pd.date_range("2024-03-31 00:00", periods=4, freq="h", tz="Europe/Paris"),  # across the clock change
     pd.date_range("2024-03-31 05:00", periods=3, freq="h", tz="Europe/Paris")),
    (pd.RangeIndex(10, 18, 2), pd.RangeIndex(18, 24, 2)),
    (pd.Index([0.5, 1.0, 2.0, 4.0]), pd.RangeIndex(1, 4, name="steps ahead")),  # no step of its own
])
def test_to_pandas_continues_the_index_of_the_series_filtered(index, labels):
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=2.0)
    series = pd.Series([1.0, 2.0, np.nan, 3.0], index=index, name="flow")
    if isinstance(index, pd.TimedeltaIndex):  # (times in seconds, which a model without dt refuses)
        model = gf.model(gf.RandomWalk(q=1.0), gf.Position(r=2.0), dt=2.0)
    fc = gf.forecast(model, gf.filter(model, gf.Gaussian(0.0, 10.0), series), 3)
    frame = fc.to_pandas()
    pd.testing.assert_index_equal(frame.index, labels, check_names=False)
    assert list(frame.columns) == ["flow", "flow_sd"]
    np.testing.assert_array_equal(frame["flow"], fc.measurement_means[:, 0])
    np.testing.assert_array_equal(frame["flow_sd"], np.sqrt(fc.measurement_covs[:, 0, 0]))
    states = fc.to_pandas(of="states", names=["level"])
    np.testing.assert_array_equal(states["level_sd"], np.sqrt(fc.covs[:, 0, 0]))


def test_to_pandas_of_a_forecast_at_times_and_of_a_gaussian():
    model = gf.model(gf.ConstantVelocity(), gf.Position(r=1.0))
    times = pd.DatetimeIndex(["2024-01-04", "2024-01-04 00:00:01", "2024-01-04 00:00:03"])
    fc = gf.forecast(model, gf.Gaussian([0.0, 1.0], np.eye(2)), times=times)
    frame = fc.to_pandas(of="states", covariances=True)
    pd.testing.assert_index_equal(frame.index, times[1:])
    assert list(frame.columns) == ["x", "vx", "x_sd", "vx_sd", "cov_x_vx"]  # the motion's names
    np.testing.assert_array_equal(frame["cov_x_vx"], fc.covs[:, 0, 1])
    plain = gf.forecast(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=2.0), gf.Gaussian(0.0, 1.0), 2)
    assert list(plain.to_pandas().columns) == ["z0", "z0_sd"]
    unnamed = pd.Series([1.0, 2.0], index=pd.RangeIndex(2))
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=2.0)
    frame = gf.forecast(model, gf.filter(model, gf.Gaussian(0.0, 1.0), unnamed), 2).to_pandas()
    assert list(frame.columns) == ["z0", "z0_sd"]  # (not "None")
    pd.testing.assert_index_equal(frame.index, pd.RangeIndex(2, 4))
    pd.testing.assert_index_equal(plain.to_pandas().index, pd.RangeIndex(1, 3, name="steps ahead"))
    with pytest.raises(ValueError, match=r"`of` must be 'measurements' or 'states'; got 'state'"):
        plain.to_pandas(of="state")


def test_to_pandas_with_another_model_than_the_filters_and_names_as_an_array():
    """A forecast through a model of another m took the filtered Series' one name for its two measurements and
    failed, blaming `names` and "state components"; names as an array raised NumPy's "truth value ... is
    ambiguous" (review R10)."""
    single = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=2.0)
    double = gf.LinearModel(F=1.0, H=[[1.0], [1.0]], Q=1.0, R=np.eye(2))
    filtered = gf.filter(single, gf.Gaussian(0.0, 10.0), pd.Series(np.arange(6.0), name="q"))
    fc = gf.forecast(double, filtered, 2)
    assert list(fc.to_pandas().columns) == ["z0", "z1", "z0_sd", "z1_sd"]
    assert list(fc.to_pandas(names=np.array(["a", "b"])).columns) == ["a", "b", "a_sd", "b_sd"]
    assert list(filtered.to_pandas(names=np.array(["level"])).columns) == ["level", "level_sd"]
    with pytest.raises(ValueError, match=r"`names` must have 2 entries, one per measurement component; got 1\."):
        fc.to_pandas(names=["a"])


def test_a_misspelt_steps_and_times_at_another_dt_are_explained():
    """`step=3` got "needs `steps`" without naming the misspelling, and times at another step than the model's
    dt were told to leave `times` out and pass a Series' values, which a forecast has not (review R10)."""
    with pytest.raises(TypeError, match=r"^forecast\(\) needs `steps` .* or `times` \(`step` for `steps`\?\)\.$"):
        gf.forecast(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=2.0), gf.Gaussian([0.0], [[1.0]]), step=3)
    model = gf.model(gf.ConstantVelocity(dim=1, q=0.1), gf.Position(dim=1, r=4.0), dt=1.0)
    with pytest.raises(ValueError, match=r"^`times` step by 2 s but the model is for dt = 1 s; build it for the "
                                         r"times' step, or with gf.model\(motion, sensor\) without dt\.$"):
        gf.forecast(model, gf.Gaussian([0.0, 1.0], np.eye(2)), times=[0.0, 2.0, 4.0])


@pytest.mark.parametrize("index", [
    pd.date_range("2026-01-01", periods=3, freq="2s"),
    pd.date_range("2026-03-29 00:59:58", periods=3, freq="2s", tz="Europe/Berlin"),
    pd.timedelta_range(0, periods=3, freq="2s"),
])
def test_times_start_at_the_time_of_a_pandas_result(index):
    """A forecast from a result whose index gave its times took `times[0]` as the belief's time unchecked: the
    future times alone made a forecast one step short whose first step was the gap between the first two of them
    (audit DD6)."""
    track = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.Position(dim=1, r=1.0))
    zs = pd.Series([0.0, 2.0, 4.0], index=index)
    result = gf.filter(track, gf.Gaussian([0.0, 1.0], np.eye(2)), zs)
    times = index[-1:].append(index[-1] + (index[1:] - index[0]))  # the belief's time, then two steps of 2 s
    fc = gf.forecast(track, result, times=times)
    want = gf.forecast(track, gf.Gaussian(result.last_mean, result.last_cov), times=[0.0, 2.0, 4.0])
    np.testing.assert_array_equal(fc.covs, want.covs)
    pd.testing.assert_index_equal(fc.to_pandas().index, times[1:])
    smoothed = gf.smooth(track, gf.Gaussian([0.0, 1.0], np.eye(2)), zs)
    np.testing.assert_array_equal(gf.forecast(track, smoothed, times=times.to_numpy()).covs, want.covs)
    for wrong in (times[1:], [0.0, 2.0, 4.0]):
        with pytest.raises(ValueError, match=r"^`times\[0\]` must be the belief's time, the last entry of zs\.index "
                                             r"\(.*\); got .*\. Give that time, then the times to forecast at\.$"):
            gf.forecast(track, result, times=wrong)
