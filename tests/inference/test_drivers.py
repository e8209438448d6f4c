"""gf.filter and gf.smooth against the dense joint-Gaussian oracle and a published reference."""

from __future__ import annotations

import re
import subprocess
import sys
import tracemalloc
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import _oracle
import gaussfuse as gf
from gaussfuse import diagnostics

RTOL = 1e-8

# ---------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------


def assert_close(actual, desired, what: str, rtol: float = RTOL) -> None:
    """allclose with an absolute floor scaled to the size of the reference values."""
    actual, desired = np.asarray(actual), np.asarray(desired)
    assert actual.shape == desired.shape, f"{what}: shape {actual.shape} != {desired.shape}"
    finite = desired[np.isfinite(desired)]
    scale = max(1.0, float(np.max(np.abs(finite)))) if finite.size else 1.0
    np.testing.assert_allclose(actual, desired, rtol=rtol, atol=rtol * scale, equal_nan=True, err_msg=what)


def build(problem: dict) -> tuple[gf.LinearModel, gf.Gaussian]:
    model = gf.LinearModel(
        F=problem["F"], H=problem["H"], Q=problem["Q"], R=problem["R"], B=problem["B"]
    )
    return model, gf.Gaussian(problem["m0"], problem["P0"])


def oracle(problem: dict, zs=None) -> dict:
    return _oracle.reference(
        problem["F"], problem["H"], problem["Q"], problem["R"], problem["m0"], problem["P0"],
        problem["zs"] if zs is None else zs, B=problem["B"], us=problem["us"],
    )


def assert_filter_matches(res: gf.FilterResult, ref: dict, zs: np.ndarray) -> None:
    for name in ("predicted_means", "predicted_covs", "means", "covs",
                 "innovations", "innovation_covs"):
        assert_close(getattr(res, name), ref[name], name)
    # Innovations are NaN exactly where a component is missing.
    np.testing.assert_array_equal(np.isnan(res.innovations), np.isnan(zs))
    assert np.ndim(res.loglik) == 0
    assert res.loglik == pytest.approx(ref["loglik"], rel=RTOL, abs=RTOL)
    np.testing.assert_array_equal(res.covs, np.swapaxes(res.covs, -1, -2))


MATRICES = ("F", "H", "Q", "R", "B")


@st.composite
def problems(draw):
    """Dimensions, which matrices vary in time, control input, missing-data mask, seed."""
    n = draw(st.integers(1, 4), label="n")
    m = draw(st.integers(1, 3), label="m")
    T = draw(st.integers(1, 8), label="T")
    p = draw(st.sampled_from([0, 1, 2]), label="p")
    varying = frozenset(
        name for name in MATRICES if (name != "B" or p) and draw(st.booleans(), label=f"{name} varies")
    )
    kind = draw(st.sampled_from(["complete", "partial", "all missing"]), label="missing")
    mask = np.zeros((T, m), dtype=bool)
    if kind == "partial":
        flat = draw(st.lists(st.booleans(), min_size=T * m, max_size=T * m), label="mask")
        mask = np.array(flat, dtype=bool).reshape(T, m)
        rows = draw(st.sets(st.integers(0, T - 1), max_size=T), label="missing rows")
        mask[sorted(rows)] = True
    elif kind == "all missing":
        mask[:] = True
    seed = draw(st.integers(0, 2**32 - 1), label="seed")
    return _oracle.random_problem(np.random.default_rng(seed), n, m, T, p, varying, mask)


HYPOTHESIS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ---------------------------------------------------------------------------
# The oracle itself, on a case computed by hand
# ---------------------------------------------------------------------------


def test_oracle_reproduces_hand_computed_scalar_case():
    f, h, q, r, m0, p0, b, u, z = 0.9, 2.0, 0.5, 0.3, 1.0, 2.0, 0.7, 1.5, 3.0
    ref = _oracle.reference([[f]], [[h]], [[q]], [[r]], [m0], [[p0]], [[z]], B=[[b]], us=[[u]])
    m_pred = f * m0 + b * u
    p_pred = f * f * p0 + q
    s = h * h * p_pred + r
    k = p_pred * h / s
    assert ref["predicted_means"][0, 0] == pytest.approx(m_pred, rel=1e-13)
    assert ref["predicted_covs"][0, 0, 0] == pytest.approx(p_pred, rel=1e-13)
    assert ref["innovations"][0, 0] == pytest.approx(z - h * m_pred, rel=1e-13)
    assert ref["innovation_covs"][0, 0, 0] == pytest.approx(s, rel=1e-13)
    assert ref["means"][0, 0] == pytest.approx(m_pred + k * (z - h * m_pred), rel=1e-13)
    assert ref["covs"][0, 0, 0] == pytest.approx(p_pred - k * h * p_pred, rel=1e-13)
    v = z - h * m_pred
    ll = -0.5 * (v * v / s + np.log(s) + np.log(2 * np.pi))
    assert ref["loglik"] == pytest.approx(ll, rel=1e-13)


