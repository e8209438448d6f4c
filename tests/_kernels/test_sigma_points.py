"""The compiled sigma-point engine (ukf, ckf, ghkf) equals the readable path.

Every comparison runs ``engine="numba"`` against ``engine="python"`` (the
readable SLR + Kalman path) to 1e-10, in the three execution modes of
:mod:`gaussfuse._kernels.sigma_points`: plain Python f and h, vectorized f
and h, and numba-compiled f and h (the whole loop compiled).
"""

import json
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from _pendulum import DT, G, PENDULUM_Q, pendulum_f, pendulum_f_vec, pendulum_h, pendulum_h_vec
import gaussfuse as gf
from gaussfuse.inference import drivers
from gaussfuse._kernels import sigma_points as sp
from gaussfuse.errors import ModelFunctionError

DATA = Path(__file__).resolve().parent.parent / "data"
TOL = 1e-10
MODES = ["plain", "vectorized", "jitted"]
METHODS = [("ukf", {}), ("ckf", {}), ("ghkf", {})]


def assert_same(got, want, tol=TOL):
    """Every field of two Filter/SmoothResults agrees to `tol` (None where the other is None)."""
    assert type(got) is type(want)
    for field in fields(want):
        a, b = getattr(got, field.name), getattr(want, field.name)
        if field.name == "filtered":
            assert_same(a, b, tol)
        elif b is None:
            assert a is None, field.name
        else:
            assert np.shape(a) == np.shape(b), field.name
            np.testing.assert_allclose(a, b, rtol=tol, atol=tol, err_msg=field.name)


def both(fn, *args, **kwargs):
    """``fn`` with the compiled and the readable engine: (numba result, python result, mode used)."""
    got = fn(*args, engine="numba", **kwargs)
    mode = sp.execution_mode(args[0], args[1], kwargs.get("us", args[3] if len(args) > 3 else None))
    return got, fn(*args, engine="python", **kwargs), mode


# ---------------------------------------------------------------------------
# Särkkä & Svensson's pendulum, in the three modes
# ---------------------------------------------------------------------------


pendulum_f_jit = numba.njit(cache=True)(pendulum_f)
pendulum_h_jit = numba.njit(cache=True)(pendulum_h)


@numba.njit(cache=True)
def pendulum_f_stack_jit(X):
    out = np.empty_like(X)
    out[:, 0] = X[:, 0] + DT * X[:, 1]
    out[:, 1] = X[:, 1] - G * np.sin(X[:, 0]) * DT
    return out


@numba.njit(cache=True)
def pendulum_h_stack_jit(X):
    return np.sin(X[:, :1])


@numba.njit(cache=True)
def pendulum_h_scalar_jit(x):
    return np.sin(x[0])


PENDULUM_FUNCTIONS = {
    "plain": (pendulum_f, pendulum_h, False),
    "vectorized": (pendulum_f_vec, pendulum_h_vec, False),
    "jitted": (pendulum_f_jit, pendulum_h_jit, False),
    "jitted-vectorized": (pendulum_f_stack_jit, pendulum_h_stack_jit, True),
    "jitted-scalar-h": (pendulum_f_jit, pendulum_h_scalar_jit, False),
}
PENDULUM_TABLE = [
    ("ukf", {"alpha": 1.0, "beta": 0.0, "kappa": 1.0}, 0.09524392, 0.03661756),
    ("ckf", {}, 0.11419660, 0.04064624),
    ("ghkf", {"order": 5}, 0.09980624, 0.03710182),
]


def pendulum_model(mode):
    f, h, stacked = PENDULUM_FUNCTIONS[mode]
    return gf.NonlinearModel(f, h, PENDULUM_Q, 0.1, vectorized=mode == "vectorized" or stacked)


@pytest.fixture(scope="module")
def pendulum():
    data = json.loads((DATA / "pendulum.json").read_text())
    return np.array(data["X"]).T, np.array(data["Y"])


def _rmse(means, truth):
    return np.sqrt(np.mean((means[:, 0] - truth[:, 0]) ** 2))


@pytest.mark.parametrize("mode", list(PENDULUM_FUNCTIONS))
@pytest.mark.parametrize("method, options, filter_rmse, smoother_rmse", PENDULUM_TABLE,
                         ids=[row[0] for row in PENDULUM_TABLE])
def test_pendulum_table(pendulum, mode, method, options, filter_rmse, smoother_rmse):
    truth, zs = pendulum
    model = pendulum_model(mode)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    sm, ref, used = both(gf.smooth, model, prior, zs, method=method, **options)
    assert used == ("python" if mode in ("plain", "vectorized") else "compiled")
    assert _rmse(sm.filtered.means, truth) == pytest.approx(filter_rmse, abs=5e-8)
    assert _rmse(sm.means, truth) == pytest.approx(smoother_rmse, abs=5e-8)
    assert_same(sm, ref)
    res = gf.filter(model, prior, zs, method=method, engine="numba", **options)
    np.testing.assert_array_equal(res.means, sm.filtered.means)
    np.testing.assert_array_equal(res.covs, sm.filtered.covs)
    assert res.loglik == sm.loglik


# ---------------------------------------------------------------------------
# A small nonlinear model with angles, controls, time-varying noise and gaps
# ---------------------------------------------------------------------------
# x = (position, heading [an angle], speed); z = (range to a beacon, bearing [an angle]).


def toy_f(x):
    return np.array([x[0] + 0.1 * x[2] * np.cos(x[1]), x[1] + 0.3 + 0.05 * np.sin(x[0]), 0.95 * x[2]])


def toy_f_u(x, u):
    return toy_f(x) + np.array([u[0], 0.0, u[1]])


