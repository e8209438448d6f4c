"""`times=`: seconds from any clock, exact discretisation on irregular grids (against the continuous process's
own joint Gaussian), and the errors that say how to fix a model that cannot take the times."""

from __future__ import annotations

import datetime
import re

import numpy as np
import pandas as pd
import pytest

import gaussfuse as gf
from gaussfuse.inference.timing import as_seconds, same_time


def _integrated_wiener_joint(ts: np.ndarray, q: float, m0: np.ndarray, P0: np.ndarray):
    """Mean and covariance of [p(t_1), v(t_1), ..., p(t_T), v(t_T)] of the continuous constant-velocity process.

    x(t) = Φ(t) x(0) + w(t), Φ(t) = [[1, t], [0, 1]], w the integrated Wiener process of spectral density q:
    Cov(v(s), v(t)) = q min, Cov(p(s), v(t)) = q s²/2 (s <= t) or q (s t - t²/2), and
    Cov(p(s), p(t)) = q (min² max / 2 - min³ / 6). Closed forms of the process, not the filter's recursion.
    """
    T = ts.shape[0]
    mean, cov = np.empty(2 * T), np.empty((2 * T, 2 * T))

    def pv(s, t):
        return q * s * s / 2 if s <= t else q * (s * t - t * t / 2)

    for j, s in enumerate(ts):
        Phi_s = np.array([[1.0, s], [0.0, 1.0]])
        mean[2 * j:2 * j + 2] = Phi_s @ m0
        for k, t in enumerate(ts):
            Phi_t = np.array([[1.0, t], [0.0, 1.0]])
            lo, hi = min(s, t), max(s, t)
            W = np.array([[q * (lo * lo * hi / 2 - lo**3 / 6), pv(s, t)], [pv(t, s), q * lo]])
            cov[2 * j:2 * j + 2, 2 * k:2 * k + 2] = Phi_s @ P0 @ Phi_t.T + W
    return mean, cov