def test_oracle_two_step_smoother_by_hand():
    # Random walk, two steps, only z_2 observed: x_1 is smoothed through x_2.
    q, r, p0 = 1.0, 0.5, 2.0
    ref = _oracle.reference([[1.0]], [[1.0]], [[q]], [[r]], [0.0], [[p0]], [[np.nan], [4.0]])
    p1, p2 = p0 + q, p0 + 2 * q
    assert ref["loglik"] == pytest.approx(-0.5 * (16 / (p2 + r) + np.log(2 * np.pi * (p2 + r))))
    assert ref["smoothed_means"][1, 0] == pytest.approx(p2 / (p2 + r) * 4.0)
    # Cov(x_1, z_2) = p1, so E[x_1 | z_2] = p1 / (p2 + r) * z_2.
    assert ref["smoothed_means"][0, 0] == pytest.approx(p1 / (p2 + r) * 4.0)
    assert ref["smoothed_covs"][0, 0, 0] == pytest.approx(p1 - p1 * p1 / (p2 + r))


# ---------------------------------------------------------------------------
# filter / smooth against the dense oracle
# ---------------------------------------------------------------------------


@HYPOTHESIS
@given(problems())
def test_filter_matches_dense_oracle(problem):
    model, prior = build(problem)
    res = gf.filter(model, prior, problem["zs"], problem["us"])
    assert_filter_matches(res, oracle(problem), problem["zs"])


@HYPOTHESIS
@given(problems())
def test_smooth_matches_dense_oracle(problem):
    model, prior = build(problem)
    sm = gf.smooth(model, prior, problem["zs"], problem["us"])
    ref = oracle(problem)
    assert_close(sm.means, ref["smoothed_means"], "smoothed means")
    assert_close(sm.covs, ref["smoothed_covs"], "smoothed covs")
    assert_close(sm.gains, ref["gains"], "smoother gains")
    assert_filter_matches(sm.filtered, ref, problem["zs"])
    assert sm.loglik == sm.filtered.loglik
    # The last smoothed belief is the last filtered one.
    np.testing.assert_array_equal(sm.means[-1], sm.filtered.means[-1])


@pytest.mark.parametrize("T", [1, 5])
def test_all_missing_series_is_the_prior_propagated(T):
    rng = np.random.default_rng(7)
    problem = _oracle.random_problem(rng, 3, 2, T, 1, {"F", "B"}, np.ones((T, 2), bool))
    model, prior = build(problem)
    sm = gf.smooth(model, prior, problem["zs"], problem["us"])
    res = sm.filtered
    assert res.loglik == 0.0
    np.testing.assert_array_equal(res.means, res.predicted_means)
    np.testing.assert_array_equal(res.covs, res.predicted_covs)
    np.testing.assert_array_equal(sm.means, res.means)
    assert np.isnan(res.innovations).all()
    # Without measurements the beliefs are the prior pushed through the dynamics.
    mean, cov = problem["m0"], problem["P0"]
    for k in range(T):
        F = problem["F"][k]
        mean = F @ mean + problem["B"][k] @ problem["us"][k]
        cov = F @ cov @ F.T + problem["Q"]
        assert_close(res.means[k], mean, "propagated mean")
        assert_close(res.covs[k], cov, "propagated cov")
    assert_filter_matches(res, oracle(problem), problem["zs"])


