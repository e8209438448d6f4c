"""pandas in and out: a DataFrame's index and columns, its DatetimeIndex as times, pd.NA as missing."""

from __future__ import annotations

import datetime

import numpy as np
import pandas as pd
import pytest

import gaussfuse as gf
from gaussfuse.inference.frames import measurement_names


def _frame():
    idx = pd.DatetimeIndex(pd.to_datetime("2026-01-01") + pd.to_timedelta([0.0, 1.0, 3.0, 4.0, 9.0], unit="s"))
    df = pd.DataFrame({"x": [0.1, 1.2, pd.NA, 4.1, 9.0], "y": [0.0, 2.0, 6.1, 8.0, 18.2]}, index=idx)
    return df.astype("Float64"), np.array([[0.1, 0.0], [1.2, 2.0], [np.nan, 6.1], [4.1, 8.0], [9.0, 18.2]])


def test_a_dataframe_is_its_values_at_its_times_and_comes_back_indexed_like_it():
    df, values = _frame()
    timed = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.1))
    prior = gf.Gaussian([0.0, 0.0, 1.0, 2.0], np.eye(4))
    seconds = np.array([0.0, 1.0, 3.0, 4.0, 9.0])
    want = gf.smooth(timed, prior, values, times=seconds)
    got = gf.smooth(timed, prior, df)
    np.testing.assert_array_equal(got.means, want.means)
    frame = got.to_pandas(covariances=True)
    assert frame.index.equals(df.index)
    assert list(frame.columns[:8]) == ["x", "y", "vx", "vy", "x_sd", "y_sd", "vx_sd", "vy_sd"]
    np.testing.assert_array_equal(frame[["x", "y", "vx", "vy"]].to_numpy(), want.means)
    np.testing.assert_allclose(frame["vx_sd"].to_numpy(), np.sqrt(want.covs[:, 2, 2]), rtol=1e-15)
    np.testing.assert_array_equal(frame["cov_x_vx"].to_numpy(), want.covs[:, 0, 2])
    filt = gf.filter(timed, prior, df).to_pandas(names=["a", "b", "c", "d"])
    assert list(filt.columns[:4]) == ["a", "b", "c", "d"] and filt.index.equals(df.index)


def test_a_series_with_a_plain_index_keeps_it_and_a_masked_array_is_missing_values():
    model = gf.constant_velocity(dt=1.0, q=0.5, r=0.1)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    series = pd.Series([1.0, 2.0, None, 4.0], index=[10, 11, 12, 13], name="pos")
    frame = gf.filter(model, prior, series).to_pandas()
    assert list(frame.index) == [10, 11, 12, 13] and list(frame.columns) == ["x", "vx", "x_sd", "vx_sd"]
    masked = np.ma.masked_array([1.0, 2.0, 99.0, 4.0], mask=[False, False, True, False])
    np.testing.assert_array_equal(gf.filter(model, prior, masked).means, gf.filter(model, prior, series).means)


def test_fit_reads_a_dataframe_and_gives_its_parameters_as_a_series():
    rng = np.random.default_rng(2)
    y = np.cumsum(rng.normal(size=200)) + rng.normal(scale=2.0, size=200)
    series = pd.Series(y, index=pd.date_range("2026-01-01", periods=200, freq="D"))
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0, dt=86400.0)
    fit = gf.fit(model, gf.Gaussian([0.0], [[10.0]]), series, method="mle")
    want = gf.fit(model, gf.Gaussian([0.0], [[10.0]]), y, method="mle")
    params = fit.to_pandas()
    assert params.name == "estimate" and list(params.index) == ["Q", "R"]
    assert params["R"] == pytest.approx(want.params["R"], rel=1e-12)
    with pytest.raises(ValueError, match="the model is for dt = 3600 s"):
        gf.fit(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0, dt=3600.0), gf.Gaussian([0.0], [[10.0]]), series)