def _condition(mean, cov, H, r, zs, upto):
    """The states given the measurements z_1..z_upto (NaN = missing): dense Gaussian conditioning."""
    T = zs.shape[0]
    rows = [k for k in range(upto) if not np.isnan(zs[k])]
    A = np.zeros((len(rows), 2 * T))
    for i, k in enumerate(rows):
        A[i, 2 * k:2 * k + 2] = H
    S = A @ cov @ A.T + r * np.eye(len(rows))
    G = cov @ A.T @ np.linalg.inv(S)
    return mean + G @ (zs[rows] - A @ mean), cov - G @ A @ cov


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_irregular_steps_are_the_continuous_process_exactly(engine):
    """Steps of 0.1 to 7 s, a missing value: filter and smoother equal the continuous process conditioned densely."""
    q, r = 0.3, 0.5
    gaps = np.array([1.0, 0.1, 2.5, 7.0, 0.3, 1.0, 4.0, 0.2, 0.2, 3.0])
    ts = np.cumsum(gaps)  # the prior at time 0
    zs = np.sin(ts) + 0.1 * ts
    zs[4] = np.nan
    m0, P0 = np.array([0.0, 0.5]), np.array([[2.0, 0.3], [0.3, 1.0]])
    timed = gf.model(gf.ConstantVelocity(q=q), gf.Position(r=r))
    sm = gf.smooth(timed, gf.Gaussian(m0, P0), zs, times=np.concatenate([[0.0], ts]), engine=engine)
    mean, cov = _integrated_wiener_joint(ts, q, m0, P0)
    H = np.array([1.0, 0.0])
    post_mean, post_cov = _condition(mean, cov, H, r, zs, len(ts))
    for k in range(len(ts)):
        block = slice(2 * k, 2 * k + 2)
        np.testing.assert_allclose(sm.means[k], post_mean[block], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(sm.covs[k], post_cov[block, block], rtol=1e-9, atol=1e-10)
        f_mean, f_cov = _condition(mean, cov, H, r, zs, k + 1)
        np.testing.assert_allclose(sm.filtered.means[k], f_mean[block], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(sm.filtered.covs[k], f_cov[block, block], rtol=1e-9, atol=1e-10)


def test_clocks_give_the_same_filter():
    """Seconds, datetime64, datetimes, a pandas DatetimeIndex in another time zone and a TimedeltaIndex agree."""
    timed = gf.model(gf.ConstantVelocity(dim=2, q=0.1), gf.Position(dim=2, r=1.0))
    prior = gf.Gaussian([0.0, 0.0, 1.0, 1.0], np.eye(4))
    seconds = np.array([0.0, 1.0, 2.5, 3.0, 8.0])
    zs = np.column_stack([seconds, 2 * seconds]) + 0.1
    start = datetime.datetime(2026, 3, 29, 0, 59, 58)  # across a change of summer time in Europe
    clocks = [
        seconds + 1e9,
        np.datetime64("2026-01-01T00:00:00") + (seconds * 1e3).astype("timedelta64[ms]"),
        [start + datetime.timedelta(seconds=float(s)) for s in seconds],
        pd.DatetimeIndex([start + datetime.timedelta(seconds=float(s)) for s in seconds], tz="UTC").tz_convert(
            "Europe/Paris"),
        pd.to_timedelta(seconds, unit="s"),
        pd.Series(pd.to_datetime(seconds, unit="s")),
    ]
    want = gf.filter(timed, prior, zs, times=seconds)
    for clock in clocks:
        got = gf.filter(timed, prior, zs, times=clock)
        np.testing.assert_allclose(got.means, want.means, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got.covs, want.covs, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(as_seconds("times", clocks[3]), seconds)


def test_regular_times_keep_a_time_invariant_model_and_its_speed():
    """Regular times discretise to the fixed-dt model itself (time-invariant: compiled, fixed point reused)."""
    timed = gf.model(gf.ConstantVelocity(q=0.5), gf.Position(r=0.1))
    model, _ = timed.at(np.full(40, 0.25))
    assert model.steps is None and model.dt == 0.25
    zs = np.linspace(0, 10, 40)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    np.testing.assert_array_equal(gf.filter(timed, prior, zs, times=np.arange(1, 41) * 0.25).means,
                                  gf.filter(gf.model(gf.ConstantVelocity(q=0.5), gf.Position(r=0.1), 0.25), prior,
                                            zs).means)


def test_a_nonlinear_motion_steps_by_each_dt():
    """Coordinated turn and range-bearing: step k is f(x, dt_k) with Q(dt_k), as a fixed-dt model of that dt."""
    timed = gf.model(gf.CoordinatedTurn(q_acc=0.1, q_turn=1e-3), gf.RangeBearing(origin=(-5.0, 0.0)))
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5, 0.05], np.diag([1.0, 1.0, 0.1, 0.1, 0.01]))
    zs = np.array([[5.0, 0.1], [6.0, 0.12], [8.0, 0.2]])
    for method in ("ekf", "ukf"):
        res = gf.filter(timed, prior, zs, times=[0.0, 1.0, 3.0, 3.5], method=method)
        belief = prior
        for k, dt in enumerate([1.0, 2.0, 0.5]):
            step = gf.model(gf.CoordinatedTurn(q_acc=0.1, q_turn=1e-3), gf.RangeBearing(origin=(-5.0, 0.0)), dt)
            one = gf.filter(step, belief, zs[k:k + 1], method=method)
            np.testing.assert_allclose(res.means[k], one.means[0], rtol=1e-10, atol=1e-12)
            belief = one.last


@pytest.mark.parametrize("times, model, message", [
    (np.array([0.0, 1.0, 2.0, 4.0, 5.0]), "fixed", r"`times` are irregular \(steps from 1 s to 2 s\)"),
    (np.arange(5.0), "dt2", r"`times` step by 1 s but the model is for dt = 2 s; .* or, if each row is one step of "
                            r"dt whatever its time, leave `times` out \(for a pandas `zs`, pass its values\)\.$"),
    (None, "timed", "`times` is required"),
    (np.array([0.0, 1.0, 1.0, 2.0, 3.0]), "timed", "strictly increasing; step 2 has dt = 0"),
    (np.arange(3.0), "timed", "must have 5 entries, one per measurement, or 6"),
    (np.array(["a", "b", "c", "d", "e"]), "timed", "`times` must be numbers"),
    (np.arange(10.0).reshape(5, 2), "timed", "one-dimensional"),
    (np.array([0.0, 1.0, np.nan, 3.0, 4.0]), "timed", "finite"),
    # steps too long for float64: said so, not "`Q` must be finite" or "`dt` must be a positive number; got inf"
    (np.array([0.0, 1.0, 1e300, 2e300, 3e300]), "timed",
     r"^a step of dt = 1e\+300 s is too long for ConstantVelocity: its F or Q overflows float64"),
    (np.array([-1.7e308, -1.6e308, 1.7e308, 1.71e308, 1.72e308]), "timed",
     r"^`times` step 2 is longer than the largest float64 \(dt = inf s\)"),
])
def test_times_that_do_not_fit_are_named(times, model, message):
    models = {"fixed": gf.constant_velocity(1.0, 0.5, 0.1), "dt2": gf.constant_velocity(2.0, 0.5, 0.1),
              "timed": gf.model(gf.ConstantVelocity(q=0.5), gf.Position(r=0.1))}
    with pytest.raises((ValueError, TypeError), match=message):
        gf.filter(models[model], gf.Gaussian([0.0, 1.0], np.eye(2)), np.arange(5.0), times=times)


def test_fit_forecast_and_simulate_take_times():
    """Each equals the same call on the model discretised for those steps (TimedModel.at), and fit refuses to learn
    what varies with dt."""
    timed = gf.model(gf.ConstantVelocity(q=0.5), gf.Position(r=2.0))
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    gaps = np.random.default_rng(0).choice([1.0, 2.0, 5.0], size=120)
    times = np.concatenate([[0.0], np.cumsum(gaps)])
    stepped, _ = timed.at(gaps)
    sim = gf.simulate(timed, prior, 120, times=times, rng=4)
    np.testing.assert_array_equal(sim.states, gf.simulate(stepped, prior, 120, rng=4).states)
    fit = gf.fit(timed, prior, sim.measurements, learn=("R",), times=times, method="mle")
    want = gf.fit(stepped, prior, sim.measurements, learn=("R",), method="mle")
    assert fit.params["R"] == pytest.approx(want.params["R"], rel=1e-12)
    with pytest.raises(ValueError, match=r"`learn` includes \['Q'\]"):
        gf.fit(timed, prior, sim.measurements, learn=("Q", "R"), times=times)
    ahead = np.array([times[-1], times[-1] + 0.5, times[-1] + 10.0])
    fc = gf.forecast(timed, gf.Gaussian([3.0, 1.0], np.eye(2)), times=ahead)
    for k, dt in enumerate([0.5, 9.5]):
        step = gf.forecast(gf.model(gf.ConstantVelocity(q=0.5), gf.Position(r=2.0), dt),
                           gf.Gaussian([3.0, 1.0], np.eye(2)) if k == 0 else gf.Gaussian(fc.means[0], fc.covs[0]), 1)
        np.testing.assert_allclose(fc.means[k], step.means[0], rtol=1e-14)
        np.testing.assert_allclose(fc.covs[k], step.covs[0], rtol=1e-14)
    with pytest.raises(ValueError, match="give `steps` or `times`, not both"):
        gf.forecast(timed, prior, 2, times=ahead)
    with pytest.raises(ValueError, match="`times` is required"):
        gf.forecast(timed, prior, 2)


@pytest.mark.parametrize("build", [
    lambda: gf.model(gf.ConstantAcceleration(), gf.Position(), dt=1e160),
    lambda: gf.constant_acceleration(1e160, 1.0, 1.0),
    lambda: gf.model(gf.ConstantVelocity(noise="piecewise"), gf.Position(), dt=1e200),
    lambda: gf.filter(gf.model(gf.ConstantAcceleration(), gf.Position()), gf.Gaussian(np.zeros(3), np.eye(3)),
                      [1.0, 2.0], times=[0.0, 1e160]),
])
def test_a_step_whose_powers_overflow_python_floats_is_named(build):
    """dt³ of 1e160 in Python floats raised a bare OverflowError (34, 'Numerical result out of range')."""
    with pytest.raises(ValueError, match=r"^a step of dt = 1e\+(160|200) s is too long for Constant"):
        build()


def test_datetime_steps_are_rounded_once_from_their_exact_difference():
    """Steps were differences of float seconds from the first time: 10 µs steps a day after it were off by up
    to 1.5e-11 s (1.5e-6 of a step). Against the same steps given as seconds, rounded once each."""
    base = np.datetime64("2026-11-30T00:00:00.000000000")
    counts = 86_400 * 10**9 + 10_000 * np.cumsum(np.random.default_rng(2).integers(1, 4, size=300))
    times = np.concatenate([[base], base + counts.astype("timedelta64[ns]")])
    dts = gf.inference.timing.step_sizes("times", times, 300)
    np.testing.assert_array_equal(dts, np.diff(np.concatenate([[0], counts])) / 1e9)
    timed = gf.model(gf.ConstantVelocity(q=4.0), gf.Position(r=1e-12))
    zs = np.cumsum(np.random.default_rng(3).normal(size=300)) * 1e-5
    got = gf.filter(timed, gf.Gaussian([0.0, 1.0], np.eye(2)), zs, times=times)
    want = gf.filter(timed.at(dts)[0], gf.Gaussian([0.0, 1.0], np.eye(2)), zs)
    np.testing.assert_array_equal(got.means, want.means)
    assert got.loglik == want.loglik


# 400 times 100 ms apart, from 2026-05-01T12:00 UTC: as float seconds since 1970 their differences scatter from
# 0.09999990 to 0.10000014 s (the round-off of 1.78e9); as datetime64 they are exact
GRID_MS = np.datetime64("2026-05-01T12:00:00.000", "ms") + np.arange(401) * np.timedelta64(100, "ms")
GRID_EPOCH = (GRID_MS - np.datetime64("1970-01-01T00:00:00", "ms")).astype(np.int64) / 1000.0


def test_a_regular_grid_of_float_seconds_is_regular_to_its_round_off():
    """A model for dt = 0.1 refused 100 ms times as seconds since 1970 ("irregular, 0.0999999 to 0.1 s"), and fit
    refused to learn Q on 0.1 * k ("discretised for each step's dt"), which datetimes of the same instants passed."""
    assert np.ptp(np.diff(GRID_EPOCH)) > 1e-7  # the scatter, far beyond 1e-9 of a step
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    fixed = gf.constant_velocity(dt=0.1, q=0.7, r=0.3)
    zs = gf.simulate(fixed, prior, 400, rng=3).measurements
    np.testing.assert_array_equal(gf.filter(fixed, prior, zs, times=GRID_EPOCH, check="off").means,
                                  gf.filter(fixed, prior, zs, check="off").means)
    with pytest.raises(ValueError, match=r"`times` step by 0\.1 s but the model is for dt = 0\.2 s"):
        gf.filter(gf.constant_velocity(dt=0.2, q=0.7, r=0.3), prior, zs, times=GRID_EPOCH)
    ms = gf.constant_velocity(dt=0.001, q=0.7, r=0.3)
    start = GRID_EPOCH[0]
    gf.filter(ms, prior, zs, times=start + 0.001 * np.arange(401), check="off")
    for factor in (1.0001, 1.001, 1.003):  # the mean step is known far better than one time's round-off (3e-6 s)
        with pytest.raises(ValueError, match=r"but the model is for dt = 0\.001 s"):
            gf.filter(ms, prior, zs, times=start + 0.001 * factor * np.arange(401))
    jittered = GRID_EPOCH + np.r_[0.0, 1e-4, np.zeros(399)]
    with pytest.raises(ValueError, match=r"`times` are irregular"):
        gf.filter(fixed, prior, zs, times=jittered)
    timed = gf.model(gf.ConstantVelocity(q=0.7), gf.Position(r=0.3))
    # Q = q I, a maximum inside its range (a full Q's lies where its small eigenvalue is 0, where the search ends
    # by chance); one engine for all, the times being the subject ("auto" may pick either as the cache fills).
    learn = dict(learn=("Q", "R"), structure={"Q": "scalar"}, method="mle", engine="python")
    for times in (0.1 * np.arange(401), GRID_EPOCH):
        fit = gf.fit(timed, prior, zs, times=times, **learn)
        want = gf.fit(timed, prior, zs, times=GRID_MS, **learn)
        np.testing.assert_allclose(fit.model.Q, want.model.Q, rtol=1e-6)
        assert fit.loglik == pytest.approx(want.loglik, rel=1e-9)


def test_a_pandas_series_of_zoned_times():
    """A Series of aware datetimes raised pandas' "index is not a valid DatetimeIndex" (tz_convert converts a Series'
    index): it is the same instants as its DatetimeIndex, and as naive UTC times."""
    timed = gf.model(gf.ConstantVelocity(q=0.7), gf.Position(r=0.3))
    prior, zs = gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.5, 2.0]
    index = pd.date_range("2026-05-01 14:00", periods=3, freq="1500ms", tz="Europe/Berlin")
    want = gf.filter(timed, prior, zs, times=index.tz_convert("UTC").tz_localize(None)).means
    for times in (pd.Series(index), index, pd.Series(index.tz_convert("UTC").tz_localize(None))):
        np.testing.assert_array_equal(gf.filter(timed, prior, zs, times=times).means, want)


