"""gf.simulate and gf.sample_posterior: seeded sample moments against the model's exact moments and the RTS smoother."""

from __future__ import annotations

import numpy as np
import pytest

import gaussfuse as gf
from gaussfuse import kalman


def _within_sampling_error(draws: np.ndarray, mean: np.ndarray, cov: np.ndarray, name: str, z: float = 5.0) -> None:
    """The draws' (N, d) mean and covariance within z standard errors of (mean, cov), entry by entry.

    The standard error of a sample covariance entry of a Gaussian is
    sqrt((σ_ii σ_jj + σ_ij²) / N). The draws are seeded: the test is
    deterministic; z = 5 leaves room for every entry of every step.
    """
    N = draws.shape[0]
    d = np.diag(cov)
    np.testing.assert_array_less(np.abs(draws.mean(axis=0) - mean), z * np.sqrt(d / N) + 1e-12, err_msg=name)
    got = np.cov(draws, rowvar=False).reshape(cov.shape)
    bound = z * np.sqrt((np.outer(d, d) + cov**2) / N) + 1e-12
    np.testing.assert_array_less(np.abs(got - cov), bound, err_msg=name)


def _controlled_model():
    F = np.array([[1.0, 0.5, 0.0], [0.0, 0.9, 0.0], [0.0, 0.0, 1.0]])
    B = np.array([[0.0], [1.0], [0.0]])
    H = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Q = np.diag([0.05, 0.2, 0.0])  # the third state has no noise
    return gf.LinearModel(F, H, Q, np.diag([0.5, 0.1]), B), gf.Gaussian([0.0, 1.0, 2.0], np.diag([1.0, 0.5, 0.0]))


def test_simulated_moments_are_the_models():
    """20,000 seeded series of a controlled model: the states' and measurements' moments at each step are the
    model's (kalman.predict from the prior); a state without noise and a known start is the same in every draw."""
    model, prior = _controlled_model()
    us = np.array([[0.5], [-1.0], [0.0], [2.0]])
    sim = gf.simulate(model, prior, 4, us, size=20_000, rng=7)
    assert sim.states.shape == (20_000, 4, 3) and sim.measurements.shape == (20_000, 4, 2)
    mean, cov = prior.mean, prior.cov
    _within_sampling_error(sim.initial, mean, cov + np.diag([0, 0, 1e-300]), "x0")
    for k in range(4):
        mean, cov = kalman.predict(mean, cov, model.F, model.Q, model.B @ us[k])
        _within_sampling_error(sim.states[:, k], mean, cov + np.diag([0, 0, 1e-300]), f"states {k}")
        zmean, zcov = kalman.predict(mean, cov, model.H, model.R)
        _within_sampling_error(sim.measurements[:, k], zmean, zcov, f"measurements {k}")
    assert np.all(sim.states[:, :, 2] == 2.0)


def test_seeds_reproduce_and_generators_are_used_as_given():
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    a, b = gf.simulate(model, prior, 30, rng=3), gf.simulate(model, prior, 30, rng=3)
    np.testing.assert_array_equal(a.states, b.states)
    rng = np.random.default_rng(3)
    c = gf.simulate(model, prior, 30, rng=rng)
    np.testing.assert_array_equal(c.measurements, a.measurements)
    assert not np.array_equal(gf.simulate(model, prior, 30, rng=rng).states, a.states)  # the generator moved on
    assert a.states.shape == (30, 2) and a.initial.shape == (2,)