def toy_h(x):
    return np.array([np.sqrt(1.0 + (x[0] - 2.0) ** 2 + x[2] ** 2), np.arctan2(x[2] - 0.5, x[0] - 2.0)])


def toy_f_vec(X):
    return np.stack([X[:, 0] + 0.1 * X[:, 2] * np.cos(X[:, 1]), X[:, 1] + 0.3 + 0.05 * np.sin(X[:, 0]),
                     0.95 * X[:, 2]], axis=-1)


def toy_f_u_vec(X, u):
    return toy_f_vec(X) + np.array([u[0], 0.0, u[1]])


def toy_h_vec(X):
    return np.stack([np.sqrt(1.0 + (X[:, 0] - 2.0) ** 2 + X[:, 2] ** 2),
                     np.arctan2(X[:, 2] - 0.5, X[:, 0] - 2.0)], axis=-1)


toy_f_jit = numba.njit(cache=True)(toy_f)
toy_h_jit = numba.njit(cache=True)(toy_h)


@numba.njit(cache=True)
def toy_f_u_jit(x, u):
    return toy_f_jit(x) + np.array([u[0], 0.0, u[1]])


@numba.njit(cache=True)
def toy_f_stack_jit(X):
    out = np.empty_like(X)
    for i in range(X.shape[0]):
        out[i] = toy_f_jit(X[i])
    return out


@numba.njit(cache=True)
def toy_f_u_stack_jit(X, u):
    out = np.empty_like(X)
    for i in range(X.shape[0]):
        out[i] = toy_f_u_jit(X[i], u)
    return out


@numba.njit(cache=True)
def toy_h_stack_jit(X):
    out = np.empty((X.shape[0], 2))
    for i in range(X.shape[0]):
        out[i] = toy_h_jit(X[i])
    return out


TOY = {
    "plain": (toy_f, toy_f_u, toy_h),
    "vectorized": (toy_f_vec, toy_f_u_vec, toy_h_vec),
    "jitted": (toy_f_jit, toy_f_u_jit, toy_h_jit),
    "jitted-vectorized": (toy_f_stack_jit, toy_f_u_stack_jit, toy_h_stack_jit),
}


def _spd(rng, size, scale):
    A = rng.standard_normal((size, size))
    return scale * (A @ A.T / size + 0.2 * np.eye(size))


def toy_problem(seed, mode, *, N=1, T=6, controls=False, missing=False, varying=False, angles=True):
    rng = np.random.default_rng(seed)
    f, f_u, h = TOY[mode]
    Q = np.stack([_spd(rng, 3, 0.01) for _ in range(T)]) if varying else _spd(rng, 3, 0.01)
    R = np.stack([_spd(rng, 2, 0.05) for _ in range(T)]) if varying else _spd(rng, 2, 0.05)
    model = gf.NonlinearModel(f_u if controls else f, h, Q, R, vectorized=mode.endswith("vectorized"),
                              state_angles=[1] if angles else (), measurement_angles=[1] if angles else ())
    prior = gf.Gaussian(rng.normal(0.0, 0.3, 3) + [0.0, 3.0, 1.0], _spd(rng, 3, 0.05))
    zs = np.stack([toy_h(x) for x in rng.normal(0.0, 1.0, (N * T, 3))]).reshape(N, T, 2)
    zs += rng.normal(0.0, 0.2, zs.shape)
    if missing:
        zs[rng.random(zs.shape) < 0.3] = np.nan
        zs[:, T // 2] = np.nan  # a step with nothing observed
    us = rng.normal(0.0, 0.1, (N, T, 2)) if controls else None
    return model, prior, zs, us


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), mode=st.sampled_from(list(TOY)), method=st.sampled_from(["ukf", "ckf", "ghkf"]),
       N=st.integers(1, 3), T=st.integers(1, 7), controls=st.booleans(), missing=st.booleans(),
       varying=st.booleans(), angles=st.booleans(), keep=st.sampled_from(["all", "means", "last"]))
def test_filter_and_smoother_equal_the_readable_path(seed, mode, method, N, T, controls, missing, varying, angles,
                                                     keep):
    model, prior, zs, us = toy_problem(seed, mode, N=N, T=T, controls=controls, missing=missing,
                                       varying=varying, angles=angles)
    res, ref, used = both(gf.filter, model, prior, zs, us, method=method, keep=keep)
    assert used == ("compiled" if mode.startswith("jitted") else "python")
    assert_same(res, ref)
    sm, ref, _ = both(gf.smooth, model, prior, zs, us, method=method)
    assert_same(sm, ref)
    assert sm.means.shape == (N, T, 3) and sm.gains.shape == (N, T - 1, 3, 3)


@pytest.mark.parametrize("mode", list(TOY))
@pytest.mark.parametrize("method, options", [("ukf", {"alpha": 0.5, "beta": 2.0, "kappa": 0.0}),
                                             ("ghkf", {"order": 2})])
def test_options_controls_time_varying_noise_and_gaps(mode, method, options):
    model, prior, zs, us = toy_problem(3, mode, N=2, T=30, controls=True, missing=True, varying=True)
    sm, ref, _ = both(gf.smooth, model, prior, zs, us, method=method, **options)
    assert_same(sm, ref)
    assert np.isnan(sm.filtered.innovations[:, 15]).all()  # the all-missing step
    np.testing.assert_array_equal(sm.filtered.means[:, 15], sm.filtered.predicted_means[:, 15])