def test_singular_prediction_uses_least_squares_gain_and_matches_oracle():
    # No process noise and a prior certain along one direction: every predicted
    # covariance is singular, so the RTS gain takes its least-squares branch.
    F = np.array([[1.0, 0.1], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    Q = np.zeros((2, 2))
    R = np.array([[0.25]])
    m0, P0 = np.array([0.0, 1.0]), np.array([[0.0, 0.0], [0.0, 1.0]])
    zs = np.array([[0.2], [0.1], [np.nan], [0.5], [0.4]])
    sm = gf.smooth(gf.LinearModel(F, H, Q, R), gf.Gaussian(m0, P0), zs)
    assert np.linalg.matrix_rank(sm.filtered.predicted_covs[1]) == 1
    # The oracle's gains need a definite prediction, so condition the joint directly.
    J = _oracle.JointGaussian(F, H, Q, R, m0, P0, len(zs))
    mean_s, cov_s = J.condition(zs, len(zs))
    for k in range(len(zs)):
        xi = J.x_index(k)
        assert_close(sm.means[k], mean_s[xi], f"smoothed mean {k}")
        assert_close(sm.covs[k], cov_s[np.ix_(xi, xi)], f"smoothed cov {k}")


# ---------------------------------------------------------------------------
# Batches of series
# ---------------------------------------------------------------------------


@settings(max_examples=15, deadline=None)
@given(
    st.integers(1, 3), st.integers(1, 2), st.integers(1, 6), st.sampled_from([0, 1, 2]),
    st.integers(1, 4), st.booleans(), st.integers(0, 2**32 - 1),
)
def test_batch_equals_per_series(n, m, T, p, N, shared_controls, seed):
    rng = np.random.default_rng(seed)
    problem = _oracle.random_problem(rng, n, m, T, p, {"F", "R"})
    model, prior = build(problem)
    zs = rng.normal(size=(N, T, m))
    zs[rng.random(size=zs.shape) < 0.2] = np.nan
    if p == 0:
        us = None
    elif shared_controls:
        us = rng.normal(size=(T, p))  # one control sequence for every series
    else:
        us = rng.normal(size=(N, T, p))

    res = gf.filter(model, prior, zs, us)
    sm = gf.smooth(model, prior, zs, us)
    assert np.shape(res.loglik) == (N,)
    assert np.shape(sm.loglik) == (N,)
    assert res.means.shape == (N, T, n)
    assert res.innovation_covs.shape == (N, T, m, m)
    assert sm.gains.shape == (N, max(T - 1, 0), n, n)
    for i in range(N):
        u_i = None if us is None else (us if shared_controls else us[i])
        one = gf.filter(model, prior, zs[i], u_i)
        one_sm = gf.smooth(model, prior, zs[i], u_i)
        for name in ("means", "covs", "predicted_means", "predicted_covs",
                     "innovations", "innovation_covs"):
            np.testing.assert_array_equal(getattr(res, name)[i], getattr(one, name), err_msg=name)
            np.testing.assert_array_equal(getattr(sm.filtered, name)[i], getattr(one, name))
        assert res.loglik[i] == one.loglik
        np.testing.assert_array_equal(sm.means[i], one_sm.means)
        np.testing.assert_array_equal(sm.covs[i], one_sm.covs)
        # And each series against the oracle.
        ref = oracle(problem | {"us": u_i}, zs[i])
        assert_close(sm.means[i], ref["smoothed_means"], "batch smoothed means")
        assert res.loglik[i] == pytest.approx(ref["loglik"], rel=RTOL, abs=RTOL)


def test_batch_of_one_keeps_the_series_axis():
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = np.arange(4.0).reshape(1, 4, 1)
    res = gf.filter(model, prior, zs)
    assert res.means.shape == (1, 4, 2)
    assert np.shape(res.loglik) == (1,)
    assert res.loglik[0] == gf.filter(model, prior, zs[0]).loglik


# ---------------------------------------------------------------------------
# Input forms
# ---------------------------------------------------------------------------


def test_scalar_measurements_and_controls_accept_1d_arrays():
    rng = np.random.default_rng(3)
    problem = _oracle.random_problem(rng, 2, 1, 6, 1)
    model, prior = build(problem)
    a = gf.filter(model, prior, problem["zs"][:, 0], problem["us"][:, 0])
    b = gf.filter(model, prior, problem["zs"], problem["us"])
    np.testing.assert_array_equal(a.means, b.means)
    assert a.loglik == b.loglik
    assert a.innovations.shape == (6, 1)


def test_explicit_kf_method_equals_default():
    rng = np.random.default_rng(4)
    problem = _oracle.random_problem(rng, 2, 2, 5)
    model, prior = build(problem)
    a = gf.smooth(model, prior, problem["zs"])
    b = gf.smooth(model, prior, problem["zs"], method="kf")
    np.testing.assert_array_equal(a.means, b.means)
    assert a.loglik == b.loglik
    assert "kf" in gf.METHODS


def test_single_step_smoother_is_the_filter():
    rng = np.random.default_rng(5)
    problem = _oracle.random_problem(rng, 3, 2, 1)
    model, prior = build(problem)
    sm = gf.smooth(model, prior, problem["zs"])
    np.testing.assert_array_equal(sm.means, sm.filtered.means)
    np.testing.assert_array_equal(sm.covs, sm.filtered.covs)
    assert sm.gains.shape == (0, 3, 3)


def test_results_are_frozen():
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0)
    res = gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0])
    with pytest.raises(AttributeError):
        res.loglik = 0.0


# ---------------------------------------------------------------------------
# Published reference: Särkkä & Svensson's car-tracking example
# ---------------------------------------------------------------------------

CAR_DT, CAR_Q, CAR_S = 0.1, 1.0, 0.5
RMSE_MEASUREMENTS = 0.7679855237247215
RMSE_KF = 0.4253824660526518
RMSE_RTS = 0.26497104638205465


def car_model_explicit() -> gf.LinearModel:
    dt, q, s = CAR_DT, CAR_Q, CAR_S
    A = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    Q = q * np.array([
        [dt**3 / 3, 0, dt**2 / 2, 0],
        [0, dt**3 / 3, 0, dt**2 / 2],
        [dt**2 / 2, 0, dt, 0],
        [0, dt**2 / 2, 0, dt],
    ])
    H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], dtype=float)
    R = s**2 * np.eye(2)
    return gf.LinearModel(F=A, H=H, Q=Q, R=R)


def car_model_library() -> gf.LinearModel:
    return gf.constant_velocity(dt=CAR_DT, q=CAR_Q, r=CAR_S**2, dim=2)


CAR_PRIOR = ([0.0, 0.0, 1.0, -1.0], np.eye(4))


def position_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((estimate[:, :2] - truth[:, :2]) ** 2, axis=-1))))


def test_car_track_models_agree():
    a, b = car_model_explicit(), car_model_library()
    for name in ("F", "H", "Q", "R"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-15, atol=1e-17, err_msg=name)
    assert b.B is None and b.steps is None


def test_car_track_measurement_rmse(car_track):
    X, Y = car_track["X"], car_track["Y"]
    assert X.shape == (4, 100) and Y.shape == (2, 100)
    assert position_rmse(Y.T, X.T) == pytest.approx(RMSE_MEASUREMENTS, abs=1e-8)


