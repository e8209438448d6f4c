"""Consistency diagnostics: NEES/NIS intervals catch a mistuned filter, whiteness, RMSE."""

import re
import warnings

import numpy as np
import pytest
from scipy import stats

import gaussfuse as gf
from gaussfuse import diagnostics as dg

MODEL = gf.constant_velocity(dt=0.5, q=0.2, r=1.0, dim=2)
PRIOR = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))


def simulate(model, prior, runs, T, seed):
    rng = np.random.default_rng(seed)
    x = rng.multivariate_normal(prior.mean, prior.cov, size=runs)
    truth, zs = np.empty((runs, T, model.n)), np.empty((runs, T, model.m))
    for k in range(T):
        x = x @ model.F.T + rng.multivariate_normal(np.zeros(model.n), model.Q, size=runs)
        truth[:, k] = x
        zs[:, k] = x @ model.H.T + rng.multivariate_normal(np.zeros(model.m), model.R, size=runs)
    return truth, zs


@pytest.fixture(scope="module")
def monte_carlo():
    return simulate(MODEL, PRIOR, runs=100, T=60, seed=1)


def test_tuned_filter_is_consistent_over_100_runs(monte_carlo):
    truth, zs = monte_carlo
    res = gf.filter(MODEL, PRIOR, zs, engine="python")
    report = dg.consistency(res, truth)
    assert report.runs == 100
    assert report.nees_interval[0] <= report.nees <= report.nees_interval[1]
    assert report.nis_ok and report.nees_ok and report.consistent
    # across runs, at each step: the average NEES stays within its interval at ~95% of steps
    lo, hi = dg.chi2_interval(4, count=100)
    per_step = dg.nees(truth - res.means, res.covs).mean(axis=0)
    assert np.mean((per_step >= lo) & (per_step <= hi)) > 0.85
    assert "consistent" in str(report)


def test_q_100_times_too_small_is_flagged(monte_carlo):
    truth, zs = monte_carlo
    small = gf.LinearModel(MODEL.F, MODEL.H, MODEL.Q / 100, MODEL.R)
    report = dg.consistency(gf.filter(small, PRIOR, zs, engine="python"), truth)
    assert not report.nees_ok and report.nees > report.nees_interval[1]
    assert not report.nis_ok and not report.consistent
    assert "overconfident" in str(report)
    big = gf.LinearModel(MODEL.F, MODEL.H, MODEL.Q, MODEL.R * 100)
    assert "too cautious" in str(dg.consistency(gf.filter(big, PRIOR, zs, engine="python"), truth))


def test_nis_and_nees_against_direct_formulas():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 3, 3))
    C = A @ np.swapaxes(A, -1, -2) + np.eye(3)
    e = rng.standard_normal((5, 3))
    direct = np.array([ei @ np.linalg.solve(Ci, ei) for ei, Ci in zip(e, C)])
    np.testing.assert_allclose(dg.nees(e, C), direct, rtol=1e-12)
    e[1, 0] = np.nan  # a missing component: the others' χ²_2
    e[2, :] = np.nan
    got = dg.nis(e, C)
    o = [1, 2]
    assert got[1] == pytest.approx(e[1, o] @ np.linalg.solve(C[1][np.ix_(o, o)], e[1, o]), rel=1e-12)
    assert np.isnan(got[2])


@pytest.mark.parametrize("dof, count", [(1, 1), (3, 50), (2, 7)])
def test_chi2_interval_keeps_both_tails_at_high_confidence(dof, count):
    """Audit OO1: the lower bound was the upper-tail quantile at 1 - alpha/2, which rounds alpha away: at a
    confidence of 1 - 1e-15 it was 21% off for one degree of freedom. Oracle: the regularised incomplete gamma
    functions in mpmath at 60 digits, inverted by bisection in log y (each tail is monotone)."""
    import mpmath as mp

    k = dof * count

    def quantile(tail: float, lower: bool) -> float:
        with mp.workdps(60):
            a, lo, hi = mp.mpf(k) / 2, mp.mpf(-900), mp.log(mp.mpf(100 * k + 1000))
            for _ in range(300):
                mid = (lo + hi) / 2
                y = mp.exp(mid)
                p = mp.gammainc(a, 0, y, regularized=True) if lower else 1 - mp.gammainc(a, y, mp.inf, regularized=True)
                lo, hi = (mid, hi) if (p < tail if lower else p < 1 - mp.mpf(tail)) else (lo, mid)
            return float(2 * mp.exp(lo) / count)

    for confidence in (0.95, 1 - 1e-6, 1 - 1e-9, 1 - 1e-12, 1 - 1e-15):
        tail = (1.0 - confidence) / 2.0  # exact in float64 for these confidences
        lo, hi = dg.chi2_interval(dof, count, confidence)
        assert lo == pytest.approx(quantile(tail, lower=True), rel=1e-12, abs=0.0), confidence  # (bounds of 1e-31)
        assert hi == pytest.approx(quantile(tail, lower=False), rel=1e-12, abs=0.0), confidence


def test_chi2_interval_matches_scipy():
    lo, hi = dg.chi2_interval(3, count=50, confidence=0.99)
    assert lo == pytest.approx(stats.chi2.ppf(0.005, 150) / 50)
    assert hi == pytest.approx(stats.chi2.ppf(0.995, 150) / 50)
    with pytest.raises(ValueError, match=r"`confidence` must be in \(0, 1\); got 1.5"):
        dg.chi2_interval(3, confidence=1.5)


def test_whiteness_detects_correlated_innovations():
    truth, zs = simulate(MODEL, PRIOR, runs=1, T=400, seed=4)
    good = gf.filter(MODEL, PRIOR, zs[0])
    w = dg.whiteness(good.innovations, good.innovation_covs)
    assert w.white and np.all(np.abs(w.autocorrelation) < 3 * w.bound)
    # a random-walk model for a moving target leaves a trend in the innovations
    rw = gf.LinearModel(np.eye(4), MODEL.H, MODEL.Q, MODEL.R)
    bad = gf.filter(rw, PRIOR, zs[0])
    wb = dg.whiteness(bad.innovations, bad.innovation_covs)
    assert not wb.white and wb.autocorrelation[0] > wb.bound
    with pytest.raises(ValueError, match=r"`lags` must be an integer in \[1, 399\]"):
        dg.whiteness(good.innovations, good.innovation_covs, lags=400)