@pytest.mark.parametrize("mode", MODES)
def test_keep_and_batches(mode):
    model, prior, zs, us = toy_problem(11, mode, N=3, T=20, controls=True, missing=True)
    full = gf.filter(model, prior, zs, us, method="ckf", engine="numba")
    for keep, dropped in (("means", ("covs", "predicted_covs", "innovation_covs")),
                          ("last", ("means", "covs", "predicted_means", "predicted_covs", "innovations", "nis",
                                    "innovation_covs"))):
        part = gf.filter(model, prior, zs, us, method="ckf", engine="numba", keep=keep)
        for field in fields(part):
            value = getattr(part, field.name)
            if field.name in dropped:
                assert value is None
            else:
                np.testing.assert_array_equal(value, getattr(full, field.name))
    # a batch is its series, one by one
    assert full.loglik.shape == (3,) and full.last_mean.shape == (3, 3) and full.last_cov.shape == (3, 3, 3)
    for i in range(3):
        one = gf.filter(model, prior, zs[i], us[i], method="ckf", engine="numba")
        assert isinstance(one.loglik, float)
        np.testing.assert_allclose(one.means, full.means[i], rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(one.last_cov, full.last_cov[i], rtol=1e-13, atol=1e-13)
        assert one.loglik == pytest.approx(full.loglik[i], rel=1e-13)


# ---------------------------------------------------------------------------
# A range-bearing track whose bearing crosses ±180°
# ---------------------------------------------------------------------------

CV = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1.0]])
CV_Q = 0.01 * np.kron(np.array([[1 / 3, 1 / 2], [1 / 2, 1]]), np.eye(2))
RB_R = np.diag([0.5**2, np.deg2rad(1.0) ** 2])


def rb_f(x):
    return CV @ x