@pytest.mark.parametrize("make_model", [car_model_explicit, car_model_library], ids=["explicit", "library"])
def test_car_track_kalman_filter_and_rts_smoother_rmse(car_track, make_model):
    X, Y = car_track["X"], car_track["Y"]
    prior = gf.Gaussian(*CAR_PRIOR)
    sm = gf.smooth(make_model(), prior, Y.T)
    assert position_rmse(sm.filtered.means, X.T) == pytest.approx(RMSE_KF, abs=1e-8)
    assert position_rmse(sm.means, X.T) == pytest.approx(RMSE_RTS, abs=1e-8)
    # gf.filter is the same forward pass.
    res = gf.filter(make_model(), prior, Y.T)
    np.testing.assert_array_equal(res.means, sm.filtered.means)


def test_car_track_against_dense_oracle(car_track):
    # The full 100-step joint Gaussian is 600-dimensional: still cheap, and it
    # pins the filter's numbers on real data, not just the RMSE summary.
    Y = car_track["Y"].T[:40]
    model = car_model_explicit()
    ref = _oracle.reference(model.F, model.H, model.Q, model.R, CAR_PRIOR[0], CAR_PRIOR[1], Y)
    sm = gf.smooth(model, gf.Gaussian(*CAR_PRIOR), Y)
    assert_close(sm.means, ref["smoothed_means"], "smoothed means")
    assert_close(sm.covs, ref["smoothed_covs"], "smoothed covs")
    assert_filter_matches(sm.filtered, ref, Y)