def test_rmse():
    assert dg.rmse([[3.0, 4.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]) == pytest.approx(np.sqrt(12.5))
    np.testing.assert_allclose(dg.rmse(np.ones((2, 3, 1)), np.zeros((2, 3, 1)), axis=1), [1.0, 1.0])
    with pytest.raises(ValueError, match=r"`truth` must have shape \(2, 2\), that of `estimates`"):
        dg.rmse(np.ones((2, 2)), np.ones((3, 2)))
    # a 1-D array is a series of scalars: the square root of the mean square, not the norm of one vector
    errors = np.array([0.5, -2.0, 1.0, 3.0])
    assert dg.rmse(errors, np.zeros(4)) == pytest.approx(np.sqrt(np.mean(errors**2)))
    assert dg.rmse(errors, np.zeros(4)) == dg.rmse(errors[:, None], np.zeros((4, 1)))


def test_rmse_of_errors_near_the_ends_of_the_floats():
    """The squares were formed directly: errors of 1e155 gave inf and of 1e-170 gave 0 (audit DD2). The oracle is
    analytic: errors (e, e) and (2e, 0) have an RMSE of e sqrt(3)."""
    for e in (1e300, 1e200, 1e155, 1.0, 1e-170, 1e-200, 1e-300):
        errors = np.array([[e, e], [2 * e, 0.0]])
        assert dg.rmse(errors, np.zeros((2, 2))) == pytest.approx(e * np.sqrt(3.0), rel=1e-15, abs=0.0)
    stacked = np.array([[[1e200, 0.0]], [[1e-200, 0.0]]])  # each mean over its own scale
    np.testing.assert_allclose(dg.rmse(stacked, np.zeros_like(stacked), axis=1), [1e200, 1e-200], rtol=1e-15)
    assert dg.rmse([1e308], [-1e308]) == np.inf  # a difference beyond the largest float
    with warnings.catch_warnings():  # no estimates: NaN, with NumPy's warnings of a mean of nothing (review R28)
        warnings.simplefilter("ignore", RuntimeWarning)
        assert np.isnan(dg.rmse(np.zeros((0, 2)), np.zeros((0, 2)))) and np.isnan(dg.rmse([], []))


def test_a_monitor_with_check_off_says_nothing_but_still_finds_the_windows():
    """"off" was accepted and then warned like "warn" (audit DD2)."""
    update = gf.kalman.update(np.zeros(1), np.eye(1), np.array([40.0]), np.eye(1), np.eye(1))
    quiet = dg.DivergenceMonitor(window=4, check="off")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for k in range(8):
            quiet.observe(update, k, "steps {}-{}")
    tested = dg.DivergenceMonitor(window=4, check="off")  # the windows are still tested
    assert [tested.add(update.nis, 1, k) for k in range(4)][-1] == (0, 3, update.nis)
    loud = dg.DivergenceMonitor(window=4)
    with pytest.warns(gf.DivergenceWarning):
        for k in range(8):
            loud.observe(update, k, "steps {}-{}")


def test_the_default_whiteness_lags_count_the_steps_observed_in_full():
    """The docstring said min(10, T // 5) of all T steps (audit DD2)."""
    model = gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=0.1 * np.eye(2), R=np.eye(2))
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = np.array(gf.simulate(model, prior, 40, rng=0).measurements)
    zs[::2, 1] = np.nan  # 20 of the 40 steps complete: min(10, 20 // 5) = 4 lags
    assert dg.consistency(gf.filter(model, prior, zs)).whiteness.autocorrelation.size == 4
    zs[:35, 1] = np.nan  # 5 complete steps: no test
    assert dg.consistency(gf.filter(model, prior, zs)).whiteness is None


# ---------------------------------------------------------------------------
# divergence: the chi-square window test behind filter(check=...)
# ---------------------------------------------------------------------------


def test_divergence_flags_a_window_above_the_laurent_massart_threshold():
    """Flagged exactly when a window's sum reaches d + 2√(d t) + 2t, t = log(windows / 1e-3)."""
    T, W = 200, 50
    windows = 7  # starts 0, 25, ..., 150
    t = np.log(windows / 1e-3)
    threshold = W + 2 * np.sqrt(W * t) + 2 * t
    below = np.ones(T)
    below[100:150] = (threshold - 1e-6) / W
    above = below.copy()
    above[100:150] = (threshold + 1e-6) / W
    assert dg.divergence(below, np.ones(T)) == []
    got = dg.divergence(above, np.ones(T))
    assert [(s, a, b) for s, a, b, _ in got] == [(0, 100, 149)]
    assert got[0][3] == pytest.approx((threshold + 1e-6) / W)


def test_divergence_skips_missing_steps_merges_ranges_and_names_series():
    v = np.ones((2, 300))
    v[1, 40:160] = 4.0
    v[1, 60] = np.nan  # nothing observed there: left out of its windows
    dof = np.where(np.isnan(v), 0, 1)
    got = dg.divergence(v, dof)
    assert [(s, a, b) for s, a, b, _ in got] == [(1, 25, 174)]
    assert dg.divergence(np.zeros(0), np.zeros(0)) == []
    assert dg.divergence(np.full(10, 50.0), np.ones(10))[0][1:3] == (0, 9)  # a run shorter than a window


def test_divergence_takes_a_scalar_dof_as_that_dof_at_every_step():
    """A scalar dof is the per-step array it stands for, flagged ranges and averages alike."""
    v = np.random.default_rng(3).chisquare(2, size=(3, 260))
    v[2, 100:180] *= 4.0
    per_step = dg.divergence(v, np.full(v.shape, 2))
    assert {s for s, *_ in per_step} == {2}
    assert dg.divergence(v, 2) == per_step
    v[0, 7] = np.nan  # a step with nothing observed still counts no degrees of freedom
    assert dg.divergence(v, 2) == dg.divergence(v, np.where(np.isnan(v), 0, 2))


def test_divergence_rarely_flags_consistent_filters():
    """Seeded χ² draws of 400 consistent runs of 300 steps with 2 components: the rate is at most 1e-3 per run."""
    rng = np.random.default_rng(12)
    runs = rng.chisquare(2, size=(400, 300))
    flagged = sum(bool(dg.divergence(run, np.full(300, 2))) for run in runs)
    assert flagged == 0
    # and a filter twice as confident as it should be is flagged in every run
    assert all(dg.divergence(2.0 * run, np.full(300, 2)) for run in runs[:50])