def rb_h(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def rb_f_vec(X):
    return X @ CV.T


def rb_h_vec(X):
    return np.stack([np.hypot(X[:, 0], X[:, 1]), np.arctan2(X[:, 1], X[:, 0])], axis=-1)


@numba.njit(cache=True)
def rb_f_jit(x):
    return np.array([x[0] + x[2], x[1] + x[3], x[2], x[3]])


rb_h_jit = numba.njit(cache=True)(rb_h)
RB = {"plain": (rb_f, rb_h), "vectorized": (rb_f_vec, rb_h_vec), "jitted": (rb_f_jit, rb_h_jit)}


def crossing_track(T=40):
    """A target moving along x = -100 from y = +60 to y = -60; bearings reported in [0, 2π)."""
    rng = np.random.default_rng(7)
    truth = np.zeros((T, 4))
    truth[:, 0], truth[:, 1], truth[:, 3] = -100.0, 60.0 - 3.0 * np.arange(T), -3.0
    r = np.hypot(truth[:, 0], truth[:, 1]) + 0.5 * rng.standard_normal(T)
    b = np.arctan2(truth[:, 1], truth[:, 0]) + np.deg2rad(1.0) * rng.standard_normal(T)
    return truth, np.stack([r, b % (2 * np.pi)], axis=-1)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("method", ["ukf", "ckf", "ghkf"])
def test_bearing_crossing_180_degrees(mode, method):
    truth, zs = crossing_track()
    assert np.any(np.abs(np.diff(np.arctan2(truth[:, 1], truth[:, 0]))) > np.pi)
    model = gf.NonlinearModel(*RB[mode], CV_Q, RB_R, vectorized=mode == "vectorized", measurement_angles=[1])
    prior = gf.Gaussian([-100.0, 63.0, 0.0, -3.0], np.diag([25.0, 25.0, 1.0, 1.0]))
    sm, ref, _ = both(gf.smooth, model, prior, zs, method=method)
    assert_same(sm, ref)
    assert np.hypot(*(sm.means[:, :2] - truth[:, :2]).T).max() < 5.0
    assert np.all(np.abs(sm.filtered.innovations[:, 1]) < np.deg2rad(10))  # wrapped: no 2π jumps


def test_state_angles_are_wrapped():
    model = gf.NonlinearModel(lambda x: np.array([x[0] + 0.5]), lambda x: np.array([np.cos(x[0]), np.sin(x[0])]),
                              Q=1e-4, R=0.01 * np.eye(2), state_angles=[0])
    heading = (0.5 * np.arange(1, 21) + np.pi) % (2 * np.pi) - np.pi
    zs = np.stack([np.cos(heading), np.sin(heading)], axis=-1)
    sm, ref, _ = both(gf.smooth, model, gf.Gaussian(0.0, 0.01), zs, method="ukf")
    assert_same(sm, ref)
    assert np.all((sm.means >= -np.pi) & (sm.means < np.pi))


# ---------------------------------------------------------------------------
# Singular and nearly singular covariances, with tolerances scaled to the problem
# ---------------------------------------------------------------------------

VARIANCES = [0.0, 1e-30, 1e-4, 1.0, 1e4]


def scaled_cov(rng, variances):
    """A covariance with the given variances: correlated where they are ordinary, diagonal where tiny."""
    n = len(variances)
    A = rng.standard_normal((n, n))
    corr = A @ A.T / n + 0.2 * np.eye(n)
    corr /= np.sqrt(np.outer(np.diag(corr), np.diag(corr)))
    tiny = variances < 1e-20
    corr[tiny], corr[:, tiny] = 0.0, 0.0
    corr[tiny, tiny] = 1.0
    sd = np.sqrt(variances)
    return sd[:, None] * corr * sd[None, :]


def degenerate_problem(seed, mode, *, N=1, T=6, q_kind="full"):
    """The toy model with a degenerate prior (variances from VARIANCES) and process noise of `q_kind`.

    Returns the problem and whether its smoothers can be compared (see
    test_singular_and_nearly_singular_covariances).
    """
    rng = np.random.default_rng(seed)
    f, _, h = TOY[mode]
    variances = rng.choice(VARIANCES, 3)
    Q = _spd(rng, 3, 0.01)
    if q_kind == "zero rows":  # some components without process noise
        still = rng.random(3) < 0.5
        Q[still], Q[:, still] = 0.0, 0.0
    elif q_kind == "low rank":
        B = rng.standard_normal((3, int(rng.integers(1, 3))))
        Q = 0.01 * B @ B.T
    elif q_kind == "zero":
        Q = np.zeros((3, 3))
    model = gf.NonlinearModel(f, h, Q, _spd(rng, 2, 0.05), vectorized=mode.endswith("vectorized"),
                              state_angles=[1], measurement_angles=[1])
    prior = gf.Gaussian(rng.normal(0.0, 0.3, 3) + [0.0, 3.0, 1.0], scaled_cov(rng, variances))
    zs = np.stack([toy_h(x) for x in rng.normal(0.0, 1.0, (N * T, 3))]).reshape(N, T, 2)
    zs += rng.normal(0.0, 0.2, zs.shape)
    unresolved = np.any((variances == 1e-30) & (np.diag(Q) == 0.0))
    return model, prior, zs, not unresolved


def equilibrated_condition(cov):
    """The condition number of `cov` scaled to unit diagonal, on its numerical range.

    Scaling makes it blind to units (variances of 1e-30 next to 1e4 alone are
    harmless); components of zero variance and eigenvalues of the scaled matrix
    below ``n ε λ_max`` (exact rank deficiency, which the smoothers treat as
    such) do not count.
    """
    d = np.diag(cov)
    keep = d > 0
    if not keep.any():
        return 1.0
    sd = np.sqrt(d[keep])
    lam = np.linalg.eigvalsh(cov[np.ix_(keep, keep)] / np.outer(sd, sd))
    lam = lam[lam > keep.sum() * np.finfo(float).eps * lam[-1]]
    return float(lam[-1] / lam[0])


def assert_agree(got, want, tol=TOL):
    """Two Filter/SmoothResults agree to `tol` relative to the scale of the quantities.

    With M the largest |mean| and V the largest |variance| of the forward pass
    (filtered and predicted), means are compared to ``tol (M + √V)`` and
    covariances to ``tol (V + 10⁻³ M √V)``: sigma points sit at ``m ± σ``, so
    every spread they measure carries the round-off of the mean, about
    ``ε |m| σ`` (a covariance of 1e-30 at a mean of 1 is round-off), and
    10⁻³ × 1e-10 allows 450 ε. Smoothed values are differences of the
    filtered ones, and are held to the same scale, times
    ``max(1, 10⁻⁴ κ)`` with κ the largest :func:`equilibrated_condition` of the
    predictions (10⁻⁴ × 1e-10 allows 45 ε κ). The log-likelihood is
    compared relative (and absolute) to `tol`.
    """
    filt = want.filtered if isinstance(want, gf.SmoothResult) else want
    M = max(np.max(np.abs(filt.means)), np.max(np.abs(filt.predicted_means)))
    V = max(np.max(np.abs(filt.covs)), np.max(np.abs(filt.predicted_covs)))
    mean_atol, cov_atol = tol * (M + np.sqrt(V)), tol * (V + 1e-3 * M * np.sqrt(V))

    def close(name, atol, a, b):
        np.testing.assert_allclose(a, b, rtol=0, atol=max(atol, 1e-300), err_msg=name)

    if isinstance(want, gf.SmoothResult):
        assert_agree(got.filtered, want.filtered, tol)
        # The gains G = C (P⁻)⁻¹ carry round-off times the condition of P⁻.
        n = filt.means.shape[-1]
        factor = max(1.0, 1e-4 * max(map(equilibrated_condition, filt.predicted_covs.reshape(-1, n, n))))
        close("smoothed means", factor * mean_atol, got.means, want.means)
        close("smoothed covs", factor * cov_atol, got.covs, want.covs)
        # A singular P⁻ fixes the gain only on its range (SmoothResult.gains): G P⁻ = C is compared.
        got_C, want_C = (r.gains @ r.filtered.predicted_covs[..., 1:, :, :] for r in (got, want))
        close("gains times P⁻", factor * cov_atol, got_C, want_C)
        return
    for name in ("means", "predicted_means"):
        close(name, mean_atol, getattr(got, name), getattr(want, name))
    for name in ("covs", "predicted_covs"):
        close(name, cov_atol, getattr(got, name), getattr(want, name))
    S = want.innovation_covs
    v = np.nan_to_num(want.innovations)
    close("innovations", tol * (np.max(np.abs(v)) + np.sqrt(np.max(np.abs(S)))), np.nan_to_num(got.innovations), v)
    close("innovation_covs", tol * np.max(np.abs(S)), got.innovation_covs, S)
    np.testing.assert_allclose(got.loglik, want.loglik, rtol=tol, atol=tol, err_msg="loglik")


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), mode=st.sampled_from(list(TOY)),
       method=st.sampled_from(["ukf", "ckf", "ghkf"]), T=st.integers(1, 7),
       q_kind=st.sampled_from(["full", "zero rows", "low rank", "zero"]))
def test_singular_and_nearly_singular_covariances(seed, mode, method, T, q_kind):
    """Zero variances, variances of 1e-30 next to 1e4, process noise missing on some components or all.

    The filters always agree. The smoothers are compared unless a component
    keeps a tiny nonzero variance without process noise: its spread is then a
    few units in the last place of its mean, the sigma points along it are
    quantised, and the smoother gains of *both* engines divide that
    round-off by a variance of 1e-30 (on the toy model the engines then differ
    by 1e-6 relative in the smoothed covariances; neither is right).
    """
    model, prior, zs, smoothable = degenerate_problem(seed, mode, T=T, q_kind=q_kind)
    res, ref, _ = both(gf.filter, model, prior, zs, method=method)
    assert_agree(res, ref)
    if smoothable:
        sm, ref, _ = both(gf.smooth, model, prior, zs, method=method)
        assert_agree(sm, ref)