def robot_model(robot: dict, Q=None, R=None) -> gf.LinearModel:
    """The robot data's model: the offsets b_k enter as controls u_k through B = I; d is taken off the data."""
    return gf.LinearModel(F=robot["A"], H=robot["C"], Q=robot["Q"] if Q is None else Q,
                          R=robot["R"] if R is None else R, B=np.eye(5))


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_robot_filter_and_smoother_equal_the_published_matlab_results(robot, engine):
    """pykalman's robot data (Abbeel, 2011): 500 steps of a 5-state model, filtered and smoothed in MATLAB."""
    zs = robot["y"] - robot["d"]
    sm = gf.smooth(robot_model(robot), gf.Gaussian(robot["x0"], robot["P_0"]), zs, us=robot["b"], engine=engine)
    scale = np.abs(robot["xfilt"]).max()  # about 60; the covariances are of order 1
    np.testing.assert_allclose(sm.filtered.means, robot["xfilt"][1:], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(sm.filtered.covs, robot["Vfilt"][1:], rtol=0, atol=1e-11)
    np.testing.assert_allclose(sm.means, robot["xsmooth"][1:], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(sm.covs, robot["Vsmooth"][1:], rtol=0, atol=1e-11)


def _cv_model(method: str):
    """A 2-D constant-velocity model, as a LinearModel for "kf" or the same functions for "ukf"."""
    linear = gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)
    if method == "kf":
        return linear
    return gf.NonlinearModel(lambda x: linear.F @ x, lambda x: linear.H @ x, linear.Q, linear.R)


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("writeable", [True, False])
def test_measurements_are_read_not_changed(engine, writeable):
    prior = gf.Gaussian(np.zeros(4), np.eye(4))
    zs = np.random.default_rng(2).normal(size=(50, 2))
    zs[3, 1] = zs[7] = np.nan
    given = zs.copy()
    zs.setflags(write=writeable)
    for method in ("kf", "ukf"):
        gf.smooth(_cv_model(method), prior, zs, method=method, engine=engine)
        np.testing.assert_array_equal(zs, given)


@pytest.mark.parametrize("method", ["kf", "ukf"])
def test_keep_last_reads_a_read_only_series_in_place(method):
    """A read-only float64 series (say np.load(..., mmap_mode="r")) is not copied."""
    model = _cv_model(method)
    prior = gf.Gaussian(np.zeros(4), np.eye(4))
    zs = np.random.default_rng(3).normal(size=(20_000, 2)).cumsum(axis=0)
    zs.setflags(write=False)
    gf.filter(model, prior, zs[:5], method=method, engine="numba", keep="last")  # compile first
    tracemalloc.start()
    try:
        gf.filter(model, prior, zs, method=method, engine="numba", keep="last")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < zs.nbytes / 4


# ---------------------------------------------------------------------------
# Overflow: a non-finite belief is an error naming the step, in both engines
# ---------------------------------------------------------------------------


def _overflow(run, *args, match, **kwargs):
    """Both engines raise the same FloatingPointError, matching `match`; numpy's own warnings stay quiet."""
    messages = []
    for engine in ("python", "numba"):
        with pytest.raises(FloatingPointError, match=match) as err:  # -W error: a RuntimeWarning would fail
            run(*args, engine=engine, **kwargs)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


@pytest.mark.parametrize("run", [gf.filter, gf.smooth], ids=["filter", "smooth"])
def test_overflow_in_the_prediction_names_the_step(run):
    model = gf.LinearModel(F=[[1e120, 0.0], [0.0, 1.0]], H=[0.0, 1.0], Q=np.eye(2), R=1.0)
    prior = gf.Gaussian([1.0, 0.0], np.eye(2))  # x0 is not measured: variance 1e240 at step 0, inf at step 1
    _overflow(run, model, prior, [1.0, 2.0, 3.0],
              match=r"^at step 1: the predicted mean or covariance is not finite \(inf or NaN\): the computation "
                    r"overflowed; check the scale of the model, the prior and the measurements\.$")


def test_overflow_of_the_log_likelihood_names_the_step():
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    zs = [0.0, 1.0, 1e300, 1.0]  # finite, but its squared innovation is not
    _overflow(gf.filter, model, gf.Gaussian(0.0, 1.0), zs,
              match=r"^at step 2: the filtered mean, covariance or log-likelihood is not finite")


def test_overflow_names_the_series_of_a_batch_in_the_compiled_engine():
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    zs = np.zeros((3, 4, 1))
    zs[2, 1] = zs[1, 3] = 1e300  # series 1 overflows at step 3, series 2 at step 1: series 1 is named
    for run in (gf.filter, gf.smooth):
        with pytest.raises(FloatingPointError, match=r"^in series 1, at step 3: the filtered mean, covariance or "
                                                     r"log-likelihood is not finite"):
            run(model, gf.Gaussian(0.0, 1.0), zs, engine="numba")
        with pytest.raises(FloatingPointError, match=r"^in series 1, at step 3: the filtered"):  # the same words
            run(model, gf.Gaussian(0.0, 1.0), zs, engine="python")


def test_smoothed_beliefs_are_checked_after_a_compiled_backward_pass():
    from gaussfuse.inference.results import check_smoothed

    means, covs = np.zeros((2, 5, 2)), np.tile(np.eye(2), (2, 5, 1, 1))
    check_smoothed(means, covs)
    covs[1, 1, 0, 0] = covs[1, 3, 1, 1] = np.inf
    with pytest.raises(FloatingPointError, match=r"^in series 1, at step 3: the smoothed mean or covariance is not "
                                                 r"finite"):
        check_smoothed(means, covs)  # the backward pass would have met step 3 first
    with pytest.raises(FloatingPointError, match=r"^at step 2: the smoothed"):
        check_smoothed(np.where(np.arange(5)[None, :, None] == 2, np.nan, 0.0)[:1], covs[:1])


# ---------------------------------------------------------------------------
# engine="auto": compile only when it pays
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("state, steps, passes, compiled", [
    ("cold", 5_000, 1, False),       # 14 s of compilation against 0.1 s of readable steps
    ("cold", 2_000_000, 1, True),    # 40 s of readable steps
    ("cached", 5_000, 1, False),     # loading (1 s) against 0.1 s
    ("cached", 100_000, 1, True),
    ("cached", 5_000, 30, True),     # a fit's thirty passes: 3 s
    ("loaded", 1_000, 1, True),
    ("loaded", 999, 1, False),       # short calls stay readable, the same in every process
    ("loaded", 100, 30, False),      # ... however many passes
])
def test_auto_compiles_only_when_it_costs_less_than_the_readable_path(monkeypatch, state, steps, passes, compiled):
    from gaussfuse._kernels import kernels, linear  # noqa: F401  (imported: its kernels may be loaded)
    from gaussfuse.inference import drivers
    from gaussfuse.inference.registry import METHODS

    seen = []
    monkeypatch.setattr(drivers, "kernel_states",
                        lambda *args: seen.append(args) or dict.fromkeys(kernels(*args[:2]), state))
    chosen = drivers.compiled_engine(METHODS["kf"], "auto", steps, passes)
    assert (chosen is not None) == compiled
    assert seen == ([] if steps < drivers.AUTO_NUMBA_STEPS else [("linear", False, None)])
    # "numba" and "python" are not weighed
    assert drivers.compiled_engine(METHODS["kf"], "numba", 1) is not None
    assert drivers.compiled_engine(METHODS["kf"], "python", 10**9) is None
    assert len(seen) <= 1


@pytest.mark.parametrize("state, steps, first", [
    ("loaded", 600, 2),     # nothing to pay, but not before 1000 readable steps: the third round
    ("loaded", 5_000, 1),
    ("cached", 600, 83),    # loading (1 s) against 600 * 2e-5 s a round: paid by the 84th round
    ("cold", 600, 1583),    # compiling (14 + 5 s)
])
def test_a_loop_of_readable_rounds_starts_the_kernels_once_they_would_have_paid(monkeypatch, state, steps, first):
    from gaussfuse.inference import drivers

    pytest.importorskip("numba")
    monkeypatch.setattr(drivers, "kernel_states", lambda module, smoothing=False: dict.fromkeys(
        [("linear", "forward"), ("_rts", "backward")], state))
    assert drivers.switch_step("linear", True, steps) == first


def test_auto_weighs_the_kernels_a_call_runs(monkeypatch):
    """A filter asks about the forward kernel, a smoother and a fit about the backward pass too."""
    from gaussfuse._kernels import linear  # noqa: F401  (imported: otherwise short calls skip asking)
    from gaussfuse.errors import ConvergenceWarning
    from gaussfuse.inference import drivers

    seen = []
    monkeypatch.setattr(drivers, "kernel_states", lambda *args: seen.append(args) or {("linear", "forward"): "cold"})
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    prior = gf.Gaussian(0.0, 1.0)
    y = np.zeros((2, 500, 1))
    gf.filter(model, prior, y)
    gf.smooth(model, prior, y)
    gf.smooth(model, prior, y[0])  # 500 steps: readable without asking
    with pytest.warns(ConvergenceWarning):
        gf.fit(model, prior, np.zeros(1200), iterations=2)  # and again for EM's iteration to start them
    assert seen == [("linear", False, None), ("linear", True, None), ("linear", True, None), ("linear", True)]


SHORT_DECISION = """
import sys
import gaussfuse as gf
from gaussfuse.inference import drivers
from gaussfuse.inference.registry import METHODS
asked = []
drivers.kernel_states = lambda *args: asked.append(args) or {}
short = drivers.compiled_engine(METHODS["kf"], "auto", 5_000)
print(short is None, len(asked), "gaussfuse._kernels.linear" in sys.modules, "importlib.metadata" in sys.modules)
drivers.compiled_engine(METHODS["kf"], "auto", 5_000_000)
print(len(asked))
"""


def test_a_call_that_loading_alone_would_not_pay_for_looks_at_nothing_on_disk():
    """With no kernel of the engine imported, starting it costs at least a load (1 s): a call whose readable
    steps cost less is readable without reading numba's cache (which costs 30-40 ms of imports)."""
    child = subprocess.run([sys.executable, "-c", SHORT_DECISION], capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr
    # readable, without asking about the kernels or reading the cache; a long call asks
    assert child.stdout.split() == ["True", "0", "False", "False", "1"]


def test_the_start_is_the_compilation_of_each_cold_kernel_plus_one_load():
    from gaussfuse.inference.drivers import COMPILE, START, start_seconds

    assert start_seconds({("linear", "forward"): "loaded", ("_rts", "backward"): "loaded"}) == 0.0
    assert start_seconds({("linear", "forward"): "cached", ("_rts", "backward"): "cached"}) == START["cached"]
    assert start_seconds({("linear", "forward"): "cold", ("_rts", "backward"): "cached"}) == (
        COMPILE["linear.forward"] + START["cached"])
    assert start_seconds({("sigma_points", "advance"): "cold", ("sigma_points", "hold"): "cold"}) == (
        COMPILE["sigma_points.advance"] + COMPILE["sigma_points.hold"])


def test_every_kernel_has_a_compile_estimate():
    from gaussfuse._kernels import kernels
    from gaussfuse.inference.drivers import COMPILE

    names = {f"{m}.{n}" for module in ("linear", "sigma_points") for smoothing in (False, True)
             for jitted in (False, True) for m, n in kernels(module, smoothing, jitted)}
    assert names == set(COMPILE)


@pytest.mark.parametrize("step, loop, steps, compiled", [
    ("cold", "cold", 500_000, False),    # compiling the step and the loop (28 + 4 + 1 s) against 30 s readable
    ("cold", "cold", 600_000, True),
    ("cached", "cold", 30_000, False),   # loading the step (1 s) and compiling the loop (1 s) against 1.8 s
    ("cached", "cold", 40_000, True),
    ("cached", "cached", 15_000, False),  # loading them (1 s) against 0.9 s
    ("cached", "cached", 20_000, True),
    ("loaded", "loaded", 1_000, True),
])
def test_auto_weighs_the_loop_compiled_around_jitted_functions(monkeypatch, step, loop, steps, compiled):
    """For numba-jitted f and h the sigma-point engine runs a loop compiled for their signatures, which calls
    the Python mode's step kernel: "auto" weighs the states of both."""
    from gaussfuse._kernels import JITTED_LOOP
    from gaussfuse.inference import drivers
    from gaussfuse.inference.registry import METHODS

    def states(module, smoothing=False, jitted=None):
        assert (module, smoothing, jitted) == ("sigma_points", False, loop)
        return {("sigma_points", "advance"): step, ("sigma_points", "hold"): step, JITTED_LOOP: jitted}

    import gaussfuse._kernels.sigma_points  # noqa: F401 - imported, as it is whenever f and h are jitted

    monkeypatch.setattr(drivers, "kernel_states", states)
    chosen = drivers.compiled_engine(METHODS["ukf"], "auto", steps, loop=lambda: loop)
    assert (chosen is not None) == compiled


@pytest.mark.parametrize("module, method", [("linear", "kf"), ("sigma_points", "ukf")])
def test_auto_starts_the_kernels_once_the_readable_calls_would_have_paid_for_them(monkeypatch, module, method):
    """Ski rental: calls that each would not pay for a load stay readable until, together with the next, they
    would; then the kernels are started. Each engine keeps its own account, and short calls are not counted."""
    from gaussfuse._kernels import kernels
    from gaussfuse.inference import drivers
    from gaussfuse.inference.registry import METHODS

    monkeypatch.setattr(drivers, "kernel_states", lambda *args: dict.fromkeys(kernels(*args[:2]), "cached"))
    share = drivers.START["cached"] / 3.5  # a call's readable cost beyond the compiled one: 3.5 calls buy a load
    steps = int(share / drivers.READABLE_STEP[module])
    other = "sigma_points" if module == "linear" else "linear"
    choices = []
    for _ in range(5):
        drivers.compiled_engine(METHODS[method], "auto", drivers.AUTO_NUMBA_STEPS - 1)  # short: not counted
        choices.append(drivers.compiled_engine(METHODS[method], "auto", steps) is not None)
    assert choices == [False, False, False, True, True]  # the fourth call's share reaches the load
    assert drivers._SPENT[module] == pytest.approx(3 * share, rel=1e-3)
    assert other not in drivers._SPENT


# ---------------------------------------------------------------------------
# The divergence check
# ---------------------------------------------------------------------------


def _pendulum(skip: int):
    """The README's pendulum; `skip` = 6 draws first, which makes the UKF diverge (issue 12)."""
    dt, g = 0.01, 9.81
    model = gf.NonlinearModel(f=lambda x: np.array([x[0] + dt * x[1], x[1] - g * np.sin(x[0]) * dt]),
                              h=lambda x: np.sin(x[:1]), Q=0.01 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]),
                              R=0.1)
    rng = np.random.default_rng(0)
    rng.standard_normal(skip)
    zs = np.sin(np.cos(np.arange(1, 301) * dt * np.sqrt(g))) + np.sqrt(0.1) * rng.standard_normal(300)
    return model, gf.Gaussian([0.0, 0.0], np.eye(2)), zs