def test_a_nonlinear_model_without_noise_follows_f_exactly():
    """Q = 0 and a known start: the states are f iterated (plain and vectorized f agree); h plus R's noise."""
    dt = 0.05

    def f(x):
        return np.array([x[0] + dt * x[1], x[1] - dt * 9.81 * np.sin(x[0])])

    plain = gf.NonlinearModel(f, lambda x: np.sin(x[:1]), np.zeros((2, 2)), np.array([[0.01]]))
    vec = gf.NonlinearModel(lambda X: np.stack([f(x) for x in X]), lambda X: np.sin(X[:, :1]), np.zeros((2, 2)),
                            np.array([[0.01]]), vectorized=True)
    prior = gf.Gaussian([1.0, 0.0], np.zeros((2, 2)))
    x, truth = np.array([1.0, 0.0]), []
    for _ in range(40):
        x = f(x)
        truth.append(x)
    for model in (plain, vec):
        sim = gf.simulate(model, prior, 40, size=3, rng=1)
        np.testing.assert_array_equal(sim.states, np.broadcast_to(truth, (3, 40, 2)))
        noise = sim.measurements[..., 0] - np.sin(sim.states[..., 0])
        assert 0.05 < noise.std() < 0.15


def test_posterior_draws_converge_to_the_rts_smoother():
    """20,000 seeded trajectories (controls, a missing value, a state known exactly): at each step, mean and
    covariance within sampling error of the RTS smoother's; the known state is drawn exactly."""
    model, prior = _controlled_model()
    rng = np.random.default_rng(2)
    us = rng.normal(size=(12, 1))
    zs = gf.simulate(model, prior, 12, us, rng=rng).measurements.copy()
    zs[4, 0] = np.nan
    draws = gf.sample_posterior(model, prior, zs, 20_000, us, rng=5)
    sm = gf.smooth(model, prior, zs, us)
    assert draws.shape == (20_000, 12, 3)
    for k in range(12):
        _within_sampling_error(draws[:, k, :2], sm.means[k, :2], sm.covs[k, :2, :2], f"step {k}")
    np.testing.assert_array_equal(draws[:, :, 2], 2.0)


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_a_state_measured_exactly_is_a_valid_belief_to_go_on_from(engine):
    """One state measured twice with one shared noise (a singular R = r rᵀ) is known exactly: the covariance
    form's filtered and smoothed variances were -1.97e-17, so forecast from the result, the result's last
    belief as a Gaussian and sample_posterior refused them as not positive semi-definite (audit V). Now 0, and
    the draws are the state."""
    model = gf.LinearModel(F=0.7, H=[[1.0], [2.0]], Q=1.0, R=np.outer([1.0, 0.7], [1.0, 0.7]))
    prior = gf.Gaussian([0.0], [[1.0]])
    zs = np.array([[0.5 + 0.1, 2 * 0.5 + 0.07]])
    filt, sm = gf.filter(model, prior, zs, engine=engine), gf.smooth(model, prior, zs, engine=engine)
    for res in (filt, sm):
        assert res.covs[0, 0, 0] >= 0.0 and res.covs[0, 0, 0] <= 1e-16
        np.testing.assert_allclose(gf.forecast(model, res, steps=2).covs[:, 0, 0], [1.0, 1.49], rtol=1e-15)
    assert gf.Gaussian(filt.last_mean, filt.last_cov).cov[0, 0] == filt.last_cov[0, 0]
    for form in ("cov", "sqrt"):
        np.testing.assert_allclose(gf.sample_posterior(model, prior, zs, 3, rng=0, form=form), 0.5, rtol=1e-15)


def test_posterior_draws_with_a_noise_free_sensor_and_a_rank_two_q():
    """R = 0, Q of rank 2 and a known start (audit V's case): the covariance form's filtered covariances have
    eigenvalues of -4e-17 and a variance of 2.5e-5 made by cancelling ones of 0.65, which its factorisation
    refused ("not symmetric positive semi-definite on the scale of its components"; 34 random such models in
    400). Its draws now match the RTS smoother's moments within sampling error."""
    F = np.array([[0.2, -0.8, -0.3], [-0.9, 0.7, 0.3], [-0.6, -1.1, 0.3]])
    G = np.array([[-0.4, 0.1], [-0.3, 0.3], [-1.5, 0.6]])
    model = gf.LinearModel(F=F, H=[1.0, -0.1, 0.4], Q=G @ G.T, R=0.0)
    prior = gf.Gaussian(np.zeros(3), np.zeros((3, 3)))
    zs = np.array([-0.2, 0.4, -0.3])
    draws = gf.sample_posterior(model, prior, zs, 20_000, rng=1, check="off")
    sm = gf.smooth(model, prior, zs, check="off")
    for k in range(3):
        _within_sampling_error(draws[:, k], sm.means[k], sm.covs[k], f"step {k}")