@numba.njit(cache=True)
def drift_f_jit(x):
    return np.array([x[0] + 0.1 * x[1], x[1]])


@numba.njit(cache=True)
def sine_h_jit(x):
    return np.array([np.sin(x[0]), 0.1 * x[1] ** 2])


@pytest.mark.parametrize("method, N", [("ckf", 1), ("ukf", 3)])
def test_a_correlated_rank_one_prior_without_noise_smooths_alike_on_both_engines(method, N):
    """A prior of rank one with its two components correlated, and Q = 0, keep P⁻ singular at every step, to
    round-off: at some steps one engine's last bits of P⁻ left a pivot² of 4.5 ε of its row (kept, a Cholesky
    gain) and the other's 0.65 ε (round-off, the least-squares gain), and their gains differed by 0.47 (ckf)
    and 1.8 (three series, ukf) off the range of P⁻. The smoothed moments, and the gains on that range (G P⁻,
    the cross-covariance, and G Pˢ, the lag-one covariance), agree (audit W)."""
    rng = np.random.default_rng(2)
    zs = rng.normal(0.0, 0.5, (N, 25, 2))
    if N > 1:
        zs[rng.random(zs.shape) < 0.3] = np.nan
    model = gf.NonlinearModel(drift_f_jit, sine_h_jit, np.zeros((2, 2)), np.diag([0.05, 0.04]))
    prior = gf.Gaussian([0.3, 0.2], [[0.1, 0.1], [0.1, 0.1]])
    sm, ref, used = both(gf.smooth, model, prior, zs, method=method, check="off")
    assert used == "compiled"
    assert_agree(sm, ref)
    # assert_agree holds the smoothed moments to its tolerance times the condition of P⁻, which a singular P⁻
    # makes larger than the moments themselves (audit QQ2: a smoother off by 1.0 in every mean passed with ukf);
    # the moments do not depend on the gain off the range of P⁻, and agree to round-off (measured 7e-16, 2e-16)
    np.testing.assert_allclose(sm.means, ref.means, rtol=0, atol=1e-13 * np.abs(ref.means).max())
    np.testing.assert_allclose(sm.covs, ref.covs, rtol=0, atol=1e-12 * np.abs(ref.covs).max())
    lag_one = [r.gains @ r.covs[:, 1:] for r in (sm, ref)]
    np.testing.assert_allclose(*lag_one, rtol=0, atol=1e-12 * np.abs(lag_one[1]).max())


# ---------------------------------------------------------------------------
# Singular covariances, odd functions, the automatic engine
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["plain", "jitted"])
def test_singular_covariances_use_the_readable_square_root_and_gain(mode):
    """No noise on a state that starts known: Cholesky fails; the symmetric root and lstsq gain are used."""
    f, h = (pendulum_f, pendulum_h) if mode == "plain" else (pendulum_f_jit, pendulum_h_jit)
    model = gf.NonlinearModel(f, h, np.diag([0.0, 1e-4]), 0.1)
    prior = gf.Gaussian([0.3, 0.0], np.diag([0.0, 0.0]))
    zs = np.sin(0.3 + 0.01 * np.arange(8))
    sm, ref, _ = both(gf.smooth, model, prior, zs, method="ukf")
    assert_same(sm, ref)
    batch, ref, _ = both(gf.filter, model, prior, np.stack([zs, zs + 0.1])[..., None], method="ckf")
    assert_same(batch, ref)


def test_jitted_functions_that_do_not_fit_run_in_python_mode():
    """A jitted h returning integers (a signature the compiled loop does not take) still gives the same numbers."""
    h_int = numba.njit(cache=True)(lambda x: np.array([int(x[0] > 0.0)]))
    model = gf.NonlinearModel(pendulum_f_jit, h_int, PENDULUM_Q, 0.1)
    assert sp.execution_mode(model, gf.Gaussian([0.1, 0.0], np.eye(2))) == "python"
    res, ref, used = both(gf.filter, model, gf.Gaussian([0.1, 0.0], np.eye(2)), np.ones(5), method="ukf")
    assert used == "python"
    assert_same(res, ref)


def test_both_engines_share_one_compiled_square_root_backward_pass():
    """The sigma-point smoother handed the backward pass writable arrays where the linear one hands read-only
    ones: numba compiled it twice (2 s more on a first call). Both results against the readable path."""
    from gaussfuse._kernels import _rts

    model, prior, zs, us = toy_problem(0, "plain")
    assert_same(gf.smooth(model, prior, zs, us, method="ukf", engine="numba", form="sqrt"),
                gf.smooth(model, prior, zs, us, method="ukf", engine="python", form="sqrt"))
    linear = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.1, 0.01]), R=1.0)
    start = gf.Gaussian([0.0, 0.0], np.eye(2))
    want = gf.smooth(linear, start, np.sin(np.arange(20.0)), engine="python", form="sqrt")
    got = gf.smooth(linear, start, np.sin(np.arange(20.0)), engine="numba", form="sqrt")
    np.testing.assert_allclose(got.means, want.means, rtol=1e-10, atol=1e-12)
    assert len(_rts.backward_sqrt.signatures) == 1, _rts.backward_sqrt.signatures