def test_to_pandas_needs_one_series_with_its_means():
    model = gf.constant_velocity(dt=1.0, q=0.5, r=0.1)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    with pytest.raises(ValueError, match="one series whose means were kept"):
        gf.filter(model, prior, np.zeros((2, 5, 1))).to_pandas()
    with pytest.raises(ValueError, match="covariances=True needs the covariances"):
        gf.filter(model, prior, np.zeros(5), keep="means").to_pandas(covariances=True)
    with pytest.raises(TypeError, match="`zs` must hold numbers"):
        gf.filter(model, prior, pd.Series(["a", "b"]))


@pytest.mark.parametrize("column, message", [
    ([5 + 7j, 2, 3], r"must be real; got complex values in column 'a'"),
    ([True, False, True], r"must hold numbers; got booleans in column 'a'"),
    (["1", "2", "3"], r"must hold numbers; got str values in column 'a' \(such as '1'\)"),
    (np.array([1.0, True, 3.0], dtype=object), r"must hold numbers; got bool values in column 'a'"),
])
def test_a_frame_of_what_an_array_may_not_hold_is_refused_alike(column, message):
    """pandas' cast to float dropped the imaginary part of 5+7j (only its own ComplexWarning), read True as 1
    and parsed the text "1", where an array of the same values is refused."""
    model = gf.LinearModel(np.eye(2), np.eye(2), np.eye(2), np.eye(2))
    frame = pd.DataFrame({"a": column, "b": [1.0, 2.0, 3.0]})
    with pytest.raises(TypeError, match=rf"^`zs` {message}"):
        gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), frame)
    missing = pd.DataFrame({"a": pd.array([1.0, None, 3.0], dtype="Float64"), "b": [1.0, 2.0, 3.0]})
    assert np.isnan(gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), missing).innovations[1, 0])


def test_names_that_collide_with_a_column_are_refused():
    """["pos", "pos_sd"] wrote the position's sd into the velocity's column; ["a", "a"] lost the position; "pv" was
    read as ('p', 'v') and covariances="yes" as True."""
    pytest.importorskip("pandas")
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([1.0, 3.0]), R=10.0)
    r = gf.filter(model, gf.Gaussian([0, 1], 500 * np.eye(2)), [1.0, 2, 3, 2, 1])
    for names in (["pos", "pos_sd"], ["a", "a"]):
        with pytest.raises(ValueError, match=r"^`names` .* give the column\(s\)"):
            r.to_pandas(names=names)
    with pytest.raises(TypeError, match=r"^`names` must be a sequence of 2 str"):
        r.to_pandas(names="pv")
    with pytest.raises(TypeError, match=r"^`covariances` must be True or False"):
        r.to_pandas(covariances="yes")
    frame = r.to_pandas(names=["pos", "vel"])
    assert list(frame.columns) == ["pos", "vel", "pos_sd", "vel_sd"]


def test_a_table_of_several_series_is_refused():
    """A DataFrame indexed by (series, time) was filtered as one series, the series joined end to end, silently."""
    index = pd.MultiIndex.from_tuples([("a", 0.0), ("a", 1.0), ("b", 0.0), ("b", 1.0)], names=["id", "t"])
    frame = pd.DataFrame({"z": [1.0, 2.0, 10.0, 11.0]}, index=index)
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    with pytest.raises(ValueError, match=r"`zs` has a MultiIndex \(id, t\): a table of several series would be"):
        gf.filter(model, gf.Gaussian(0.0, 1.0), frame)
    np.testing.assert_array_equal(gf.filter(model, gf.Gaussian(0.0, 1.0), frame.xs("a")).means,
                                  gf.filter(model, gf.Gaussian(0.0, 1.0), [1.0, 2.0]).means)