def _reference_monitor(nis, dofs, window, false_alarm=dg.DIVERGENCE_FALSE_ALARM):
    """DivergenceMonitor's rule written out update by update: the oracle of add and add_many."""
    kept = [(v, d, k) for k, (v, d) in enumerate(zip(nis, dofs)) if d > 0]
    stride, reports, tested, previous = max(window // 2, 1), [], 0, False
    for i in range(window - 1, len(kept), stride):
        values = kept[i - window + 1:i + 1]
        total, d = sum(v for v, _, _ in values), float(sum(d for _, d, _ in values))
        tested += 1
        t = np.log(tested * (tested + 1) / false_alarm)
        flagged = total >= d + 2 * np.sqrt(d * t) + 2 * t
        if flagged and not previous:
            reports.append((values[0][2], values[-1][2], total / d))
        previous = flagged
    return reports


@pytest.mark.parametrize("seed", range(40))
def test_monitor_in_pieces_matches_the_rule_update_by_update(seed):
    rng = np.random.default_rng(seed)
    T, window = int(rng.integers(1, 500)), int(rng.integers(1, 70))
    dofs = rng.choice([0, 1, 2, 3], T)
    nis = rng.chisquare(np.maximum(dofs, 1)) * np.where(np.arange(T) % 97 > 60, 5.0, 1.0)
    nis[dofs == 0] = 0.0  # nothing observed: a NIS of 0 (a positive one is refused since review R45)
    want = _reference_monitor(nis, dofs, window)
    one, many = dg.DivergenceMonitor(window=window), dg.DivergenceMonitor(window=window)
    singly = [r for k in range(T) if (r := one.add(nis[k], dofs[k], k)) is not None]
    pieces, mixed, k = [], [], 0
    both = dg.DivergenceMonitor(window=window)
    while k < T:
        n = int(rng.integers(1, 120))
        steps = range(k, min(k + n, T))  # (one label per update: the last piece is shorter)
        pieces += many.add_many(nis[k:k + n], dofs[k:k + n], steps)
        if n % 2:  # the two mixed on one monitor
            mixed += both.add_many(nis[k:k + n], dofs[k:k + n], steps)
        else:
            mixed += [r for j in range(k, min(k + n, T)) if (r := both.add(nis[j], dofs[j], j)) is not None]
        k += n
    for got in (singly, pieces, mixed):
        assert [(a, b) for a, b, _ in got] == [(a, b) for a, b, _ in want]
        np.testing.assert_allclose([avg for *_, avg in got], [avg for *_, avg in want], rtol=1e-12)


@pytest.mark.parametrize("call, error, match", [
    (lambda: dg.divergence(np.ones(10), 1, window=0), ValueError, r"`window` must be a positive integer; got 0"),
    (lambda: dg.divergence(np.ones(10), 1, window=-1), ValueError, r"`window` must be a positive integer"),
    (lambda: dg.divergence(np.ones(10), 1, window=2.5), TypeError, r"`window` must be a positive integer"),
    (lambda: dg.divergence(np.ones(10), 1, false_alarm=0), ValueError, r"`false_alarm` must be a probability"),
    (lambda: dg.divergence(np.ones(10), 1, false_alarm=-1), ValueError, r"`false_alarm` must be a probab"),
    (lambda: dg.chi2_interval(0), ValueError, r"`dof` must be a positive integer; got 0"),
    (lambda: dg.chi2_interval(2, 0), ValueError, r"`count` must be a positive integer; got 0"),
    (lambda: dg.DivergenceMonitor(window=-3), ValueError, r"`window` must be a positive integer"),
    (lambda: dg.DivergenceMonitor(false_alarm=2.0), ValueError, r"`false_alarm` must be a probability"),
])
def test_test_settings_are_checked(call, error, match):
    """window=0 ran no test and answered "not diverging"; -1 gave an IndexError, 2.5 a cast error, false_alarm=0 a
    ZeroDivisionError, chi2_interval(0) (nan, nan)."""
    with pytest.raises(error, match=match):
        call()


def test_one_huge_nis_does_not_spoil_the_later_windows():
    """Window sums were differences of running sums: after one NIS of 7.7e17 every later window was rounded to a
    multiple of 128, so consistent windows (averages near 1) were flagged and a real divergence missed. Against
    each window summed on its own."""
    rng = np.random.default_rng(4)
    v = rng.chisquare(3, size=1000)
    v[500:] *= 3.0  # diverging from step 500
    v[10] = 7.7e17
    flagged = dg.divergence(v, 3)
    assert flagged[0][:3] == (0, 0, 49)
    later = [(a, b, avg) for _, a, b, avg in flagged[1:]]
    assert later and all(a >= 475 and avg > 2.0 for a, b, avg in later)
    monitor = dg.DivergenceMonitor.for_check("warn")
    reports = monitor.add_many(v, np.full(1000, 3), list(range(1000)))
    one_by_one = dg.DivergenceMonitor.for_check("warn")
    singles = [r for i in range(1000) if (r := one_by_one.add(v[i], 3, i)) is not None]
    assert [r[:2] for r in reports] == [r[:2] for r in singles] and any(r[0] >= 475 for r in reports)


def test_a_gate_that_rejects_everything_after_a_jump_is_named():
    """Rejected steps have no innovation, so the check saw nothing when the gate rejected all 200 measurements after
    a level jumped by 20 (the estimate 110 sd off). The gate's counts are tested now: at least half rejected, and
    beyond the binomial tail of a consistent filter's 1%; a consistent gated run (1.3% rejected, in runs of up to
    8) is not flagged."""
    rng = np.random.default_rng(0)
    model, prior = gf.LinearModel(F=1.0, H=1.0, Q=1e-4, R=1.0), gf.Gaussian([0.0], [[1.0]])
    z = rng.normal(size=300)
    z[100:] += 20.0
    with pytest.warns(gf.DivergenceWarning, match=r"The gate rejected 200 of 225 over steps 75-299"):
        gf.filter(model, prior, z, gate=0.99)
    with pytest.warns(gf.DivergenceWarning, match=r"The gate rejected"):
        gf.smooth(model, prior, z, gate=0.99)
    rng = np.random.default_rng(3)
    level = np.cumsum(rng.normal(scale=10, size=10_000))
    with warnings.catch_warnings():
        warnings.simplefilter("error", gf.DivergenceWarning)
        r = gf.filter(gf.LinearModel(1.0, 1.0, 100.0, 1.0), gf.Gaussian([0.0], [[100.0]]),
                      level + rng.normal(size=10_000), gate=0.99)
    assert 0.01 < r.rejected.mean() < 0.02


def test_rejections_is_the_binomial_tail_over_half():
    """Against scipy.stats.binom: a window of 50 offered with 26 rejected is flagged at p = 0.01, 25 of 60 is not
    (under half), and 0 rejected never is."""
    rejected, offered = np.zeros(100, dtype=int), np.ones(100, dtype=int)
    rejected[30:56] = 1  # 26 in the window 25-74 of 50
    got = dg.rejections(rejected, offered, 0.99)
    assert got and got[0][1] <= 30 and got[0][2] >= 55
    assert stats.binom.sf(25, 50, 0.01) < 1e-3 / 3
    assert dg.rejections(np.zeros(100), offered, 0.99) == []
    sparse = np.zeros(100, dtype=int)
    sparse[::4] = 1  # a quarter: far beyond 1%, but under half
    assert dg.rejections(sparse, offered, 0.99) == []


def test_the_nees_verdict_holds_its_confidence_over_consistent_runs():
    """The NEES average over time was given the χ² interval of independent values, but a run's estimation errors
    are correlated: a consistent local level was called inconsistent in 53% of runs (audit N). One run now gets no
    interval; N runs a t interval on their time averages, which 95% of consistent batches pass."""
    rng = np.random.default_rng(12)
    model, prior = gf.LinearModel(1.0, 1.0, 0.01, 1.0), gf.Gaussian([0.0], [[1.0]])
    passed = []
    for _ in range(200):
        x = rng.normal(size=(20, 1)) + np.cumsum(rng.normal(scale=0.1, size=(20, 100)), axis=1)
        z = x + rng.normal(size=x.shape)
        report = dg.consistency(gf.filter(model, prior, z[..., None], check="off"), truth=x[..., None])
        passed.append(report.nees_ok)
    assert 0.90 <= np.mean(passed) <= 0.99  # 95% expected; sd of the share over 200 batches 1.5%
    one = dg.consistency(gf.filter(model, prior, z[0, :, None], check="off"), truth=x[0, :, None])
    assert one.nees is not None and one.nees_interval is None and one.nees_ok is None and "one run" in str(one)


@pytest.mark.parametrize("m", [1, 3])
def test_the_whiteness_bound_is_crossed_at_its_share_of_lags(m):
    """The bound was one component's while the autocorrelation is the mean over m: with m = 3 white components
    0.05% of the lags fell outside a 95% bound."""
    rng = np.random.default_rng(5)
    outside = []
    for _ in range(400):
        w = dg.whiteness(rng.normal(size=(200, m)), np.broadcast_to(np.eye(m), (200, m, m)), 10, 0.95)
        outside.append(np.abs(w.autocorrelation) > w.bound)
    assert 0.035 <= np.mean(outside) <= 0.065  # 5% expected; sd of the share over 4,000 lags 0.35%


def test_consistency_takes_every_filter_result_that_has_innovations():
    """A diffuse prior's result (NaN innovation covariances at its first steps) raised about NaN, keep='means' named
    a non-existent argument, a SmoothResult gave a bare AttributeError (audit N). The filter's own NIS are used."""
    rng = np.random.default_rng(2)
    model = gf.LinearModel(1.0, 1.0, 0.5, 1.0)
    z = np.cumsum(rng.normal(scale=np.sqrt(0.5), size=300)) + rng.normal(size=300)
    full = dg.consistency(gf.filter(model, gf.Gaussian([0.0], [[10.0]]), z))
    diffuse = dg.consistency(gf.filter(model, "diffuse", z))
    means = dg.consistency(gf.filter(model, gf.Gaussian([0.0], [[10.0]]), z, keep="means"))
    assert full.nis_ok and diffuse.nis_ok and means.nis == pytest.approx(full.nis, rel=1e-12)
    assert means.whiteness is None and full.whiteness is not None
    with pytest.raises(TypeError, match=r"^`result` must be a FilterResult .* its \.filtered"):
        dg.consistency(gf.smooth(model, gf.Gaussian([0.0], [[10.0]]), z))
    with pytest.raises(ValueError, match=r"keep='last'"):
        dg.consistency(gf.filter(model, gf.Gaussian([0.0], [[10.0]]), z, keep="last"))


@pytest.mark.parametrize("call, error, message", [
    (lambda: dg.divergence(np.ones(200), np.ones(7)), ValueError, r"^`dof` must have shape \(\) or one broadcastable"),
    (lambda: dg.divergence(np.ones(200), -1), ValueError, r"^`dof` must be non-negative integers"),
    (lambda: dg.divergence(np.ones(200), 0.5), ValueError, r"^`dof` must be non-negative integers"),
    (lambda: dg.divergence(np.ones(200), True), TypeError, r"^`dof` must be an array of numbers"),
    (lambda: dg.divergence("abc", 1), TypeError, r"^`nis_values` must be an array of numbers"),
    (lambda: dg.divergence(np.ones((2, 3, 50)), 1), ValueError, r"^`nis_values` must have shape \(T,\) or \(N, T\)"),
    (lambda: dg.divergence(-np.ones(200), 1), ValueError, r"^`nis_values` must be non-negative"),
    (lambda: dg.DivergenceMonitor(check="rasie"), ValueError, r"^`check` must be 'warn', 'raise' or 'off'"),
    (lambda: dg.chi2_interval(2, confidence="0.9"), TypeError, r"^`confidence` must be a probability"),
    (lambda: dg.nis(1.0, 1.0), ValueError, r"^`innovations` must have shape \(\.\.\., m\)"),
    (lambda: dg.nis(np.ones(2), np.ones(2)), ValueError, r"^`innovation_covs` must have shape \(2, 2\) to match"),
    (lambda: dg.whiteness(np.ones((50, 1)), np.ones((50, 1, 1)), confidence=2), ValueError, r"^`confidence` must be"),
])
def test_diagnostics_name_their_bad_arguments(call, error, message):
    """Bare NumPy errors, garbled names ("innovations covariances"), and silent acceptance (negative or fractional
    dof, negative NIS, check='rasie', confidence=2) before (audit N)."""
    with pytest.raises(error, match=message):
        call()


def test_consistency_leaves_out_a_diffuse_prior_s_first_steps():
    """A diffuse prior's first means and covariances are NaN (not identified yet): with the truth, consistency
    raised a ValueError naming `estimates` (an argument of rmse, not its own); without it, it left out the
    whiteness test of a series with 98 complete innovations. Both now use the identified steps only."""
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=np.diag([0.1, 0.05]), R=1.0)
    sim = gf.simulate(model, gf.Gaussian([0.0, 1.0], np.eye(2)), 100, size=5, rng=0)
    res = gf.filter(model, "diffuse", sim.measurements)
    known = np.isfinite(res.means).all(axis=-1)
    assert not known.all() and known[:, 2:].all()
    report = dg.consistency(res, sim.states)
    want = dg.nees(sim.states - res.means, res.covs)[known].mean()
    assert report.nees == pytest.approx(want, rel=1e-12) and np.isfinite(report.nees)
    assert report.rmse == pytest.approx(dg.rmse(res.means[known], sim.states[known]), rel=1e-12)
    one = gf.filter(model, "diffuse", sim.measurements[0])
    steps = np.isfinite(one.innovation_covs).all(axis=(1, 2))
    want = dg.whiteness(one.innovations[steps], one.innovation_covs[steps], 10)
    assert dg.consistency(one).whiteness.p_value == pytest.approx(want.p_value, rel=1e-12)