def test_auto_engine_compiles_long_series(pendulum, monkeypatch):
    """With the kernels loaded in this process, "auto" runs them from 1000 steps on, in both modes."""
    _, zs = pendulum
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zz = np.concatenate([zs, zs])  # 1000 steps
    calls = []
    original = sp.filter
    monkeypatch.setattr(sp, "filter", lambda *args, **kwargs: calls.append(1) or original(*args, **kwargs))
    for mode in ("plain", "jitted"):
        model = pendulum_model(mode)
        gf.filter(model, prior, zz[:5], method="ckf", engine="numba")  # loads (or compiles) the kernels
        assert sp.execution_mode(model, prior) == ("compiled" if mode == "jitted" else "python")
        del calls[:]
        assert_same(gf.filter(model, prior, zz[:999], method="ckf"), gf.filter(model, prior, zz[:999], method="ckf",
                                                                               engine="python"))
        assert calls == []  # 999 steps: readable
        res = gf.filter(model, prior, zz, method="ckf")
        assert calls == [1]
        assert_same(res, gf.filter(model, prior, zz, method="ckf", engine="python"))


LOOP_PROBE = """
import sys
import numba, numpy as np, gaussfuse as gf
from gaussfuse._kernels import jitted_loop_state
f, h = numba.njit(lambda x: x * 1.0), numba.njit(lambda x: np.sin(x[:1]))
model = gf.NonlinearModel(f, h, np.eye(2), 1.0)
for form in sys.argv[1:]:
    state = jitted_loop_state(model, gf.Gaussian([0.0, 0.0], np.eye(2)), form=form)
    print(state, "gaussfuse._kernels.sigma_points" in sys.modules)
"""