@pytest.mark.parametrize("times, got", [
    ([datetime.datetime(2026, 5, 1), 1.0, 2.0], "float at `times[1]`"),
    ([0.0, None, 2.0], "NoneType at `times[1]`"),
    ([0.0, 1.0, datetime.datetime(2026, 5, 1)], "datetime at `times[2]`"),
])
def test_a_time_of_another_kind_is_named(times, got):
    """The message named the first entry's type ("got datetime" for a float at times[1], "got float" for None)."""
    timed = gf.model(gf.ConstantVelocity(q=0.7), gf.Position(r=0.3))
    with pytest.raises(TypeError, match=re.escape(f"all of one kind; got {got}.")):
        gf.filter(timed, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0, 3.0], times=times)


def test_one_measurement_with_one_time_asks_for_the_prior_s_time():
    """The error read "`times` must have 1 entries, one per measurement, or 2 ...; got 1" (audit N)."""
    timed = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.Position(dim=1, r=1.0))
    with pytest.raises(ValueError, match=r"^`times` must have 2 entries with one measurement, the prior's time and "
                                         r"then the measurement's \(one time alone gives no time step\); got 1\.$"):
        gf.smooth(timed, gf.Gaussian([0.0, 1.0], np.eye(2)), [1.0], times=[0.8])
    assert gf.smooth(timed, gf.Gaussian([0.0, 1.0], np.eye(2)), [1.0], times=[0.0, 0.8]).means.shape == (1, 2)


