"""A series filtered and smoothed in pieces equals the whole series filtered and smoothed at once.

The oracle is gf.filter / gf.smooth on the whole series: the pieces run the
same steps on the same beliefs, so the results must agree to the last bit
for a model that varies with the step. A time-invariant model's filter holds
its covariance once it has settled (kalman.SteadyState), and a piece starts
afresh: there they agree to round-off.
"""

import re
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import gaussfuse as gf
from gaussfuse.diagnostics import DivergenceMonitor
from gaussfuse.inference.streaming import filter_pieces, smooth_pieces


def cut(zs, times, rows):
    return [SimpleNamespace(zs=zs[i:i + rows], times=times[i:i + rows]) for i in range(0, len(zs), rows)]


@pytest.fixture
def track():
    rng = np.random.default_rng(7)
    T = 240
    times = np.cumsum(rng.choice([0.1, 0.25, 1.0], T))
    zs = np.cumsum(rng.normal(size=(T, 2)), axis=0) * 0.3 + rng.normal(size=(T, 2))
    zs[rng.random(T) < 0.1, 0] = np.nan
    zs[50:53] = np.nan  # whole steps without a measurement, across a piece boundary for rows=51
    timed = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=1.0))
    return timed, gf.Gaussian([0.0, 0.0, 1.0, 0.0], 50.0 * np.eye(4)), zs, times


def joined(results, attr):
    return np.concatenate([getattr(r, attr) for _, r in results])


def close(got, want):
    """Equal to round-off: 1e-12 relative to each array's scale."""
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.nanmax(np.abs(want)))


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("rows", [2, 51, 240, 1000])
def test_pieces_equal_the_whole_series_with_times(track, engine, rows):
    model, prior, zs, times = track
    whole = gf.smooth(model, prior, zs, times=times, engine=engine, check="off")
    filtered = list(filter_pieces(model, prior, cut(zs, times, rows), timed=True, engine=engine, check="off"))
    smoothed = list(smooth_pieces(model, prior, cut(zs, times, rows), timed=True, engine=engine, check="off"))[::-1]
    for got, want in ((filtered, whole.filtered), (smoothed, whole)):
        np.testing.assert_array_equal(joined(got, "means"), want.means)
        np.testing.assert_array_equal(joined(got, "covs"), want.covs)
    # every gain, the one across each boundary too (that was left out: audit BB3)
    np.testing.assert_array_equal(joined(smoothed, "gains"), whole.gains)
    assert [p.times[0] for p, _ in smoothed] == [p.times[0] for p in cut(zs, times, rows)]
    # each piece's forward pass is the filter's over that piece: its log-likelihood and last belief did not take
    # the next piece's first step in (audit X3: the pieces' logliks summed to -69.53 for -65.29)
    for (_, sm), (_, fi) in zip(smoothed, filtered):
        for got in (sm, sm.filtered):
            assert got.loglik == fi.loglik
        np.testing.assert_array_equal(sm.filtered.last_mean, fi.last_mean)
        np.testing.assert_array_equal(sm.filtered.last_cov, fi.last_cov)
        for got in (sm.filtered, fi):  # their own arrays, as gf.filter's are, not views of the last step's
            assert not np.shares_memory(got.last_mean, got.means) and not np.shares_memory(got.last_cov, got.covs)
    assert sum(sm.loglik for _, sm in smoothed) == pytest.approx(whole.loglik, rel=1e-12)