def test_nees_takes_a_covariance_that_knows_a_state_exactly():
    """A constant offset known exactly (its prior variance and Q zero): the filtered covariances are singular,
    and nees and consistency raised "`covs` is not positive definite". The NEES is eᵀ P⁺ e over P's range,
    χ² with rank(P) degrees of freedom, here e₀² / P₀₀ (audit Z)."""
    model = gf.LinearModel(F=[[1.0, 0.5], [0.0, 1.0]], H=[[1.0, 0.0]], Q=np.diag([0.1, 0.0]), R=1.0)
    prior = gf.Gaussian([0.0, 1.0], np.diag([1.0, 0.0]))
    sim = gf.simulate(model, prior, 100, size=20, rng=0)
    res = gf.filter(model, prior, sim.measurements)
    e = sim.states - res.means
    assert (e[..., 1] == 0.0).all()
    np.testing.assert_allclose(dg.nees(e, res.covs), e[..., 0] ** 2 / res.covs[..., 0, 0], rtol=1e-12)
    # a correlated singular covariance: P = g gᵀ + h hᵀ in 3 states, the error in its range
    g, h = np.array([1.0, 2.0, -1.0]), np.array([0.5, 0.0, 3.0])
    P = np.outer(g, g) + np.outer(h, h)
    err = 0.3 * g - 1.2 * h
    want = err @ np.linalg.pinv(P) @ err
    assert dg.nees(err[None], P[None])[0] == pytest.approx(want, rel=1e-10)
    report = dg.consistency(res, sim.states)
    assert report.nees == pytest.approx(np.mean(e[..., 0] ** 2 / res.covs[..., 0, 0]), rel=1e-12)
    assert report.nees_interval[0] < 1.0 < report.nees_interval[1]  # centred on rank 1, not n = 2
    assert sum(report.nees_interval) / 2 == pytest.approx(1.0, rel=1e-12)