def test_numbers_held_as_objects_are_seconds():
    """Times in an object array or a pandas object column, all numbers, raised a bare StopIteration (a mixed-kind
    check that found no entry of another kind): they are seconds, as the same numbers in a float array."""
    timed = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.Position(dim=1, r=1.0))
    prior, zs = gf.Gaussian([0.0, 1.0], np.eye(2)), [0.0, 2.0, 4.0]
    want = gf.filter(timed, prior, zs, times=np.array([0.0, 1.0, 2.5])).means
    for times in (np.array([0, 1.0, 2.5], dtype=object), pd.Series([0.0, 1.0, 2.5], dtype=object),
                  [0, np.float32(1.0), 2.5]):
        np.testing.assert_array_equal(gf.filter(timed, prior, zs, times=times).means, want)
    with pytest.raises(TypeError, match=re.escape("all of one kind; got bool at `times[1]`.")):
        gf.filter(timed, prior, zs, times=np.array([0, True, 2.5], dtype=object))


@pytest.mark.parametrize("a, b, same", [
    (pd.Timestamp("2026-03-29 01:00", tz="Europe/Berlin"), pd.Timestamp("2026-03-29 00:00"), True),  # (as UTC)
    (pd.Timestamp("2026-03-29 01:00", tz="Europe/Berlin"), pd.Timestamp("2026-03-29 01:00"), False),
    (np.datetime64("2026-01-01"), datetime.datetime(2026, 1, 1, tzinfo=datetime.timezone.utc), True),
    (np.datetime64("2026-01-01T00:00:00.000000001"), np.datetime64("2026-01-01"), False),
    (pd.Timedelta(1, "s"), np.timedelta64(1000, "ms"), True),
    (np.timedelta64(0, "s"), np.datetime64(0, "s"), False),  # a duration is not a date
    (0, 0.0, True), (1.0, np.float32(1.0), True),
    (1, pd.Timestamp(1), False), (True, 1, False), (np.nan, np.nan, False), ("x", "x", False),
])
def test_same_time(a, b, same):
    assert same_time(a, b) is same
    assert same_time(b, a) is same