def probe_loop(forms: list[str], cache_dir=None) -> list[str]:
    """The loop's state for each form in turn, in a new process, and whether telling it had imported the
    sigma-point engine by then."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = str(cache_dir)
    child = subprocess.run([sys.executable, "-c", LOOP_PROBE, *forms], env=env, capture_output=True, text=True,
                           timeout=600)
    assert child.returncode == 0, child.stderr
    return child.stdout.strip().splitlines()[-len(forms):]


def test_the_loop_around_jitted_functions_is_loaded_cached_or_cold(tmp_path):
    """What "auto" weighs for jitted f and h: the loop for their signatures, in this process, on disk, or neither."""
    f, h = numba.njit(lambda x: x * 1.0), numba.njit(lambda x: np.sin(x[:1]))
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    gf.filter(model, prior, np.ones(5), method="ukf", engine="numba")  # compiled, or loaded from the cache
    assert sp.loop_state(model, prior) == "loaded"
    assert sp.loop_state(model, prior, us=np.zeros((1, 5, 1))) != "loaded"  # f(x, u): another signature
    assert sp.loop_state(pendulum_model("plain"), prior) is None  # the Python mode's kernels instead
    cov, sqrt = probe_loop(["cov", "sqrt"])  # a new process, with this one's cache
    assert cov == "cached True"
    assert sqrt in ("cached True", "cold True")  # as other tests left the cache
    # nothing compiled anywhere: "cold", without importing the engine (so that a readable call pays nothing)
    assert probe_loop(["cov", "sqrt"], tmp_path) == ["cold False", "cold False"]


def test_both_modes_share_the_step_kernels_cache_entry():
    """The compiled mode asked numba for the step kernel's address, a compile that numba's disk cache keys
    apart from the Python mode's (with its return type): a new process running the other mode compiled the
    step again (13 s)."""
    from gaussfuse._kernels._jit import cached_signatures

    for mode in ("plain", "jitted"):  # the session's warm-up ran the compiled mode first
        model, prior, zs, us = toy_problem(0, mode)
        assert_same(gf.filter(model, prior, zs, us, method="ukf", engine="numba"),
                    gf.filter(model, prior, zs, us, method="ukf", engine="python"))
    assert len(cached_signatures(sp.advance.py_func)) == 1


def test_the_loop_around_jitted_functions_holds_none_of_the_step():
    """The loop compiled for each signature of f and h inlined the whole step (25 s of compiling for every
    new signature on a 2-core machine): it calls the step's kernel, compiled once, through its address, so
    its code defines no function of the step's modules (``_slr``, ``_step``). Compiled here anew, uncached,
    so that numba shows its code."""
    import re

    f, h = numba.njit(lambda x: x * 1.0), numba.njit(lambda x: np.sin(x[:1]))
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0)
    gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.ones(5), method="ukf", engine="numba")
    key = sp._loop_key(*sp._jitted_signatures(model, gf.Gaussian([0.0, 0.0], np.eye(2)), None), False, False)
    sig = sp._LOOPS[key].signatures[0]
    fresh = numba.njit(sig, cache=False, nogil=True, error_model="numpy")(sp.run)
    defined = re.findall(r'^define [^@]*@"?([^"(\s]+)', fresh.inspect_llvm(sig), re.M)
    assert any("12sigma_points3run" in name for name in defined), defined
    assert not [name for name in defined if re.search(r"8_kernels(4_slr|5_step)", name)], defined


# ---------------------------------------------------------------------------
# Errors: the readable path's messages, with the step
# ---------------------------------------------------------------------------


def same_error(exc_type, model, *args, match, **kwargs):
    """Both engines raise `exc_type` with the same message, which matches `match`.

    For jitted f and h, the error is raised from the compiled loop.
    """
    with pytest.raises(exc_type, match=match) as got:
        gf.filter(model, *args, engine="numba", **kwargs)
    expected = "compiled" if numba.extending.is_jitted(model.f) and numba.extending.is_jitted(model.h) else "python"
    assert sp.execution_mode(model, args[0]) == expected
    with pytest.raises(exc_type) as want:
        gf.filter(model, *args, engine="python", **kwargs)
    assert str(got.value) == str(want.value)


def f_nan_later(x):
    return x + (np.nan if x[0] > 0.5 else 0.1)


def f_nan_later_vec(X):
    return X + np.where(X[:, :1] > 0.5, np.nan, 0.1)


f_nan_later_jit = numba.njit(cache=True)(f_nan_later)


def h_wrong_shape(x):
    return np.ones(3)


h_wrong_shape_jit = numba.njit(cache=True)(h_wrong_shape)


def h_raises_later(x):
    if x[0] > 0.35:
        raise ValueError("too far")
    return x[:1].copy()


h_raises_later_jit = numba.njit(cache=True)(h_raises_later)


def first(x):
    return x[:1].copy()


first_jit = numba.njit(cache=True)(first)


def identity(x):
    return x.copy()


identity_jit = numba.njit(cache=True)(identity)


@pytest.mark.parametrize("mode", MODES)
def test_f_returning_nan_names_f_and_the_step(mode):
    f, h = {"plain": (f_nan_later, first), "vectorized": (f_nan_later_vec, lambda X: X[:, :1]),
            "jitted": (f_nan_later_jit, first_jit)}[mode]
    model = gf.NonlinearModel(f, h, np.eye(2) * 1e-6, 1.0, vectorized=mode == "vectorized")
    shape = r"\(4, 2\)" if mode == "vectorized" else r"\(2,\)"  # ckf: 2n = 4 points
    same_error(ModelFunctionError, model, gf.Gaussian([0.0, 0.0], 1e-6 * np.eye(2)), np.zeros(10), method="ckf",
               match=rf"at step \d+: `f` returned a non-finite value \(NaN or inf\) for an input of shape {shape}")


@pytest.mark.parametrize("mode", MODES)
def test_wrong_output_shape_names_the_function(mode):
    h = {"plain": h_wrong_shape, "vectorized": lambda X: np.ones((len(X), 3)), "jitted": h_wrong_shape_jit}[mode]
    f = {"plain": identity, "vectorized": lambda X: X, "jitted": identity_jit}[mode]
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0, vectorized=mode == "vectorized")
    given_shape, want = (r"\(5, 2\)", r"\(5, 1\)") if mode == "vectorized" else (r"\(2,\)", r"\(1,\)")
    got = r"\(5, 3\)" if mode == "vectorized" else r"\(3,\)"
    same_error(ModelFunctionError, model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros(3), method="ukf",
               match=rf"at step 0: `h` must return shape {want} for an input of shape {given_shape}, because `R` is "
                     rf"1 × 1; got shape {got}")


@pytest.mark.parametrize("mode", ["plain", "jitted"])
def test_raising_function_names_it_and_the_step(mode):
    f, h = (lambda x: x + 0.1, h_raises_later) if mode == "plain" else (
        numba.njit(cache=True)(lambda x: x + 0.1), h_raises_later_jit)
    model = gf.NonlinearModel(f, h, np.eye(2) * 1e-8, 1.0)
    same_error(ModelFunctionError, model, gf.Gaussian([0.0, 0.0], 1e-8 * np.eye(2)), np.zeros(6), method="ukf",
               match=r"at step [1-9]: `h` raised ValueError on an input of shape \(2,\): too far")


def test_wrong_type_from_a_plain_function():
    model = gf.NonlinearModel(lambda x: "x", first, np.eye(2), 1.0)
    same_error(ModelFunctionError, model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros(3), method="ukf",
               match=r"at step 0: `f` must return an array of real numbers; got str 'x'")


def test_a_boolean_output_at_one_point_is_refused_on_both_engines():
    """Stacked with the float outputs of the other points, it would have been read as numbers (0 and 1)."""
    h = lambda x: x[:1] > 0.5 if x[0] > 0.5 else x[:1].copy()  # noqa: E731
    model = gf.NonlinearModel(identity, h, np.eye(2), 1.0)
    same_error(ModelFunctionError, model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros(3), method="ukf",
               match=r"at step 0: `h` must return an array of real numbers; got boolean values")


def constant(x):
    return np.array([0.0, 1.0])


constant_jit = numba.njit(cache=True)(constant)


@pytest.mark.parametrize("mode", ["plain", "jitted"])
def test_innovation_covariance_not_positive_definite(mode):
    f, h = (identity, constant) if mode == "plain" else (identity_jit, constant_jit)
    model = gf.NonlinearModel(f, h, np.eye(2), np.diag([1.0, 0.0]))  # h ignores x: S = R, singular
    same_error(np.linalg.LinAlgError, model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.ones((2, 2)),
               method="ckf", match=r"at step 0: the innovation covariance S = H P Hᵀ \+ R is not positive "
                                   r"definite, so it cannot be factorised: \[\[1\., 0\.\],\s*\[0\., 0\.\]\]")
    # with the first component missing, the observed block is the 1 x 1 zero
    same_error(np.linalg.LinAlgError, model, gf.Gaussian([0.0, 0.0], np.eye(2)), [[np.nan, 1.0]],
               method="ckf", match=r"at step 0: .* factorised: \[\[0\.\]\]")


def turning_f(x):
    return np.array([x[0] + 0.1 * x[2], x[1] + 0.1 * x[3], x[2] * np.cos(0.2 * x[3]), x[3] + 0.05 * np.sin(x[0])])


def range_bearing(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def test_a_prediction_made_indefinite_by_a_negative_weight_says_how_to_keep_the_weights_positive():
    """kappa = -3.5 on four states weighs the centre point -7: the regression's residual spread is indefinite,
    and so is the prediction (an eigenvalue of -1.1e-4). The error named the prediction, not the cause."""
    model = gf.NonlinearModel(turning_f, range_bearing, 4.4e-6 * np.eye(4), np.diag([0.059, 0.00059]),
                              measurement_angles=[1])
    zs = range_bearing(np.array([10.0, 5.0]))[None] + np.zeros((3, 2))
    same_error(np.linalg.LinAlgError, model, gf.Gaussian([10.0, 5.0, 1.0, 0.5], 30.0 * np.eye(4)), zs,
               method="ukf", kappa=-3.5, check="off",
               match=r"at step 1: the predicted covariance is not positive semi-definite .* weighs a point "
                     r"negatively \(-7\).* kappa >= 0 .*\(method='ckf'\)")


def test_singular_prior_without_noise_fails_like_the_readable_path():
    """Singular covariances take the Python mode's square root; then S = 0 cannot be factorised."""
    model = gf.NonlinearModel(identity_jit, first_jit, np.zeros((2, 2)), 0.0)
    prior = gf.Gaussian([0.0, 0.0], np.diag([0.0, 1.0]))
    with pytest.raises(np.linalg.LinAlgError) as got:
        gf.filter(model, prior, np.ones(2), method="ukf", engine="numba")
    with pytest.raises(np.linalg.LinAlgError) as want:
        gf.filter(model, prior, np.ones(2), method="ukf", engine="python")
    assert str(got.value) == str(want.value)
    assert str(got.value).startswith("at step 0: the innovation covariance S = H P Hᵀ + R is not positive definite")