def test_a_huge_average_is_shown_with_an_exponent():
    """A divergence message printed a window's average with two decimals: a series scaled by 1e150 made a
    150-digit number."""
    model = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[1e-30]], R=[[1.0]])
    zs = 1e100 * np.random.default_rng(0).standard_normal(200)  # data 1e100 times the model's scale
    with pytest.warns(gf.DivergenceWarning, match=r"average, per observed component, \d\.\d\de\+\d+ over steps") as w:
        gf.filter(model, gf.Gaussian([0.0], [[1.0]]), zs)
    assert len(str(w[0].message)) < 600


def test_consistency_and_rmse_wrap_the_errors_of_angle_components():
    """A heading crossing ±π: the filter wraps its means, so truth - mean was 2π off across the cut (and off by
    turns where the truth was not wrapped): NEES 249 for 2.13, called consistent (the runs' spread widening
    its interval), and RMSE 0.224 for 0.0386."""
    def f(x):
        return np.array([x[0] + x[1], x[1]])

    def h(x):
        return np.array([np.cos(x[0]), np.sin(x[0])])

    model = gf.NonlinearModel(f, h, Q=np.diag([1e-4, 1e-6]), R=0.01 * np.eye(2), state_angles=(0,))
    prior = gf.Gaussian([3.0, 0.1], np.diag([1e-4, 1e-6]))
    sim = gf.simulate(model, prior, 40, size=20, rng=100)
    res = gf.filter(model, prior, sim.measurements, method="ekf", check="off")
    e = sim.states - res.means
    e[..., 0] = np.mod(e[..., 0] + np.pi, 2 * np.pi) - np.pi  # the oracle: errors wrapped by hand
    want_nees = np.einsum("...i,...ij,...j->...", e, np.linalg.inv(res.covs), e).mean()
    want_rmse = np.sqrt(np.mean(np.sum(e**2, axis=-1)))
    for angles in ((0,), [True, False], model.state_angles):
        report = dg.consistency(res, sim.states, angles=angles)
        assert report.nees == pytest.approx(want_nees, rel=1e-9) and report.rmse == pytest.approx(want_rmse, rel=1e-12)
        assert dg.rmse(res.means, sim.states, angles=angles) == pytest.approx(want_rmse, rel=1e-12)
    assert 1.0 < want_nees < 3.0 and report.nees_ok
    turned = sim.states + [2 * np.pi, 0.0]  # the same headings, one turn on (as an unwrapped truth would be)
    assert dg.consistency(res, turned, angles=(0,)).nees == pytest.approx(want_nees, rel=1e-9)
    assert dg.consistency(res, turned).rmse > 5 * want_rmse  # without `angles`: errors of 2π
    with pytest.raises(ValueError, match=r"^`angles` must hold component indices in \[-2, 2\)"):
        dg.consistency(res, sim.states, angles=[2])
    with pytest.raises(ValueError, match=r"^`angles` as a boolean mask must have length 2"):
        dg.rmse(res.means, sim.states, angles=[True])


COMPONENT = ([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], [0.0, 0.5])  # x0 measured without noise
COMBINATION = ([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], [0.0, 0.5, 0.5])  # x0 + x1 without noise


@pytest.mark.parametrize("H, R, form, engine", [
    *((*COMBINATION, form, engine) for form in ("cov", "sqrt") for engine in ("python", "numba")),
    # (the square-root form's round-off for x0 is ε of the prediction's spread, not of the values: not covered)
    *((*COMPONENT, "cov", engine) for engine in ("python", "numba")),
])
def test_nees_of_a_state_known_exactly_counts_its_rank_whatever_the_round_off(H, R, form, engine):
    """The filter leaves round-off (a variance of 1e-40 to 5e-33 for x0, an eigenvalue of 2.25 ε along x0 + x1)
    where the posterior is exactly singular: the NEES averaged 4,515 for 2, or counted 3 degrees of freedom at
    22-50% of the steps, and consistency() called the consistent filter inconsistent."""
    F = np.array([[0.9, 0.1, 0.0], [0.0, 0.95, 0.1], [0.05, 0.0, 0.9]])
    model = gf.LinearModel(F=F, H=H, Q=np.diag([0.1, 0.2, 0.1]), R=np.diag(R))
    prior = gf.Gaussian(np.zeros(3), np.eye(3))
    sim = gf.simulate(model, prior, 30, size=100, rng=2)
    res = gf.filter(model, prior, sim.measurements, check="off", form=form, engine=engine)
    errors = sim.states - res.means
    scale = np.fmax(np.fmax(np.abs(res.means), np.abs(sim.states)), np.abs(res.predicted_means))
    values, dof = dg._nees(errors, res.covs, scale)
    assert (dof == 2).mean() > 0.99  # (a round-off variance beside values near 0 can still count)
    # the oracle: the exact posterior's range is the complement of the direction the noise-free sensor fixes
    fixed = np.array(H[0]) / np.linalg.norm(H[0])
    basis = np.linalg.svd(np.eye(3) - np.outer(fixed, fixed))[0][:, :2]  # an orthonormal basis of its range
    block = basis.T @ res.covs @ basis
    e = errors @ basis
    want = np.einsum("...i,...ij,...j->...", e, np.linalg.inv(block), e)
    np.testing.assert_allclose(values[dof == 2], want[dof == 2], rtol=1e-8)
    np.testing.assert_allclose(dg.nees(errors, res.covs, scale), values, rtol=0)
    report = dg.consistency(res, sim.states)
    assert report.nees == pytest.approx(values.mean(), rel=1e-12) and report.nees_ok
    assert report.nees_interval[0] < 2.0 < report.nees_interval[1]