def test_a_diverging_ukf_is_named_with_its_steps():
    model, prior, zs = _pendulum(6)
    with pytest.warns(gf.DivergenceWarning, match=r"2\.63 over steps 100-249 \(1 expected"):
        res = gf.filter(model, prior, zs, method="ukf")
    assert abs(res.means[-1, 0]) > 10  # it did diverge: the angle ends beyond 3π
    with pytest.raises(gf.DivergenceWarning, match="steps 100-249"):
        gf.smooth(model, prior, zs, method="ukf", check="raise")
    with warnings.catch_warnings():
        warnings.simplefilter("error", gf.DivergenceWarning)
        gf.filter(model, prior, zs, method="ukf", check="off")
        gf.filter(model, prior, zs, method="ukf", keep="last")  # no per-step values: nothing to test
        for method in ("ekf", "ckf"):  # these do not diverge on this draw
            gf.filter(model, prior, zs, method=method)
        gf.filter(*_pendulum(0), method="ukf")  # nor the README's draw
    with pytest.warns(gf.DivergenceWarning, match="steps 100-249"):  # the Gauss-Hermite filter diverges too
        assert abs(gf.filter(model, prior, zs, method="ghkf").means[-1, 0]) > 10


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_nis_is_the_same_on_both_engines_and_names_the_series(engine):
    model = gf.constant_velocity(0.1, 1.0, 0.25)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    rng = np.random.default_rng(3)
    zs = 0.1 * np.arange(1, 201)[None, :, None] + 0.5 * rng.standard_normal((3, 200, 1))
    zs[2, 120:170] += 5.0  # a sensor fault in series 2
    zs[0, 50, 0] = np.nan
    with pytest.warns(gf.DivergenceWarning) as caught:
        res = gf.filter(model, prior, zs, engine=engine)
    message = str(caught[0].message)
    first, last = map(int, re.search(r"over steps (\d+)-(\d+) of series 2 \(", message).groups())
    assert first <= 120 and last >= 169 and "series 0" not in message and "series 1" not in message
    want = diagnostics.nis(res.innovations, res.innovation_covs)
    np.testing.assert_allclose(res.nis, want, rtol=1e-12)
    assert np.isnan(res.nis[0, 50])
    with pytest.raises(ValueError, match="`check` must be one of"):
        gf.filter(model, prior, zs, check="loud")