def test_durations_held_as_objects_are_times():
    """A list of pandas Timedeltas, timedeltas or timedelta64s was refused ("got Timedelta"), with a message that
    named no durations, where a TimedeltaIndex of the same durations was taken."""
    timed = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.Position(dim=1, r=1.0))
    prior, zs = gf.Gaussian([0.0, 1.0], np.eye(2)), [0.0, 2.0, 4.0]
    want = gf.filter(timed, prior, zs, times=[0.0, 1.5, 3.0]).means
    for times in ([pd.Timedelta(0), pd.Timedelta(1.5, "s"), pd.Timedelta(3, "s")],
                  [datetime.timedelta(0), datetime.timedelta(seconds=1.5), np.timedelta64(3, "s")],
                  pd.timedelta_range(0, periods=3, freq="1500ms")):
        np.testing.assert_array_equal(gf.filter(timed, prior, zs, times=times).means, want)
    with pytest.raises(TypeError, match=re.escape("or durations (timedelta64, timedelta, a pandas TimedeltaIndex), "
                                                  "all of one kind; got float at `times[1]`.")):
        gf.filter(timed, prior, zs, times=[pd.Timedelta(0), 1.5, 3.0])
    with pytest.raises(TypeError, match=re.escape("all of one kind; got datetime at `times[1]`.")):
        gf.filter(timed, prior, zs, times=[datetime.timedelta(0), datetime.datetime(2026, 1, 1), 3.0])
    with pytest.raises(ValueError, match=re.escape("`times[1]` must be a time; got NaT.")):
        gf.filter(timed, prior, zs, times=[pd.Timedelta(0), pd.NaT, pd.Timedelta(3, "s")])