@pytest.mark.parametrize("case", ["precise sensor", "precise combination", "vague prior"])
def test_nees_counts_what_is_precise_but_not_exact(case):
    """Variances far below the prediction's but computed from a sensor's noise, not round-off, are counted: a
    sensor 1e14 times more precise than the prediction (alone or of x0 - x1), a prior variance of 1e16 against a
    unit sensor. A cut relative to the prediction dropped them, and called a filter whose sensor noise was 100
    times its R consistent (NEES 1.05 for 92)."""
    rng = np.random.default_rng(5)
    H = [[1.0, -1.0], [0.0, 1.0]] if case == "precise combination" else np.eye(2)
    R = np.diag([1e-14, 1.0])
    P0 = 1e16 * np.eye(2) if case == "vague prior" else np.eye(2)
    model = gf.LinearModel(F=np.eye(2), H=H, Q=np.eye(2), R=R)
    sim = gf.simulate(gf.LinearModel(F=np.eye(2), H=H, Q=np.eye(2), R=R * 100.0), gf.Gaussian([0.0, 0.0], np.eye(2)),
                      40 if case == "vague prior" else 400, size=50 if case == "vague prior" else None, rng=rng)
    res = gf.filter(model, gf.Gaussian([0.0, 0.0], P0), sim.measurements, check="off")
    e = sim.states - res.means
    want = np.einsum("...i,...ij,...j->...", e, np.linalg.inv(res.covs), e)  # every covariance here is definite
    report = dg.consistency(res, sim.states)
    assert report.nees == pytest.approx(want.mean(), rel=1e-3)  # (the oracle's inverse loses digits at cond 1e14)
    assert report.nees > 10  # the sensor's true noise is 100 times its R: inconsistent, and seen to be
    assert (dg._nees(e, res.covs)[1] == 2).all()


def test_consistency_with_the_truth_names_a_result_without_covariances():
    """keep='means' keeps the innovations but no covariances: NEES raised "covs must be an array of numbers"."""
    model = gf.constant_velocity(1.0, 0.1, 1.0)
    sim = gf.simulate(model, gf.Gaussian([0.0, 0.0], np.eye(2)), 30, rng=0)
    res = gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), sim.measurements, keep="means")
    assert dg.consistency(res).nees is None  # the NIS alone is fine
    with pytest.raises(ValueError, match=r"^`result` holds no covariances \(keep='means'\), which the NEES needs"):
        dg.consistency(res, sim.states)


@pytest.mark.parametrize("P, message", [
    (np.diag([-1.0, 1.0]), r"a variance of -1 at component 0"),
    (np.array([[1.0, 0.0], [0.0, -1e6]]), r"a variance of -1e\+06 at component 1"),
    (np.array([[1.0, 2.0], [2.0, 1.0]]), r"an eigenvalue of -1 relative to its variances"),
])
def test_nees_refuses_an_indefinite_covariance(P, message):
    """diag(-1, 1) gave 1.0 with rank 1: the negative direction was dropped as if singular (audit Q). A variance of
    round-off below 0 beside a large one is still a zero variance."""
    with pytest.raises(np.linalg.LinAlgError, match=r"^`covs` must be positive semi-definite; .*" + message):
        dg.nees(np.ones((1, 2)), P[None])
    assert dg.nees(np.ones((1, 3)), np.diag([1e12, 1.0, -1e-3])[None])[0] == pytest.approx(1.0 + 1e-12)


@pytest.mark.parametrize("name", ["nis", "nees"])
def test_a_covariance_that_is_not_symmetric_is_refused(name):
    """S = [[2, 1], [0, 2]] gave 1.0 from its lower triangle, silently (audit Q)."""
    with pytest.raises(ValueError, match=r"must be symmetric; it is not at index \(0, 0, 1\)\.$"):
        getattr(dg, name)(np.ones((1, 2)), np.array([[[2.0, 1.0], [0.0, 2.0]]]))


@pytest.mark.parametrize("args, message", [
    (([0, 1], [1, 1], 1.5), r"`probability` must be the gate's, in \(0, 1\); got 1\.5\."),
    (([0, 1], [1, 1], "0.99"), r"`probability` must be the gate's"),
    (([0, 1, 1], [1, 1], 0.99), r"must be counts of one shape"),
    (([0, 2], [1, 1], 0.99), r"with rejected <= offered"),
    (([0, 0.5], [1, 1], 0.99), r"must be counts"),
    (([0, 1, 1], [1.5, 1.5, 1.7], 0.99), r"^`offered` must be counts \(0, 1, 2, \.\.\.\) of shape \(T,\) or \(N, T\); got "
                                          r"\[1\.5, 1\.5, 1\.7\]\.$"),
    (([0, 1], [1, np.inf], 0.99), r"^`offered` must be counts"),
    (([[0, 1], [1]], [[1, 1], [1]], 0.99), r"^`rejected` must be counts"),
])
def test_rejections_checks_its_arguments(args, message):
    """A probability of 1.5 returned [] silently; mismatched lengths raised NumPy's window-shape error (audit Q);
    offered counts of 1.5 were read as 1, of inf cast to a garbage integer, and ragged ones raised NumPy's message
    (audit II3)."""
    with pytest.raises(ValueError, match=message):
        dg.rejections(*args)


def test_diagnostics_name_empty_vectors_and_the_argument_at_fault():
    """nis and nees with m = 0 raised NumPy's reshape error; whiteness blamed `innovations` for a wrong
    `innovation_covs`; lags = 3.0 was a ValueError for a wrong type (audit Q)."""
    with pytest.raises(ValueError, match=r"^`innovations` must have shape \(\.\.\., m\), one vector of m >= 1"):
        dg.nis(np.zeros((3, 0)), np.zeros((3, 0, 0)))
    with pytest.raises(ValueError, match=r"^`errors` must have shape \(\.\.\., m\), one vector of m >= 1"):
        dg.nees(np.zeros((3, 0)), np.zeros((3, 0, 0)))
    v = np.zeros((20, 2))
    with pytest.raises(ValueError, match=r"^`innovation_covs` must have shape \(20, 2, 2\) to match `innovations`"):
        dg.whiteness(v, np.tile(np.eye(3), (20, 1, 1)))
    with pytest.raises(TypeError, match=r"^`lags` must be an integer"):
        dg.whiteness(np.random.default_rng(0).normal(size=(20, 2)), np.tile(np.eye(2), (20, 1, 1)), lags=3.0)