@pytest.mark.parametrize("engine", ["python", "auto"])  # ("numba" cannot smooth a nonlinear piece to an ending)
@pytest.mark.parametrize("rows", [3, 100])
def test_pieces_of_a_timed_model_with_a_nonlinear_sensor_equal_the_whole_series(engine, rows):
    """A constant-velocity target seen by a range-bearing sensor at irregular times: each piece's model takes
    its steps' dt as controls, which the pieces dropped ("`us` is required", audit N)."""
    rng = np.random.default_rng(4)
    timed = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.RangeBearing(r_range=0.5, r_bearing=0.01))
    times = np.cumsum(rng.uniform(0.2, 1.0, 30))
    track = np.array([2.6, 1.4])[None] + np.array([0.3, 0.5])[None] * times[:, None]
    zs = np.c_[np.hypot(*track.T), np.arctan2(track[:, 1], track[:, 0])] + rng.normal(size=(30, 2)) * [0.7, 0.1]
    prior = gf.Gaussian([2.6, 1.4, 0.0, 0.5], np.eye(4))
    whole = gf.smooth(timed, prior, zs, times=times, engine=engine, check="off")
    filtered = list(filter_pieces(timed, prior, cut(zs, times, rows), timed=True, engine=engine, check="off"))
    smoothed = list(smooth_pieces(timed, prior, cut(zs, times, rows), timed=True, engine=engine, check="off"))[::-1]
    for got, want in ((filtered, whole.filtered), (smoothed, whole)):
        close(joined(got, "means"), want.means)
        close(joined(got, "covs"), want.covs)


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("rows", [1, 3, 17])
def test_pieces_of_a_fixed_model_one_row_each_too(rows, engine):
    rng = np.random.default_rng(1)
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([0.1, 0.01]), R=4.0)
    prior = gf.Gaussian([0.0, 0.0], np.diag([1e6, 1e6]))
    zs = np.cumsum(rng.normal(size=60))[:, None]
    times = np.arange(60.0)
    whole = gf.smooth(model, prior, zs, engine=engine, check="off")
    got = list(smooth_pieces(model, prior, cut(zs, times, rows), engine=engine, check="off"))[::-1]
    close(joined(got, "means"), whole.means)
    close(joined(got, "covs"), whole.covs)


def test_a_singular_prior_and_zero_noise_stay_exact():
    """A prior certain about the velocity and a noiseless velocity: singular covariances throughout."""
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([0.5, 0.0]), R=1.0)
    prior = gf.Gaussian([0.0, 2.0], np.diag([10.0, 0.0]))
    zs = (2.0 * np.arange(1, 41) + np.random.default_rng(3).normal(size=40))[:, None]
    whole = gf.smooth(model, prior, zs, engine="python", check="off")
    got = list(smooth_pieces(model, prior, cut(zs, np.arange(40.0), 9), engine="python", check="off"))[::-1]
    close(joined(got, "means"), whole.means)
    close(joined(got, "covs"), whole.covs)
    assert np.all(joined(got, "covs")[:, 1, 1] == 0.0)


def test_a_diffuse_prior(track):
    model, _, zs, times = track
    fixed = model.at(np.full(len(zs), 0.25))[0]
    whole = gf.filter(fixed, "diffuse", zs, check="off")
    got = list(filter_pieces(fixed, "diffuse", cut(zs, times, 40), check="off"))
    close(joined(got, "means"), whole.means)
    sm = list(smooth_pieces(fixed, "diffuse", cut(zs, times, 1000), check="off"))
    np.testing.assert_allclose(sm[0][1].means, gf.smooth(fixed, "diffuse", zs, check="off").means, rtol=0, atol=0)
    with pytest.raises(ValueError, match="diffuse"):
        list(smooth_pieces(fixed, "diffuse", cut(zs, times, 40), check="off"))


@pytest.mark.parametrize("rows", [40, 61, 100])
def test_a_diffuse_prior_behind_a_gap_longer_than_a_piece(track, rows):
    """The first piece had to identify the state: 150 missing rows before the data raised NotIdentified in
    filter_pieces (and `gaussfuse filter`, whose first piece is 65,536 rows) where gf.filter answers. The
    pieces are now joined until they identify it. Against gf.filter on the whole series."""
    model, _, zs, times = track
    fixed = model.at(np.full(len(zs), 0.25))[0]
    zs = zs.copy()
    zs[:150] = np.nan
    whole = gf.filter(fixed, "diffuse", zs, check="off")
    got = list(filter_pieces(fixed, "diffuse", cut(zs, times, rows), check="off"))
    assert [len(p.zs) for p, _ in got] == [len(p.zs) for p in cut(zs, times, rows)]
    for attr in ("means", "covs", "predicted_means", "innovations"):
        close(joined(got, attr), getattr(whole, attr))
    assert sum(r.loglik for _, r in got) == pytest.approx(whole.loglik, rel=1e-12)
    for (piece, result) in got:  # each piece ends in the belief after its last row
        np.testing.assert_array_equal(result.last_mean, result.means[-1])
    with pytest.raises(gf.inference.diffuse.NotIdentified):
        list(filter_pieces(fixed, "diffuse", cut(np.full_like(zs, np.nan), times, rows), check="off"))
    with pytest.raises(ValueError, match="smoothing in pieces needs a Gaussian prior"):
        list(smooth_pieces(fixed, "diffuse", cut(zs, times, rows), check="off"))