def test_posterior_draws_of_a_huge_prior_stay_finite_and_consistent():
    """P0 = 1e12 I, R = 1e-6, Q = 0 (the robustness suite's first problem), with the square-root filter: the
    conditional covariance comes from the joint factor, never as a difference, so every draw is finite and the
    draws' moments match the square-root smoother's."""
    F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    model = gf.LinearModel(F, H, np.zeros((2, 2)), 1e-6)
    prior = gf.Gaussian([0.0, 0.0], 1e12 * np.eye(2))
    zs = 3.0 + 2.0 * np.arange(1, 11) + 1e-3 * np.random.default_rng(0).normal(size=10)
    draws = gf.sample_posterior(model, prior, zs, 5000, rng=0, form="sqrt")
    sm = gf.smooth(model, prior, zs, form="sqrt")
    assert np.all(np.isfinite(draws))
    for k in range(10):
        _within_sampling_error(draws[:, k], sm.means[k], sm.covs[k], f"step {k}", z=6.0)


@pytest.mark.parametrize("call, error, message", [
    (lambda m, p: gf.simulate(m, p, 0), ValueError, "`T` must be a positive integer"),
    (lambda m, p: gf.simulate(m, p, 5, size=0), ValueError, "`size` must be a positive integer"),
    (lambda m, p: gf.simulate(m, p, 5, rng="seed"), TypeError, "`rng` must be None, a non-negative integer seed"),
    (lambda m, p: gf.simulate(m, p, 5, rng=True), TypeError, "`rng` must be None, a non-negative integer seed"),
    (lambda m, p: gf.forecast(m, p, times="abc"), TypeError, r"`times` must be numbers \(seconds\), times "
                                                              r"\(datetime64, .*\) or durations \(timedelta64, .*\), "
                                                              r"one per step; got str 'abc'\.$"),
    (lambda m, p: gf.simulate("model", p, 5), TypeError, "`model` must be a gaussfuse.LinearModel"),
    (lambda m, p: gf.simulate(m, gf.Gaussian([0.0], [[1.0]]), 5), ValueError, "dimension 2"),
    (lambda m, p: gf.sample_posterior(m, p, np.zeros((2, 5, 1)), 10), ValueError, "one series"),
    (lambda m, p: gf.sample_posterior(m, p, np.zeros(5), 0), ValueError, "`n` must be a positive integer"),
    (lambda m, p: gf.sample_posterior(gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.eye(2), 1.0), p,
                                      np.zeros(5), 10), TypeError, "LinearModel"),
])
def test_bad_arguments_are_named(call, error, message):
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0)
    with pytest.raises(error, match=message):
        call(model, gf.Gaussian([0.0, 1.0], np.eye(2)))


def test_a_model_function_error_names_the_step():
    """As a filter names it; simulate named only the function."""
    def f(x):  # a counter of steps, without noise: fails on its fourth call, the transition into step 3
        if x[0] >= 3.0:
            raise RuntimeError("out of range")
        return x + 1.0

    model = gf.NonlinearModel(f, lambda x: x, np.zeros((1, 1)), np.eye(1))
    with pytest.raises(gf.ModelFunctionError, match=r"^at step 3: `f` raised RuntimeError .*out of range"):
        gf.simulate(model, gf.Gaussian([0.0], [[0.0]]), 6, rng=0)
    bad_h = gf.NonlinearModel(lambda x: x + 1.0, lambda x: np.log(2.5 - x), np.zeros((1, 1)), np.eye(1))
    with pytest.raises(gf.ModelFunctionError, match=r"^at step 2: `h` returned a non-finite value"):
        gf.simulate(bad_h, gf.Gaussian([0.0], [[0.0]]), 6, rng=0)