def test_consistency_refuses_a_gated_result():
    """Audit AA3: the NIS a gate keeps are χ² cut off at the gate (their mean for χ²₂ at 0.99 is 1.907), and
    rejections feed back into the predictions, so the plain χ² interval called the true model's gated filter
    "too cautious" (20 runs of 5,000 steps: 1.9234 against [1.9875, 2.0125]). It is refused, naming the gate."""
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=np.eye(2), Q=np.diag([0.05, 0.1]), R=np.diag([1.0, 0.5]))
    prior = gf.Gaussian([0, 1], np.eye(2))
    sim = gf.simulate(model, prior, 200, size=3, rng=2)
    report = dg.consistency(gf.filter(model, prior, sim.measurements, check="off"))
    assert report.nis_ok
    for gate_by in ("measurement", "component"):
        gated = gf.filter(model, prior, sim.measurements, gate=0.99, gate_by=gate_by, check="off")
        with pytest.raises(ValueError, match=r"`result` was filtered with a gate: .* without `gate`"):
            dg.consistency(gated)


def test_the_innovation_covariances_are_checked_alike_by_nis_nees_and_whiteness():
    """Audit AA3: `whiteness` took an asymmetric S and used one triangle (13.08 with S, 11.50 with Sᵀ); `nis` raised
    on a step whose S is NaN, where `nees` gives NaN, and named no step for an indefinite S."""
    v = np.random.default_rng(0).normal(size=(1000, 2))
    S = np.broadcast_to([[2.0, 0.5], [0.5, 1.0]], (1000, 2, 2)).copy()
    skew = S.copy()
    skew[:, 0, 1] = 1.4
    for check in (dg.nis, dg.whiteness):
        with pytest.raises(ValueError, match=re.escape("`innovation_covs` must be symmetric; it is not at index "
                                                       "(0, 0, 1).")):
            check(v, skew)
    missing = S.copy()
    missing[3] = np.nan
    assert np.isnan(dg.nis(v, missing)[3]) and np.isnan(dg.nees(v, missing)[3])
    np.testing.assert_array_equal(np.delete(dg.nis(v, missing), 3), np.delete(dg.nis(v, S), 3))
    indefinite = S.copy()
    indefinite[7] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(np.linalg.LinAlgError, match=r"^at step 7: `innovation_covs` is not positive definite"):
        dg.nis(v, indefinite)


def test_innovation_covariances_that_fail_are_named_at_their_series_and_step():
    """Review R16: `nis` on a batch named a flattened index ("at step 57" in series of 50 steps); `whiteness` named
    no step and printed the whole stack, and refused the NaN innovation covariances of a diffuse start, where
    `nis` gives NaN."""
    v = np.random.default_rng(0).normal(size=(2, 50, 2))
    S = np.tile(np.eye(2), (2, 50, 1, 1))
    S[1, 7] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(np.linalg.LinAlgError, match=r"^in series 1, at step 7: `innovation_covs` is not positive "
                                                    r"definite, so it cannot be factorised: \[\[1\., 2\.\], \[2\., 1\.\]\]$"):
        dg.nis(v, S)
    with pytest.raises(np.linalg.LinAlgError, match=r"^at step 7: `innovation_covs` is not positive definite, so it "
                                                    r"cannot be factorised: \[\[1\., 2\.\], \[2\., 1\.\]\]$"):
        dg.whiteness(v[1], S[1])
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=0.1 * np.eye(2), R=1.0)
    res = gf.filter(model, "diffuse", np.cumsum(np.random.default_rng(1).normal(size=100)))
    assert np.isnan(res.innovation_covs[:2]).all()  # the two steps that identify the diffuse state
    got = dg.whiteness(res.innovations, res.innovation_covs)
    want = dg.whiteness(res.innovations[2:], res.innovation_covs[2:])
    assert got.statistic == want.statistic and got.p_value == want.p_value


def test_an_innovation_covariance_nan_in_part_is_refused_and_none_at_all_is_said_so():
    """Review R17: `whiteness` left out a step whose covariance was NaN in one entry (not a step left uncomputed,
    which is NaN throughout), and with no covariance at all said "`lags` must be an integer in [1, -1]"."""
    v = np.random.default_rng(0).normal(size=(50, 2))
    S = np.tile(np.eye(2), (50, 1, 1))
    S[10, 0, 1] = np.nan
    for check in (dg.whiteness, dg.nis):
        with pytest.raises(ValueError, match=re.escape("`innovation_covs` must be finite where it was computed; it "
                                                       "is NaN or infinite in part at step 10.")):
            check(v, S)
    with pytest.raises(ValueError, match=re.escape("whiteness needs at least 2 steps with a complete innovation and "
                                                   "its covariance; 0 of the 50 have both.")):
        dg.whiteness(v, np.full((50, 2, 2), np.nan))


def test_a_batch_kept_without_covariances_has_its_consistency_report():
    """Audit II1: keep="means" over a batch raised a bare TypeError (its innovation covariances are None), where one
    series gave the report, whose NIS the batch's equals over their runs."""
    model = gf.LinearModel(1.0, 1.0, 0.5, 1.0)
    zs = gf.simulate(model, gf.Gaussian([0.0], [[1.0]]), 60, size=3, rng=1).measurements
    means = dg.consistency(gf.filter(model, gf.Gaussian([0.0], [[1.0]]), zs, keep="means"))
    full = dg.consistency(gf.filter(model, gf.Gaussian([0.0], [[1.0]]), zs))
    assert means.whiteness is None and full.whiteness is not None and means.runs == 3
    assert means.nis == pytest.approx(full.nis, rel=1e-12) and means.nis_ok == full.nis_ok


def test_the_report_says_the_confidence_of_its_intervals():
    """Audit II4: the table said "95% interval" beside a 50% one."""
    model = gf.LinearModel(1.0, 1.0, 0.5, 1.0)
    z = gf.simulate(model, gf.Gaussian([0.0], [[1.0]]), 200, rng=2).measurements
    for confidence, header in ((0.5, "50% interval"), (0.999, "99.9% interval"), (0.95, "95% interval"),
                               (0.9999999, "99.99999% interval")):
        report = dg.consistency(gf.filter(model, gf.Gaussian([0.0], [[1.0]]), z), confidence=confidence)
        assert str(report).splitlines()[0].split()[2:4] == header.split() and report.confidence == confidence
        assert report.nis_interval == pytest.approx(dg.chi2_interval(1, 200, confidence))