def test_the_step_back_to_the_prior_is_kalman_rts_step_for_every_series():
    """smooth_batch(to_prior=True) continues each series one RTS step back to the prior's time: in one stacked
    call of kalman.rts_step when the series share the prediction's covariance, series by series otherwise."""
    from dataclasses import replace

    from gaussfuse import kalman
    from gaussfuse.inference.drivers import _back_to_prior, smooth_batch
    from gaussfuse.inference.registry import METHODS

    rng = np.random.default_rng(5)
    model = gf.LinearModel(np.array([[1.0, 0.5], [0.0, 0.9]]), np.array([[1.0, 0.0]]), 0.2 * np.eye(2),
                           np.array([[0.5]]), B=np.array([[0.0], [1.0]]))
    prior = gf.Gaussian([0.3, -0.2], np.array([[2.0, 0.3], [0.3, 1.0]]))
    zs, us = rng.standard_normal((3, 8, 1)), rng.standard_normal((3, 8, 1))
    sm = smooth_batch(METHODS["kf"], model, prior, zs, us, {}, "python")
    shared = _back_to_prior(model, prior, sm)
    filt = sm.filtered
    changed = filt.predicted_covs.copy()
    changed[1, 0] *= 1.5  # series 1 with a prediction of its own: the series-by-series path
    apart = _back_to_prior(model, prior, replace(sm, filtered=replace(filt, predicted_covs=changed)))
    for res, pcovs in ((shared, filt.predicted_covs), (apart, changed)):
        for i in range(3):
            m0, P0, G0 = kalman.rts_step(prior.mean, prior.cov, filt.predicted_means[i, 0], pcovs[i, 0],
                                         sm.means[i, 0], sm.covs[i, 0], prior.cov @ model.F.T)
            np.testing.assert_allclose(res.means[i, 0], m0, rtol=1e-13, atol=1e-14)
            np.testing.assert_allclose(res.covs[i, 0], P0, rtol=1e-13, atol=1e-14)
            np.testing.assert_allclose(res.gains[i, 0], G0, rtol=1e-13, atol=1e-14)
            np.testing.assert_array_equal(res.means[i, 1:], sm.means[i])
            np.testing.assert_array_equal(res.gains[i, 1:], sm.gains[i])
    assert not np.allclose(apart.covs[1, 0], shared.covs[1, 0])