def test_a_calendar_index_is_one_step_a_row_for_a_model_with_fixed_matrices():
    """Yearly, monthly and business-day indexes were refused by a model with fixed matrices ("`times` are
    irregular", years being 365 or 366 days), with advice (a TimedModel) that counted its dt in seconds: Q 3e7
    times too large (audit F). Calendar periods are one step a row for such a model, as statsmodels takes them;
    a TimedModel still steps by their seconds, and a model with a dt in seconds still checks them."""
    from gaussfuse.datasets import nile

    years, flow = nile()
    model, prior = gf.LinearModel(F=1.0, H=1.0, Q=1469.1, R=15099.0), gf.Gaussian(0.0, 1e7)
    want = gf.filter(model, prior, flow)
    for index in (pd.to_datetime([f"{int(y)}-01-01" for y in years]), pd.date_range("1871-01", periods=100, freq="MS"),
                  pd.bdate_range("2020-01-01", periods=100)):
        got = gf.filter(model, prior, pd.Series(flow, index=index))
        np.testing.assert_array_equal(got.means, want.means)
        assert got.to_pandas().index.equals(index)
        assert gf.fit(model, prior, pd.Series(flow, index=index), method="em", iterations=2, tol=0).loglik == \
            gf.fit(model, prior, flow, method="em", iterations=2, tol=0).loglik
    gap = pd.to_datetime(["2020-01-01", "2020-01-02", "2020-01-03", "2020-01-05", "2020-01-06"])  # a day missed
    with pytest.raises(ValueError, match=r"`zs.index` are irregular .* give `zs.to_numpy\(\)`"):  # (named: DD6)
        gf.filter(model, prior, pd.Series(flow[:5], index=gap))
    monthly = pd.Series(flow[:5], index=pd.date_range("2020-01", periods=5, freq="MS"))
    with pytest.raises(ValueError, match=r"`zs.index` are irregular"):  # a model with a dt in seconds
        gf.filter(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0, dt=0.1), prior, monthly)
    timed = gf.model(gf.RandomWalk(q=1e-4), gf.LinearSensor(H=[[1.0]], R=[[15099.0]]))  # q per second
    seconds = (monthly.index - monthly.index[0]).total_seconds().to_numpy()
    np.testing.assert_array_equal(gf.filter(timed, prior, monthly).means,
                                  gf.filter(timed, prior, flow[:5], times=seconds).means)


def test_pd_na_in_a_data_frame_of_object_dtype_is_missing():
    """Audit Z3: pd.DataFrame({"z": [1.0, pd.NA, 2.0]}) (object dtype, pandas' default for such a list) raised
    TypeError "not 'NAType'", though the same column as a Series, or as Float64, is missing values."""
    model, prior = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0), gf.Gaussian(0.0, 1.0)
    frame = pd.DataFrame({"z": [1.0, pd.NA, 2.0], "w": [pd.NA, 3, 4.5]})
    assert (frame.dtypes == object).all()
    two = gf.LinearModel(F=1.0, H=[[1.0], [1.0]], Q=1.0, R=np.eye(2))
    want = gf.filter(two, prior, np.array([[1.0, np.nan], [np.nan, 3.0], [2.0, 4.5]]))
    got = gf.filter(two, prior, frame)
    np.testing.assert_array_equal(got.means, want.means)
    assert got.loglik == want.loglik
    one = gf.filter(model, prior, frame[["z"]])
    np.testing.assert_array_equal(one.means, gf.filter(model, prior, frame["z"]).means)
    with pytest.raises(TypeError, match=r"`zs` must hold numbers; got str values in column 'z'"):
        gf.filter(two, prior, pd.DataFrame({"z": [1.0, pd.NA, "2"], "w": [1.0, 2.0, 3.0]}))


@pytest.mark.parametrize("column", [
    pd.to_datetime(["2026-01-01", "2026-01-02", "2026-01-03"]),
    pd.to_datetime(["2026-01-01", "2026-01-02", "2026-01-03"]).tz_localize("Europe/Berlin"),
    pd.to_timedelta([1.0, 2.0, 3.0], unit="s"),
], ids=["datetime", "zoned", "timedelta"])
def test_a_column_of_dates_or_durations_is_not_measurements(column):
    """Review R13: such a column became nanosecond counts (1.7e18 for 2026), filtered as measurements."""
    model, prior = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0), gf.Gaussian(0.0, 1.0)
    with pytest.raises(TypeError, match=r"`zs` must hold numbers; got (datetime|timedelta) values in column 't'"):
        gf.filter(model, prior, pd.DataFrame({"t": column}))
    with pytest.raises(TypeError, match=r"`zs` must hold numbers; got (datetime|timedelta) values in column 't'"):
        gf.filter(model, prior, pd.Series(column, name="t"))