def test_a_monitor_fed_many_updates_checks_their_lengths():
    """Audit II2: nis_values of 6 with dofs of 4 dropped two values of 1e6 silently; steps too short raised an
    IndexError."""
    monitor = dg.DivergenceMonitor(window=4, check="off")
    with pytest.raises(ValueError, match=re.escape("`dofs` must have shape (6,), that of `nis_values`; got shape (4,).")):
        monitor.add_many([1, 1, 1, 1, 1e6, 1e6], [1, 1, 1, 1], list(range(6)))
    with pytest.raises(ValueError, match=re.escape("`steps` must hold one label per update, 5; got 1.")):
        monitor.add_many(np.ones(5), np.ones(5), [0])
    with pytest.raises(ValueError, match=re.escape("`dofs` must be counts of observed components (0, 1, 2, ...); "
                                                   "got 0.5.")):
        monitor.add_many(np.ones(2), [1, 0.5], [0, 1])
    assert monitor.add_many([1, 1, 1, 1, 1e6, 1e6], [1] * 6, list(range(6))) == [(2, 5, 500000.5)]
    one, many = dg.DivergenceMonitor(window=4, check="off"), dg.DivergenceMonitor(window=4, check="off")
    values, dofs = [1.0, 1.0, 1.0, np.inf], [True, 1, 1, 1]  # what add takes, add_many takes (review R43)
    assert [one.add(v, d, k) for k, (v, d) in enumerate(zip(values, dofs))][-1] == many.add_many(values, dofs,
                                                                                              range(4))[0]


def test_rmse_names_an_axis_that_is_not_one_of_the_leading_ones():
    """Audit II6: NumPy's AxisError named the array left after the sum over the last axis ("dimension 2")."""
    a = np.ones((3, 4, 2))
    np.testing.assert_array_equal(dg.rmse(a, 0 * a, axis=-1), np.full(3, np.sqrt(2.0)))
    with pytest.raises(ValueError, match=re.escape("`axis` must be one of the estimates' 2 leading axes, from -2 to "
                                                   "1, or a tuple of them, each once (estimates of shape (3, 4, 2)); "
                                                   "got 2.")):
        dg.rmse(a, a, axis=2)
    with pytest.raises(ValueError, match=r"each once .*; got \(0, -2\)\.$"):
        dg.rmse(a, a, axis=(0, -2))
    with pytest.raises(TypeError, match=r"^`axis` must be one of .*; got '0'\.$"):
        dg.rmse(a, a, axis="0")


def test_nees_refuses_a_covariance_nan_in_part_as_nis_does():
    """Audit II7: nees left NaN for a covariance NaN in part, where nis names the step; NaN throughout (a belief
    not computed) is NaN, as before."""
    C = np.array([[[np.nan, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 1.0]], [[np.nan, np.nan], [np.nan, np.nan]]])
    for quadratic in (dg.nis, dg.nees):
        name = "innovation_covs" if quadratic is dg.nis else "covs"
        with pytest.raises(ValueError, match=rf"^`{name}` must be finite where it was computed; it is NaN or "
                                             r"infinite in part at step 0\.$"):
            quadratic(np.ones((3, 2)), C)
    np.testing.assert_array_equal(dg.nees(np.ones((2, 2)), C[1:]), [2.0, np.nan])


def test_divergence_refuses_a_positive_nis_where_nothing_was_observed():
    """Audit OO6: `divergence(np.full(100, 50.0), 0)` returned [] in silence, leaving the inconsistent steps out of
    the test; a NIS of 0 or NaN at such a step is what a filter gives, and is taken."""
    with pytest.raises(ValueError, match=r"^`nis_values` is positive at a step of 0 degrees of freedom \(index \(0,\)\)"):
        dg.divergence(np.full(100, 50.0), 0)
    dof = np.ones((2, 100), dtype=int)
    dof[1, 99] = 0
    with pytest.raises(ValueError, match=r"\(index \(1, 99\)\)"):
        dg.divergence(np.full((2, 100), 50.0), dof)
    for last in (0.0, np.nan):
        assert dg.divergence(np.r_[np.ones(99), last], np.r_[np.ones(99, dtype=int), 0]) == []


def test_the_whiteness_bound_keeps_its_tail_at_high_confidence():
    """Review R45: the bound's normal quantile was ndtri(1 - alpha/2), whose subtraction rounds alpha away: 1.8e-3
    off at a confidence of 1 - 1e-15. Oracle: scipy.stats.norm.isf, which takes the tail itself."""
    innovations = np.random.default_rng(0).standard_normal((200, 2))
    covs = np.broadcast_to(np.eye(2), (200, 2, 2))
    for confidence in (0.95, 1 - 1e-9, 1 - 1e-12, 1 - 1e-15):
        got = dg.whiteness(innovations, covs, confidence=confidence).bound
        assert got == pytest.approx(stats.norm.isf((1 - confidence) / 2) / np.sqrt(2 * 200), rel=1e-14, abs=0.0)


def test_the_divergence_monitor_refuses_a_positive_nis_where_nothing_was_observed():
    """Review R45: `divergence` refuses it since audit OO6; the online monitor still skipped it in silence."""
    monitor = dg.DivergenceMonitor()
    with pytest.raises(ValueError, match=r"^`nis_value` is 50 at an update of 0 degrees of freedom"):
        monitor.add(50.0, 0, 0)
    with pytest.raises(ValueError, match=r"^`nis_values` is positive at an update of 0 degrees of freedom \(index 1\)"):
        monitor.add_many(np.full(3, 50.0), [1, 0, 1], [0, 1, 2])
    assert monitor.add(0.0, 0, 5) is None and monitor.add(np.nan, 0, 6) is None
    assert monitor.add_many([0.0, np.nan], [0, 0], [7, 8]) == []


def test_nees_names_the_step_of_a_covariance_that_is_not_a_covariance():
    """nees said "a covariance has a variance of -1" without saying which, where nis names the step (audit XX2)."""
    errors, covs = np.zeros((5, 2)), np.tile(np.eye(2), (5, 1, 1))
    covs[3, 0, 0] = -1.0
    with pytest.raises(np.linalg.LinAlgError, match=r"the covariance at step 3 has a variance of -1 at component 0"):
        gf.diagnostics.nees(errors, covs)
    indefinite = np.tile(np.eye(2), (2, 5, 1, 1))
    indefinite[1, 2] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(np.linalg.LinAlgError, match=r"the covariance in series 1, at step 2 has an eigenvalue of -1"):
        gf.diagnostics.nees(np.zeros((2, 5, 2)), indefinite)
    partly = errors.copy()
    partly[3, 1] = np.nan  # the observed block of a step with a missing component
    with pytest.raises(np.linalg.LinAlgError, match=r"the covariance at step 3 has a variance of -1"):
        gf.diagnostics.nees(partly, covs)


def test_the_rmse_of_no_estimates_is_nan_without_a_warning():
    """No estimates: NaN, as documented, but through NumPy's "mean of empty slice" and "invalid value" warnings,
    errors under a strict warnings filter (audit XX5)."""
    from gaussfuse.diagnostics import rmse

    assert np.isnan(rmse(np.ones((0, 2)), np.ones((0, 2))))
    assert np.isnan(rmse(np.ones((0, 4, 2)), np.zeros((0, 4, 2)), axis=0)).all()
    assert rmse(np.ones((3, 4, 2)), np.zeros((3, 4, 2))) == pytest.approx(np.sqrt(2.0), rel=1e-15)