def test_posterior_draws_take_the_filters_divergence_check():
    """A model whose R is far too small for its data: the filter's DivergenceWarning, raised, or nothing."""
    import warnings

    model = gf.LinearModel(F=1.0, H=1.0, Q=1e-4, R=1e-4)
    zs = np.random.default_rng(0).normal(size=60) * 3.0
    prior = gf.Gaussian([0.0], [[1.0]])
    with pytest.warns(gf.DivergenceWarning):
        gf.sample_posterior(model, prior, zs, 5, rng=0)
    with pytest.raises(gf.DivergenceWarning):
        gf.sample_posterior(model, prior, zs, 5, rng=0, check="raise")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        quiet = gf.sample_posterior(model, prior, zs, 5, rng=0, check="off")
    np.testing.assert_array_equal(quiet, gf.sample_posterior(model, prior, zs, 5, rng=0, check="warn"))
    with pytest.raises(ValueError, match="`check`"):
        gf.sample_posterior(model, prior, zs, 5, check="loud")



def test_simulate_names_its_own_arguments():
    """It said "`zs` has 3 steps" and "matching `zs`": simulate has no `zs`."""
    model = gf.LinearModel(F=np.stack([np.eye(2)] * 4), H=np.eye(2), Q=np.eye(2), R=np.eye(2))
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    with pytest.raises(ValueError, match=r"time-varying over 4 steps but `T` asks for 3 steps"):
        gf.simulate(model, prior, 3)
    controlled = gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.eye(2), R=np.eye(2), B=np.ones((2, 1)))
    with pytest.raises(ValueError, match=r"matching `T`; got shape \(2, 3, 1\)"):
        gf.simulate(controlled, prior, 3, us=np.zeros((2, 3, 1)), size=2)


def _heading(state_angles=(0,), measurement_angles=()):
    """A heading turning at a nearly constant rate, read as its (cos, sin) or as itself."""
    def f(x):
        return np.stack([x[..., 0] + x[..., 1], x[..., 1]], axis=-1)

    def h(x):
        return np.stack([np.cos(x[..., 0]), np.sin(x[..., 0]), x[..., 0]], axis=-1)

    return gf.NonlinearModel(f, h, Q=np.diag([1e-4, 1e-6]), R=np.diag([0.01, 0.01, 0.04]), vectorized=True,
                             state_angles=state_angles, measurement_angles=measurement_angles)


def test_simulated_angles_are_wrapped_as_the_filter_wraps_its_means():
    """A heading turning at 0.1 rad a step reached 7.3 rad, and 49% of bearings near π lay outside [-π, π):
    the filter's means and a sensor's readings are wrapped, so NEES and plots saw jumps of 2π."""
    prior = gf.Gaussian([3.0, 0.1], np.diag([1e-4, 1e-6]))
    plain = gf.simulate(_heading((), ()), prior, 60, size=5, rng=4)
    wrapped = gf.simulate(_heading((0,), (2,)), prior, 60, size=5, rng=4)
    assert plain.states[..., 0].max() > 7.0  # the draws cross π many times
    start = gf.simulate(_heading(), gf.Gaussian([3.1, 0.0], np.diag([0.01, 1e-6])), 1, size=200, rng=1).initial
    assert (np.abs(start[:, 0]) <= np.pi).all() and (np.abs(start[:, 0]) > 2.5).all()  # x_0 too (it was not)
    assert (start[:, 0] < 0).sum() > 50  # (past π: wrapped)
    for got, want in ((wrapped.states, plain.states), (wrapped.measurements, plain.measurements)):
        angle = got.shape[-1] - 1 if got.shape[-1] == 3 else 0
        assert (-np.pi <= got[..., angle]).all() and (got[..., angle] < np.pi).all()
        np.testing.assert_allclose(np.delete(got, angle, -1), np.delete(want, angle, -1), atol=1e-12)
        np.testing.assert_allclose(got[..., angle], gf.wrap_angle(want[..., angle]), atol=1e-12)