def _track():
    return gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=4.0)), gf.Gaussian([0, 0, 1, 0.5],
                                                                                                10 * np.eye(4))


def test_a_frames_columns_are_taken_by_the_models_measurement_names():
    """Columns named as the sensor's measurements, in another order, were taken by position: x and y swapped,
    silently (audit DD6). The oracle is the frame in the model's order."""
    track, prior = _track()
    when = pd.to_datetime("2026-05-01 12:00") + pd.to_timedelta([0, 1, 2, 5, 6, 8], unit="s")
    fixes = pd.DataFrame({"x": [0.0, 1.1, 1.9, 5.2, None, 8.1], "y": [0.0, 0.4, 1.1, 2.4, 3.1, 3.9]}, index=when)
    want = gf.smooth(track, prior, fixes)
    got = gf.smooth(track, prior, fixes[["y", "x"]])
    np.testing.assert_array_equal(got.means, want.means)
    assert got.filtered.table.columns == ("x", "y")
    with pytest.raises(ValueError, match=r"`zs` has the columns \['x', 'vy'\], some of the model's measurements "
                                         r"\['x', 'y'\], without \['y'\], and \['vy'\] besides"):
        gf.filter(track, prior, fixes.rename(columns={"y": "vy"}))
    by_position = gf.filter(track, prior, fixes.rename(columns={"x": "east", "y": "north"}))  # other names: in order
    np.testing.assert_array_equal(by_position.means, want.filtered.means)


def test_a_regular_grid_stamped_to_its_unit_is_regular():
    """A 30 Hz grid in nanoseconds steps by 33333333 and 33333334 ns (in microseconds, by 33333 and 33334), and
    was refused by a model for dt = 1/30 s as irregular (audit DD6). Steps of 1 s and 2 s stamped in seconds are
    still two steps."""
    model = gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0, dt=1 / 30)
    prior, zs = gf.Gaussian(0.0, 1.0), np.linspace(0.0, 1.0, 40)
    want = gf.filter(model, prior, zs)
    start = pd.Timestamp("2026-01-01")
    stamps = [start + pd.to_timedelta(np.arange(40) / 30, unit="s"),
              pd.date_range(start, periods=40, freq=pd.Timedelta(seconds=1 / 30)),
              [datetime.datetime(2026, 1, 1) + datetime.timedelta(seconds=k / 30) for k in range(40)]]  # (µs)
    for times in stamps:
        np.testing.assert_array_equal(gf.filter(model, prior, zs, times=times).means, want.means)
    np.testing.assert_array_equal(gf.filter(model, prior, pd.Series(zs, index=stamps[0])).means, want.means)
    with pytest.raises(ValueError, match="are irregular"):
        gf.filter(gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0, dt=1.0), prior, [1.0, 2.0, 3.0],
                  times=np.array(["2026-01-01T00:00:00", "2026-01-01T00:00:01", "2026-01-01T00:00:03"],
                                 dtype="datetime64[s]"))
    # not a grid that drifts from one (500 steps of 10000 ns, then 500 of 10004), nor one of another dt (review R31)
    ten = gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0, dt=1e-5)
    drifting = np.concatenate([[0], np.cumsum([10000] * 500 + [10004] * 500)]).astype("datetime64[ns]")
    with pytest.raises(ValueError, match="are irregular"):
        gf.filter(ten, prior, np.zeros(1000), times=drifting)
    summed = (np.cumsum(np.full(300_000, 1 / 30)) * 1e9).astype(np.int64).astype("datetime64[ns]")  # (review R32:
    thirty = gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0, dt=1 / 30)  # a clock summed in floats, 100 ns off by its end)
    assert gf.filter(thirty, prior, np.zeros(299_999), times=summed, engine="numba", keep="last").last_mean.shape == (1,)
    exact = (np.arange(1001) * 10000).astype("datetime64[ns]")
    with pytest.raises(ValueError, match="the model is for dt = 1.0002e-05 s"):
        gf.filter(gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0, dt=1.0002e-5), prior, np.zeros(1000), times=exact)