@pytest.mark.parametrize("call", [gf.filter, gf.smooth])
@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_an_error_in_one_of_several_series_names_it_on_every_engine(call, form):
    """The compiled loops said "in series 2, at step 0: ..."; the readable path (and the square-root form,
    which falls back to it) said only "at step 0", so a batch on it could not tell which series failed."""
    twin = gf.LinearModel(F=np.eye(2), H=[[1.0, 0.0], [1.0, 0.0]], Q=np.zeros((2, 2)), R=[[1.0, 1.0], [1.0, 1.0]])
    zs = np.full((4, 3, 2), 0.3)
    zs[[0, 1, 3], :, 1] = np.nan  # only series 2 meets the singular S, taking the same measurement twice
    for engine in ("python", "numba"):
        with pytest.raises(np.linalg.LinAlgError, match=r"^in series 2, at step 0: the innovation covariance S"):
            call(twin, gf.Gaussian([0.0, 0.0], np.eye(2)), zs, engine=engine, form=form)
    with pytest.raises(np.linalg.LinAlgError, match=r"^at step 0: "):  # one series: no series to name
        call(twin, gf.Gaussian([0.0, 0.0], np.eye(2)), zs[2], engine="python", form=form)


@pytest.mark.parametrize("form", ["cov", "sqrt"])
@pytest.mark.parametrize("engine", ["python", "numba"])
def test_an_innovation_covariance_a_negative_weight_made_indefinite_names_the_weight(form, engine):
    """Audit Z4: with the unscented rule's default kappa = 3 - n (negative past three states) the measurements'
    spread can come out indefinite; the covariance form's error blamed S = H P Hᵀ + R and advised a larger R."""
    n = 10
    model = gf.NonlinearModel(lambda x: x, lambda x: np.array([x @ x]), 0.01 * np.eye(n), 0.01)
    with pytest.raises(np.linalg.LinAlgError) as info:
        gf.filter(model, gf.Gaussian(np.zeros(n), np.eye(n)), [1.0, 2.0], method="ukf", form=form, engine=engine)
    message = str(info.value)
    assert message.startswith("at step 0: ") and "innovation covariance" in message
    assert "kappa >= 0 (its default, 3 - n, is negative past three states)" in message and "method='ckf'" in message
    assert message.count("method='ckf'") == 1
    gf.filter(model, gf.Gaussian(np.zeros(n), np.eye(n)), [1.0, 2.0], method="ckf", form=form, engine=engine)
    assert "singular" not in message  # not the advice for a singular S
    # beside a measurement on a scale 1e12 times larger in variance (review R15; the square-root form's error said
    # "singular" and lost the hint)
    scaled = gf.NonlinearModel(lambda x: x, lambda x: np.array([x @ x, 1e6 * x[0]]), 0.01 * np.eye(n),
                               0.01 * np.eye(2))
    with pytest.raises(np.linalg.LinAlgError, match=r"S is indefinite.*kappa >= 0 \(its default") as info:
        gf.filter(scaled, gf.Gaussian(np.zeros(n), np.eye(n)), [[1.0, 0.0]], method="ukf", form=form, engine=engine)
    assert "singular" not in str(info.value) and "1.0100e+12" in str(info.value)
    # A singular S that is not indefinite (one state measured twice without noise) is not the weight's doing:
    # the cubature filter fails alike (review R14)
    twice = gf.NonlinearModel(lambda x: x, lambda x: x[[0, 0]], 0.01 * np.eye(n), np.zeros((2, 2)))
    for method in ("ukf", "ckf"):
        with pytest.raises(np.linalg.LinAlgError) as info:
            gf.filter(twice, gf.Gaussian(np.zeros(n), np.eye(n)), [[1.0, 1.0]], method=method, form=form,
                      engine=engine)
        assert "negatively" not in str(info.value) and "indefinite" not in str(info.value)
        assert "S is singular to round-off where" in str(info.value) and "R = 0" in str(info.value)


def test_a_smoother_at_its_limit_over_series_counts_them_once():
    """The series count of the smoother's passes was told twice, after the method's name too (review R54)."""
    model = gf.NonlinearModel(f=lambda x: np.sin(x) * 2.0, h=lambda x: x ** 3, Q=[[0.5]], R=[[0.01]])
    zs = np.random.default_rng(0).normal(0, 3, (2, 20, 1))
    with pytest.warns(gf.ConvergenceWarning) as told:
        gf.smooth(model, gf.Gaussian([0.5], [[4.0]]), zs, method="iekf", iterations=2, tol=1e-15, check="off")
    assert [str(w.message) for w in told] == [
        "method 'iekf': 40 of 40 steps of the filter made 2 iterations and the smoother made 2 passes in 2 of 2 "
        "series (the limit, `iterations`=2) without the change falling to `tol`=1e-15; raise `iterations` or `tol`, "
        "or check the model."]