def test_sample_posterior_steps_a_timed_model_by_its_times():
    """Audit AA3: a TimedModel (and the README's workaround, TimedModel.at(dts), a tuple) was refused as "exact
    for linear-Gaussian models only". With `times` it draws from the model of its steps: the same draws as from
    that model, and their moments those of the smoother at those times."""
    track = gf.model(gf.ConstantVelocity(dim=1, q=0.1), gf.Position(dim=1, r=1.0))
    prior, zs, times = gf.Gaussian([0.0, 1.0], np.eye(2)), [1.0, 1.4, np.nan, 3.0], [0.0, 1.0, 1.5, 3.5, 4.0]
    draws = gf.sample_posterior(track, prior, zs, 20_000, times=times, rng=4)
    stepped, _ = track.at(np.diff(times))
    np.testing.assert_array_equal(draws, gf.sample_posterior(stepped, prior, zs, 20_000, rng=4))
    sm = gf.smooth(track, prior, zs, times=times)
    sd = np.sqrt(np.diagonal(sm.covs, axis1=1, axis2=2))
    assert np.all(np.abs(draws.mean(axis=0) - sm.means) < 5 * sd / np.sqrt(20_000))
    with pytest.raises(ValueError, match="`times` is required"):
        gf.sample_posterior(track, prior, zs, 5)
    pd = pytest.importorskip("pandas")  # a Series' DatetimeIndex supplies the times, as in filter (review R16)
    dated = pd.Series(zs, index=pd.Timestamp("2026-01-01") + pd.to_timedelta(times[1:], unit="s"))
    np.testing.assert_array_equal(gf.sample_posterior(track, prior, dated, 50, rng=4),
                                  gf.sample_posterior(track, prior, zs, 50, times=times[1:], rng=4))
    plain = gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.eye(2), 1.0)  # not "irregular times"
    with pytest.raises(TypeError, match=r"linear-Gaussian models only; got NonlinearModel\.$"):
        gf.sample_posterior(plain, prior, zs, 5, times=times)
    turning = gf.model(gf.CoordinatedTurn(), gf.Position(dim=2, r=1.0))
    with pytest.raises(TypeError, match=r"got TimedModel \(a TimedModel of a nonlinear motion or sensor\)"):
        gf.sample_posterior(turning, gf.Gaussian(np.zeros(5), np.eye(5)), np.zeros((2, 2)), 5, times=[0.0, 1.0, 2.0])


def test_sample_posteriors_divergence_warning_points_at_the_callers_line():
    """Audit AA3: it pointed at gaussfuse/simulation.py, where filter's points at the caller's line."""
    model = gf.LinearModel(F=1.0, H=1.0, Q=1e-6, R=1e-6)
    zs = np.random.default_rng(0).normal(size=200)  # far too noisy for the model: the check fires
    with pytest.warns(gf.DivergenceWarning) as caught:
        gf.sample_posterior(model, gf.Gaussian([0.0], [[1.0]]), zs, 3, rng=0)
    assert [w.filename for w in caught] == [__file__]
    with pytest.raises(gf.DivergenceWarning):
        gf.sample_posterior(model, gf.Gaussian([0.0], [[1.0]]), zs, 3, rng=0, check="raise")
    with pytest.raises(ValueError, match="`check`"):
        gf.sample_posterior(model, gf.Gaussian([0.0], [[1.0]]), zs, 3, rng=0, check="loud")