def test_pandas_controls_must_be_the_rows_of_the_measurements():
    """They were taken by position whatever their labels: reversed, or a year off, silently (audit DD6)."""
    model = gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0, B=1.0)
    index = pd.date_range("2026-01-01", periods=5, freq="D")
    zs, us = pd.Series([1.0, 2.0, 3.5, 4.0, 5.5], index=index), pd.Series([1.0, 0.5, 2.0, 0.0, 1.0], index=index)
    prior = gf.Gaussian(0.0, 1.0)
    np.testing.assert_array_equal(gf.filter(model, prior, zs, us).means, gf.filter(model, prior, zs, us.to_numpy()).means)
    for wrong in (us[::-1], us.set_axis(index + pd.Timedelta(days=365))):
        with pytest.raises(ValueError, match="`us` is a pandas object whose index is not that of `zs`"):
            gf.filter(model, prior, zs, wrong)


def test_a_frame_of_one_row_needs_no_times_for_a_model_with_fixed_matrices():
    """Its DatetimeIndex was taken for times, and one time gives no step (audit DD6)."""
    model, prior = gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.eye(2), R=np.eye(2), dt=1.0), gf.Gaussian([0, 0], np.eye(2))
    row = pd.DataFrame([[1.0, 1.0]], index=pd.to_datetime(["2026-01-01"]))
    np.testing.assert_array_equal(gf.filter(model, prior, row).means, gf.filter(model, prior, row.to_numpy()).means)


def test_dates_in_an_object_column_are_refused_and_index_errors_name_the_index():
    """np.datetime64 values in an object column were read as day counts; a bad index was called `times`, which
    the caller never gave (audit DD6)."""
    model, prior = gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1.0), gf.Gaussian(0.0, 1.0)
    dates = pd.Series([np.datetime64("2026-01-01"), np.datetime64("2026-01-02")], dtype=object)
    with pytest.raises(TypeError, match="`zs` must hold numbers; got datetime64 values in the Series"):
        gf.filter(model, prior, dates)  # (an unnamed Series was "column None")
    timed = gf.model(gf.LocalLevel(q=0.1), gf.LinearSensor(H=[[1.0]], R=[[1.0]]))
    unsorted = pd.Series([1.0, 2.0, 3.0], index=pd.to_datetime(["2026-01-02", "2026-01-01", "2026-01-03"]))
    with pytest.raises(ValueError, match=r"^`zs.index` must be strictly increasing"):
        gf.filter(timed, prior, unsorted)


def test_a_pyarrow_index_of_timestamps_or_durations_gives_the_times():
    """It was not taken for times at all (audit DD6, review R31). The oracle is the same index in numpy's types."""
    pytest.importorskip("pyarrow")
    timed = gf.model(gf.RandomWalk(q=0.1), gf.LinearSensor(H=[[1.0]], R=[[1.0]]))  # (LocalLevel counts steps)
    prior = gf.Gaussian(0.0, 1.0)
    for index, arrow in (("2026-01-01 2026-01-02 2026-01-05", "timestamp[ns][pyarrow]"), (None, "duration[ns][pyarrow]")):
        index = pd.to_datetime(index.split()) if index else pd.to_timedelta([1, 2, 5], unit="D")
        want = gf.filter(timed, prior, pd.Series([1.0, 2.0, 3.0], index=index))
        got = gf.filter(timed, prior, pd.Series([1.0, 2.0, 3.0], index=pd.Index(index, dtype=arrow)))
        np.testing.assert_array_equal(got.means, want.means)
    with pytest.raises(ValueError, match=r"^`zs` has one row, whose time alone gives no time step: pass `times`"):
        gf.filter(timed, prior, pd.Series([1.0], index=pd.to_datetime(["2026-01-01"])))