def test_scalar_outputs_from_plain_functions_are_accepted():
    model = gf.NonlinearModel(lambda x: 0.9 * x, lambda x: float(np.sin(x[0])), 0.01, 0.1)
    res, ref, _ = both(gf.smooth, model, gf.Gaussian(0.5, 1.0), np.sin(np.linspace(0, 1, 6)), method="ukf")
    assert_same(res, ref)


def f_huge(x):
    return np.array([1e120 * x[0], x[1]])


def f_huge_vec(X):
    return X * np.array([1e120, 1.0])


f_huge_jit = numba.njit(cache=True)(f_huge)


def second(x):
    return x[1:].copy()


second_jit = numba.njit(cache=True)(second)


@pytest.mark.parametrize("mode", MODES)
def test_overflow_names_the_step(mode):
    """x0 is not measured and grows by 1e120 a step: its variance is 1e240, then inf. f's values stay finite."""
    f, h = {"plain": (f_huge, second), "vectorized": (f_huge_vec, lambda X: X[:, 1:]),
            "jitted": (f_huge_jit, second_jit)}[mode]
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0, vectorized=mode == "vectorized")
    for method in ("ukf", "ckf"):
        same_error(FloatingPointError, model, gf.Gaussian([1.0, 0.0], np.eye(2)), np.zeros(4), method=method,
                   match=r"^at step 1: the predicted mean or covariance is not finite \(inf or NaN\)")
    with pytest.raises(FloatingPointError, match=r"^at step 1: the predicted"):
        gf.smooth(model, gf.Gaussian([1.0, 0.0], np.eye(2)), np.zeros(4), method="ukf", engine="numba")


@pytest.mark.parametrize("mode", ["plain", "jitted"])
def test_overflow_of_the_log_likelihood_names_the_step(mode):
    f, h = (identity, first) if mode == "plain" else (identity_jit, first_jit)
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0)
    same_error(FloatingPointError, model, gf.Gaussian([0.0, 0.0], np.eye(2)), [0.0, 1e300, 0.0], method="ukf",
               match=r"^at step 1: the filtered mean, covariance or log-likelihood is not finite")


def h_huge(x):
    return 1e160 * x[:1]


def test_an_innovation_covariance_that_overflows_is_an_overflow():
    """h = 1e160 x: S overflows to inf - inf = NaN. An overflow on both engines, as the EKF's and the linear
    filter's (it was a LinAlgError calling S not positive definite)."""
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    prior, zs = gf.Gaussian([0.1, 0.2], 0.01 * np.eye(2)), [1.0, 5.0]
    model = gf.NonlinearModel(identity, h_huge, 0.1 * np.eye(2), 0.5)
    match = r"^at step 0: the filtered mean, covariance or log-likelihood is not finite"
    same_error(FloatingPointError, model, prior, zs, method="ukf", match=match)
    with pytest.raises(FloatingPointError, match=match):
        gf.filter(model, prior, zs, method="ekf")
    linear = gf.LinearModel(F=F, H=[1e160, 0.0], Q=0.1 * np.eye(2), R=0.5)
    for engine in ("python", "numba"):
        with pytest.raises(FloatingPointError, match=match):
            gf.filter(linear, prior, zs, engine=engine)


h_complex_jit = numba.njit(cache=True)(lambda x: x[:1] + 0j)
h_bool_jit = numba.njit(cache=True)(lambda x: x[:1] > 0.0)


@pytest.mark.parametrize("h, what", [(lambda x: x[:1] + 0j, "complex"), (h_complex_jit, "complex"),
                                     (lambda x: x[:1] > 0.0, "boolean"), (h_bool_jit, "boolean")],
                         ids=["complex", "complex-jitted", "bool", "bool-jitted"])
def test_complex_or_boolean_outputs_are_refused(h, what):
    f = identity_jit if numba.extending.is_jitted(h) else identity
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0)
    with pytest.raises(ModelFunctionError, match=rf"^at step 0: `h` must return an array of real numbers; got {what}"):
        gf.filter(model, gf.Gaussian([0.5, 0.0], np.eye(2)), np.zeros(3), method="ukf", engine="numba")
    assert sp.execution_mode(model, gf.Gaussian([0.5, 0.0], np.eye(2))) == "python"  # such an h does not fit
    with pytest.raises(ModelFunctionError, match=rf"^at step 0: `h` must return an array of real numbers; got {what}"):
        gf.filter(model, gf.Gaussian([0.5, 0.0], np.eye(2)), np.zeros(3), method="ukf", engine="python")