def test_durations_that_the_finest_unit_cannot_hold_are_refused():
    """300 years in days beside a 1 ns Timedelta, held as objects, were promoted by NumPy to nanoseconds, which
    wrapped to -9e9 s; an array of 1e17 days wrapped in its cast to seconds (review R35). Durations now go through
    the datetimes' exact conversion, which refuses what the finest unit among them cannot hold."""
    with pytest.raises(ValueError, match=re.escape("`times[1]` holds 9460800000 seconds, which timedelta64[ns]")):
        as_seconds("times", [pd.Timedelta(1, "ns"), np.timedelta64(300 * 365, "D")])
    with pytest.raises(ValueError, match=re.escape("holds 100000000000000000 days, which timedelta64[s]")):
        as_seconds("times", np.array([0, 10**17], dtype="m8[D]"))
    np.testing.assert_array_equal(as_seconds("times", [pd.Timedelta(1, "ns"), np.timedelta64(200 * 365, "D")]),
                                  [0.0, (200 * 365 * 86400 * 10**9 - 1) / 1e9])
    np.testing.assert_array_equal(as_seconds("times", np.array([0, 5], dtype="m8[W]")), [0.0, 5 * 7 * 86400.0])
    # attoseconds beside seconds: NumPy's conversion factor itself overflowed, its OverflowError let through (R36)
    with pytest.raises(ValueError, match=re.escape("`times[1]` holds 10 seconds, which timedelta64[as]")):
        as_seconds("times", np.array([np.timedelta64(0, "as"), np.timedelta64(10, "s")], dtype=object))
    # (converted through milliseconds: 1 s, which attoseconds hold, was refused as 10 s is: review R37)
    np.testing.assert_array_equal(
        as_seconds("times", np.array([np.timedelta64(0, "as"), np.timedelta64(1, "s")], dtype=object)), [0.0, 1.0])