def test_names_of_a_timed_models_sensor_and_of_a_batch_reach_the_tables():
    """A forecast of a TimedModel had measurement columns z0, z1 for its sensor's x, y; a batch kept no state
    names (audit DD6)."""
    track, prior = _track()
    fc = gf.forecast(track, prior, times=[0.0, 1.0, 2.0])
    assert fc.measurement_names == ("x", "y")
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[[1, 0]], Q=np.eye(2), R=1.0, names=("level", "slope"))
    batch = gf.filter(model, gf.Gaussian([0, 0], np.eye(2)), np.ones((2, 5, 1)))
    assert batch.state_names == ("level", "slope")
    from gaussfuse.inference.results import first

    assert list(first(batch, 1).to_pandas().columns[:2]) == ["level", "slope"]


def test_a_model_s_relabelled_states_name_its_measurements():
    """gf.model(..., names=["y", "x", ...]) kept the sensor's own "x", "y" as its measurement names, so a DataFrame
    in the model's names was taken swapped (review R36): the sensor's names are the states' it measures, renamed."""
    track = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.25), names=["y", "x", "vy", "vx"])
    assert measurement_names(track) == ("y", "x")
    zs = np.array([[0.25, -0.15], [1.2, 1.05], [1.6, 1.4]])
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], 4.0 * np.eye(4))
    want = gf.filter(track, prior, zs, times=[0.5, 1.0, 1.5]).means
    frame = pd.DataFrame({"x": zs[:, 1], "y": zs[:, 0]}, index=pd.to_timedelta([0.5, 1.0, 1.5], unit="s"))
    np.testing.assert_array_equal(gf.filter(track, prior, frame).means, want)
    plain = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.25))
    assert measurement_names(plain) == ("x", "y")


def test_relabelled_names_that_would_name_two_measurements_alike_name_none():
    """A sensor reading x and its own "speed", states relabelled ["speed", "v"]: the measurement names came out
    ("speed", "speed"), which no DataFrame matches and forecast's frame refused (review R37). There are none
    then, and columns are taken in order; a name is taken from the model only for a measurement that reads that
    state alone."""
    sensor = gf.LinearSensor([[1, 0], [0, 1]], np.diag([0.1, 0.2]), names=("x", "speed"))
    track = gf.model(gf.ConstantVelocity(dim=1, q=0.5), sensor, names=["speed", "v"])
    assert measurement_names(track) is None
    zs = np.random.default_rng(0).normal(size=(5, 2))
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    result = gf.filter(track, prior, zs, times=np.arange(5.0))
    frame = pd.DataFrame({"a": zs[:, 0], "b": zs[:, 1]}, index=pd.to_timedelta(np.arange(5.0), unit="s"))
    np.testing.assert_array_equal(gf.filter(track, prior, frame).means, result.means)  # in order
    assert list(gf.forecast(track, result, times=[4.0, 5.0]).to_pandas().columns) == ["z0", "z1", "z0_sd", "z1_sd"]
    # the sensor's own names that are the model's states in another order: a frame in the model's names was
    # matched by the sensor's meaning and swapped, silently (review R38); in order now
    swap = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.LinearSensor(np.eye(2), np.eye(2), names=("x", "y")),
                    names=["y", "x"])
    assert measurement_names(swap) is None
    frame = pd.DataFrame({"y": zs[:, 0], "x": zs[:, 1]}, index=pd.to_timedelta(np.arange(5.0), unit="s"))
    np.testing.assert_array_equal(gf.filter(swap, prior, frame).means,
                                  gf.filter(swap, prior, zs, times=np.arange(5.0)).means)