def test_the_spool_is_removed(track, tmp_path):
    model, prior, zs, times = track
    pieces = smooth_pieces(model, prior, cut(zs, times, 50), timed=True, check="off", spool_dir=str(tmp_path))
    next(pieces)
    pieces.close()
    assert list(tmp_path.iterdir()) == []


def test_divergence_in_one_piece_is_the_filters_check(track):
    model, prior, zs, times = track
    bad = zs + np.where(np.arange(len(zs))[:, None] >= 100, 30.0, 0.0)
    with pytest.warns(gf.DivergenceWarning) as want:
        gf.filter(model, prior, bad, times=times)
    with pytest.warns(gf.DivergenceWarning) as got:
        list(filter_pieces(model, prior, cut(bad, times, 1000), timed=True))
    assert str(got[0].message) == str(want[0].message)


def test_divergence_over_pieces_is_the_filters_check(track):
    """Over many pieces, the verdict and the message are gaussfuse.filter's on the whole series. They were an
    online filter's monitor's, which tests its j-th window at level α / (j (j + 1)): a file read in pieces
    missed, from step 60,000 or so, what the whole series' test found (audit EE2)."""
    model, prior, zs, times = track
    bad = zs + np.where(np.arange(len(zs))[:, None] >= 100, 30.0, 0.0)
    with pytest.warns(gf.DivergenceWarning) as want:
        gf.filter(model, prior, bad, times=times)
    for size in (30, 7):
        with pytest.warns(gf.DivergenceWarning) as got:
            list(filter_pieces(model, prior, cut(bad, times, size), timed=True))
        assert [str(w.message) for w in got] == [str(want[0].message)]
        with pytest.raises(gf.DivergenceWarning, match=re.escape(str(want[0].message))):
            list(filter_pieces(model, prior, cut(bad, times, size), timed=True, check="raise"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        list(filter_pieces(model, prior, cut(bad, times, 30), timed=True, check="off"))
        list(filter_pieces(model, prior, cut(zs, times, 30), timed=True))  # a consistent filter: nothing


def test_a_late_divergence_over_many_pieces_is_found_as_in_one():
    """Extra noise in the last 400 of 20,000 steps, read in pieces of 500: the online monitor tests window 790 or
    so at level 1.6e-9, the whole series' test every window at 1.3e-6, and the pieces said nothing where
    gaussfuse.filter warned (audit EE2, whose file was 60,000 rows)."""
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    rng = np.random.default_rng(2)
    T = 20_000
    zs = (np.cumsum(rng.normal(size=T)) + rng.normal(size=T))[:, None]
    zs[-400:] += rng.normal(size=(400, 1)) * 1.4  # extra noise at the end: windows averaging 2.6 per step
    times = np.arange(T, dtype=float)
    prior = gf.Gaussian([0.0], [[1.0]])
    with pytest.warns(gf.DivergenceWarning) as want:
        gf.filter(model, prior, zs)
    with pytest.warns(gf.DivergenceWarning) as got:
        list(filter_pieces(model, prior, cut(zs, times, 500)))
    assert [str(w.message) for w in got] == [str(want[0].message)]
    monitor = DivergenceMonitor(check="off")
    whole = gf.filter(model, prior, zs, check="off")
    assert not monitor.add_many(whole.nis, np.ones(T, dtype=int), range(T))  # what the pieces did before


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("run", [filter_pieces, smooth_pieces])
def test_an_error_names_the_step_of_the_whole_series(track, engine, run):
    """The oracle is the whole series' own error; the pieces named the step within the piece (808 for 9000)."""
    model, prior, zs, times = track
    zs = zs.copy()
    zs[130, 1] = 1e300
    with pytest.raises(FloatingPointError, match=r"^at step 130: ") as whole:
        gf.filter(model, prior, zs, times=times, engine=engine, check="off")
    with pytest.raises(FloatingPointError) as pieces:
        list(run(model, prior, cut(zs, times, 51), timed=True, engine=engine, check="off"))
    assert str(pieces.value) == str(whole.value)


@pytest.mark.parametrize("run", [filter_pieces, smooth_pieces])
def test_a_model_function_error_names_the_step_of_the_whole_series(run):
    """The oracle is the whole series' own ModelFunctionError; the pieces named the step within the piece."""
    def h(x):
        if x[0] > 100:
            raise RuntimeError("out of range")
        return x[:1]

    model = gf.NonlinearModel(f=lambda x: x, h=h, Q=0.01 * np.eye(1), R=np.eye(1))
    prior = gf.Gaussian([0.0], [[1.0]])
    zs = np.zeros((200, 1))
    zs[130] = 1e6
    times = np.arange(200.0)
    with pytest.raises(gf.ModelFunctionError, match=r"^at step 131: `h` raised") as whole:
        gf.filter(model, prior, zs, check="off")
    with pytest.raises(gf.ModelFunctionError) as pieces:
        list(run(model, prior, cut(zs, times, 51), check="off"))
    assert str(pieces.value) == str(whole.value)


@pytest.mark.parametrize("run", [filter_pieces, smooth_pieces])
def test_an_empty_piece_is_named(track, run):
    model, prior, zs, times = track
    pieces = cut(zs, times, 40)
    pieces.insert(2, SimpleNamespace(zs=zs[:0], times=times[:0]))
    with pytest.raises(ValueError, match=r"^piece 2 of the series has no rows; every piece needs at least one\.$"):
        list(run(model, prior, pieces, timed=True, engine="python", check="off"))


@pytest.mark.parametrize("run", [filter_pieces, smooth_pieces])
def test_a_first_piece_of_one_row_is_named(track, run):
    """Timed, it was refused as "`times` must have 2 entries with one measurement", an argument not given, and no
    piece named (audit YY2); later pieces of one row are fine."""
    model, prior, zs, times = track
    pieces = [SimpleNamespace(zs=zs[:1], times=times[:1]), *cut(zs[1:], times[1:], 40)]
    with pytest.raises(ValueError, match=r"^piece 0 of the series has one row, whose time alone gives no time step: "
                                         r"the first piece needs at least two rows"):
        list(run(model, prior, pieces, timed=True, engine="python", check="off"))
    pieces = [SimpleNamespace(zs=zs[:2], times=times[:2]), SimpleNamespace(zs=zs[2:3], times=times[2:3])]
    assert len(list(run(model, prior, pieces, timed=True, engine="python", check="off"))) == 2


def test_a_diffuse_first_piece_of_one_missing_row_is_joined_to_the_next(track):
    """The check of a first piece of one row refused this one, which is joined to the next before it runs, as a
    diffuse prior's pieces are until they identify the state (review R54). Against one piece."""
    model, _, zs, times = track
    missing = zs[:40].copy()
    missing[0] = np.nan
    whole = list(filter_pieces(model, "diffuse", [SimpleNamespace(zs=missing, times=times[:40])], timed=True,
                               engine="python", check="off"))[-1][1]
    split = [SimpleNamespace(zs=missing[:1], times=times[:1]), SimpleNamespace(zs=missing[1:], times=times[1:40])]
    last = list(filter_pieces(model, "diffuse", split, timed=True, engine="python", check="off"))[-1][1]
    np.testing.assert_allclose(last.means[-1], whole.means[-1], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("run", [filter_pieces, smooth_pieces])
def test_a_piece_of_the_wrong_shape_is_named(track, run):
    """A (1, T_c, m) piece gave one row of its T_c, and the others' errors named neither the piece nor what was
    given (audit BB3)."""
    model, prior, zs, times = track
    for k, wrong, message in [
            (0, SimpleNamespace(zs=zs[None, :40], times=times[:40]), r"`zs` must have shape \(T_c, 2\); got shape "
                                                                      r"\(1, 40, 2\)"),
            (2, SimpleNamespace(zs=np.ones((40, 3)), times=times[80:120]), r"`zs` must have shape \(T_c, 2\); got "
                                                                           r"shape \(40, 3\)"),
            (2, SimpleNamespace(zs=zs[80:120], times=times[80:82]), r"`times` must have shape \(40,\), one a row "
                                                                    r"of its `zs`; got shape \(2,\)")]:
        pieces = cut(zs, times, 40)
        pieces[k] = wrong
        with pytest.raises(ValueError, match=rf"^piece {k} of the series: {message}\.$"):
            list(run(model, prior, pieces, timed=True, engine="python", check="off"))


@pytest.mark.parametrize("run", [filter_pieces, smooth_pieces])
def test_an_error_names_the_time_as_written_when_the_pieces_have_it(track, run):
    """A file's pieces carry their time cells: an error names the step's, which finds its row (audit BB2: a
    0-based step did not); a time out of order names the step of the whole series (it named the piece's)."""
    model, prior, zs, times = track
    zs = zs.copy()
    zs[130, 1] = 1e300
    pieces = [SimpleNamespace(**vars(p), time_text=[f"t{i}" for i in range(40 * c, 40 * c + len(p.zs))])
              for c, p in enumerate(cut(zs, times, 40))]
    with pytest.raises(FloatingPointError, match=r"^at step 130 \(time t130\): the filtered mean"):
        list(run(model, prior, pieces, timed=True, engine="python", check="off"))
    late = cut(zs, times, 40)
    late[1].times = late[1].times - 100.0
    with pytest.raises(ValueError, match=r"^`times` must be strictly increasing; step 40 has dt = "):
        list(run(model, prior, late, timed=True, engine="python", check="off"))


@pytest.mark.parametrize("method, options", [("ekf", {}), ("ukf", {"alpha": 0.5}), ("ghkf", {"order": 5}),
                                             ("iekf", {"iterations": 40}),
                                             ("iekf", {"iterations": 1})])  # (the plain EKS: review R29)
def test_a_nonlinear_model_in_pieces_takes_the_method_asked_for(method, options):
    """A NonlinearModel in pieces always ran its default method (the UKF): 0.63 off an EKF's means (audit BB3).
    The oracle is gf.filter and gf.smooth on the whole series with the same method and options."""
    model = gf.NonlinearModel(f=lambda x: np.array([x[0] + 0.1 * x[1], 0.95 * x[1] - 0.2 * np.sin(x[0])]),
                              h=lambda x: np.array([np.sin(x[0]) + 0.5 * x[0]]), Q=np.diag([1e-3, 1e-2]), R=0.05)
    prior = gf.Gaussian([0.3, 0.0], np.diag([0.5, 0.5]))
    zs = np.random.default_rng(3).normal(scale=0.5, size=(90, 1)).cumsum(axis=0) * 0.1
    times = np.arange(90.0)
    whole = gf.filter(model, prior, zs, method=method, engine="python", check="off", **options)
    got = list(filter_pieces(model, prior, cut(zs, times, 25), method=method, engine="python", check="off", **options))
    close(joined(got, "means"), whole.means)
    close(joined(got, "covs"), whole.covs)
    if method == "iekf" and options["iterations"] > 1:  # its smoother's passes are over the whole series
        with pytest.raises(ValueError, match=r"^`method` 'iekf' smooths by passes over the whole series"):
            list(smooth_pieces(model, prior, cut(zs, times, 25), method=method, check="off", **options))
        return
    smoothed = gf.smooth(model, prior, zs, method=method, engine="python", check="off", **options)
    got = sorted(smooth_pieces(model, prior, cut(zs, times, 25), method=method, engine="python", check="off",
                               **options), key=lambda pr: pr[0].times[0])
    close(joined(got, "means"), smoothed.means)
    close(joined(got, "covs"), smoothed.covs)
    with pytest.raises(TypeError, match="unknown option"):
        list(filter_pieces(model, prior, cut(zs, times, 25), method=method, check="off", gatee=3.0))


def test_bad_check():
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    with pytest.raises(ValueError, match="`check` must be one of"):
        list(filter_pieces(model, gf.Gaussian(0.0, 1.0), [], check="loud"))


def test_a_nonlinear_models_pieces_run_forward_and_backward_on_one_engine():
    """With engine="auto", a nonlinear model's pieces are smoothed on the readable path; their forward pass
    ran compiled, so a piece's loglik and starting belief came from another arithmetic than its smoothed and
    filtered beliefs (3e-17 apart in `last_mean`). Both passes now run on the readable path."""
    rng = np.random.default_rng(4)
    model = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.RangeBearing(r_range=0.5, r_bearing=0.01), dt=0.5)
    times = 0.5 * np.arange(40.0)
    track = np.array([2.6, 1.4])[None] + np.array([0.3, 0.5])[None] * times[:, None]
    zs = np.c_[np.hypot(*track.T), np.arctan2(track[:, 1], track[:, 0])] + rng.normal(size=(40, 2)) * [0.7, 0.1]
    prior = gf.Gaussian([2.6, 1.4, 0.0, 0.5], np.eye(4))
    got = list(smooth_pieces(model, prior, cut(zs, times, 7), engine="auto", check="off"))
    want = list(smooth_pieces(model, prior, cut(zs, times, 7), engine="python", check="off"))
    for (_, g), (_, w) in zip(got, want, strict=True):
        for a, b in ((g, w), (g.filtered, w.filtered)):
            assert a.loglik == b.loglik
            np.testing.assert_array_equal(a.means, b.means)
            np.testing.assert_array_equal(a.covs, b.covs)
        np.testing.assert_array_equal(g.filtered.last_mean, w.filtered.last_mean)