@pytest.mark.parametrize("motion", [gf.LocalLevel(q=0.5), gf.LocalLinearTrend(q_level=1.0, q_slope=0.5)],
                         ids=["LocalLevel", "LocalLinearTrend"])
def test_a_motion_counting_steps_refuses_dated_times(motion):
    """Audit MM1: LocalLevel and LocalLinearTrend count steps (dt = 1 for consecutive observations), but a
    TimedModel of them given daily dates stepped them by 86400 (a daily pandas Series too, its index becoming the
    times): the level's predicted variance 43201 where one step gives 1.1, silently."""
    sensor = gf.LinearSensor(np.eye(1, motion.n), 1.0)
    timed = gf.model(motion, sensor)
    prior = gf.Gaussian(np.zeros(motion.n), np.eye(motion.n))
    zs = np.array([1.0, 1.2, 0.9, 1.5, 1.1])
    days = np.arange("2024-01-01", "2024-01-06", dtype="datetime64[D]")
    name = type(motion).__name__
    with pytest.raises(ValueError, match=rf"^`times` gives dates or durations, but {name} counts steps .*np\.arange\(T\)"):
        gf.filter(timed, prior, zs, times=days)
    series = pd.Series(zs, index=pd.date_range("2024-01-01", periods=5, freq="D"))
    with pytest.raises(ValueError, match=rf"^`zs.index` gives dates or durations, but {name} counts steps .* `zs.to_numpy\(\)`"):
        gf.smooth(timed, prior, series)
    # step numbers are what it counts: the same as the model of one step
    want = gf.filter(gf.model(motion, sensor, dt=1), prior, zs)
    for got in (gf.filter(timed, prior, zs, times=np.arange(5.0)), gf.filter(timed, prior, series, times=np.arange(5))):
        np.testing.assert_array_equal(got.means, want.means)
        np.testing.assert_array_equal(got.covs, want.covs)


def test_a_motion_in_time_takes_dated_times_in_seconds():
    """The refusal is for motions that count steps: a random walk's q is per second, and a day is 86400 s."""
    timed = gf.model(gf.RandomWalk(q=0.5), gf.LinearSensor([[1.0]], 1.0))
    days = np.arange("2024-01-01", "2024-01-04", dtype="datetime64[D]")
    got = gf.filter(timed, gf.Gaussian([0.0], [[1.0]]), [1.0, 2.0, 3.0], times=days)
    assert got.predicted_covs[1, 0, 0] == pytest.approx(got.covs[0, 0, 0] + 0.5 * 86400)


def test_a_fit_refuses_dated_times_for_a_motion_counting_steps():
    """Review R44: `fit` steps a regular grid itself (one model for its step), so the refusal in `timing.resolve`
    never ran: a LocalLevel fitted to a daily series took Q per second, 86400 a day."""
    timed = gf.model(gf.LocalLevel(q=0.5), gf.LinearSensor([[1.0]], 1.0))
    zs = pd.Series(np.sin(np.arange(30.0)), index=pd.date_range("2024-01-01", periods=30, freq="D"))
    with pytest.raises(ValueError, match=r"^`zs.index` gives dates or durations, but LocalLevel counts steps"):
        gf.fit(timed, gf.Gaussian([0.0], [[1.0]]), zs, learn=("R",), iterations=2)
    with pytest.raises(ValueError, match=r"^`times` gives dates or durations, but LocalLevel counts steps"):
        gf.fit(timed, gf.Gaussian([0.0], [[1.0]]), zs.to_numpy(), times=zs.index.to_numpy(), learn=("R",),
               iterations=2)
    durations = pd.to_timedelta(np.arange(30), unit="D").to_numpy()
    with pytest.raises(ValueError, match=r"^`times` gives dates or durations"):
        gf.filter(timed, gf.Gaussian([0.0], [[1.0]]), zs.to_numpy(), times=durations)