def test_a_frames_columns_are_taken_by_name_in_any_case():
    """Columns "Y", "X" for the measurements x, y were taken by position, swapped, silently, where the command
    line reads such a file by name (audit SS1). The oracle is the frame in the model's order and case."""
    track, prior = _track()
    when = pd.to_datetime("2026-05-01 12:00") + pd.to_timedelta([0, 1, 2, 5, 6, 8], unit="s")
    fixes = pd.DataFrame({"x": [0.0, 1.1, 1.9, 5.2, None, 8.1], "y": [0.0, 0.4, 1.1, 2.4, 3.1, 3.9]}, index=when)
    want = gf.filter(track, prior, fixes)
    for columns in ({"x": "X", "y": "Y"}, {"y": "Y"}):
        got = gf.filter(track, prior, fixes.rename(columns=columns).iloc[:, ::-1])  # (in the other order too)
        np.testing.assert_array_equal(got.means, want.means)
        assert got.table.columns == ("x", "y")
    with pytest.raises(ValueError, match=r"`zs` has the columns \['X', 'vy'\], some of the model's measurements "
                                         r"\['x', 'y'\], without \['y'\], and \['vy'\] besides"):
        gf.filter(track, prior, fixes.rename(columns={"x": "X", "y": "vy"}))


def test_names_that_differ_only_in_case_are_matched_as_written():
    """A sensor whose measurements are "x" and "X" tells them apart by case alone: columns are matched as
    written, and a frame that names them in another case is not matched in any case (it is taken in order)."""
    from gaussfuse.inference.frames import by_name

    assert by_name(["X", "x"], ("x", "X"), "", "") == [1, 0]
    assert by_name(["A", "B"], ("a", "b"), "", "") == [0, 1]
    assert by_name(["B", "A"], ("a", "b"), "", "") == [1, 0]
    assert by_name(["a", "b"], ("x", "X"), "", "") is None
    for twice, missing in (["x", "x"], "X"), (["X", "X"], "x"):  # one of them twice: the other is missing
        with pytest.raises(ValueError, match=rf"measurements \['x', 'X'\], without \['{missing}'\], "
                                             rf"\['{twice[0]}'\] more than once: name them"):
            by_name(twice, ("x", "X"), "`zs` has", "fix")
    # a column named twice beside the others: the message named nothing wrong (review R52)
    with pytest.raises(ValueError, match=r"measurements \['x', 'y'\], \['x'\] more than once: name them"):
        by_name(["x", "x", "y"], ("x", "y"), "`zs` has", "fix")


def test_a_renamed_model_takes_a_frame_in_its_sensor_s_own_names():
    """States renamed px, py, ...: a DataFrame in the sensor's own names y, x (or Y, X) was taken by position,
    swapped, where the command line reads such a file by name (review R52). They are the second choice, where
    they name none of the model's states (review R38's sensor names that do stay in order: see above)."""
    from gaussfuse.inference.frames import name_choices

    track = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.25), names=["px", "py", "vx", "vy"])
    assert name_choices(track) == [("px", "py"), ("x", "y")]
    zs = np.array([[0.25, -0.15], [1.2, 1.05], [1.6, 1.4]])
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], 4.0 * np.eye(4))
    want = gf.filter(track, prior, zs, times=[0.5, 1.0, 1.5])
    index = pd.to_timedelta([0.5, 1.0, 1.5], unit="s")
    for names in (["y", "x"], ["Y", "X"], ["py", "px"]):
        frame = pd.DataFrame(dict(zip(names, [zs[:, 1], zs[:, 0]])), index=index)
        got = gf.filter(track, prior, frame)
        np.testing.assert_array_equal(got.means, want.means)
        assert got.table.columns == ("px", "py")
    swap = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.LinearSensor(np.eye(2), np.eye(2), names=("x", "y")),
                    names=["y", "x"])
    assert name_choices(swap) == [] and name_choices(gf.LinearModel(1.0, 1.0, 1.0, 1.0)) == []
