"""The benchmark workloads: data, models and one adapter per library.

Every adapter is a function ``run(n) -> dict`` that processes the first `n`
items of the workload's input (steps of one series for W1, W3 and W4,
series for W2) and returns the arrays to compare with gaussfuse:
``{"means": (.., n_x), "covs": (.., n_x, n_x)}`` (filtered for W1, W2 and
W4, smoothed for W3), all in gaussfuse's layout.

Conventions (see README.md): gaussfuse and filterpy start from the belief
one step *before* the first measurement (predict, then update); pykalman,
simdkalman and statsmodels start from the belief *at* the first
measurement's time before its update, so they are given
``m1 = F m0, P1 = F P0 Fᵀ + Q``, gaussfuse's first prediction.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

import gaussfuse as gf

PEERS = ("filterpy", "pykalman", "simdkalman", "statsmodels")


def peer_available(name: str, skip: set[str]) -> tuple[bool, str]:
    """Whether a peer library can be used, and why not."""
    if name in skip:
        return False, "left out with --skip"
    try:
        importlib.import_module(name)
    except ImportError as exc:
        return False, f"not installed ({exc})"
    return True, ""


# ---------------------------------------------------------------------------
# Sizes
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Sizes:
    T_long: int          # W1/W3 series length
    prefix_slow: int     # pure-Python peers on W1/W3 (pykalman, gaussfuse python)
    prefix_medium: int   # filterpy, simdkalman (one series) on W1/W3
    N_batch: int         # W2 series
    T_batch: int         # W2 steps per series
    N_subset: int        # W2 series for the per-series loops (filterpy, statsmodels, python)
    T_ukf: int           # W4 steps
    T_large: dict        # W5 steps of the series of each state dimension n
    prefix_large: int    # W5 steps for the readable path
    warmup: int          # warm-up input size (steps, or series for W2)
    repeats: int         # best of this many timed runs ...
    budget: float        # ... unless the runs so far took this many seconds


FULL = Sizes(T_long=200_000, prefix_slow=20_000, prefix_medium=50_000,
             N_batch=2_000, T_batch=200, N_subset=200, T_ukf=5_000,
             T_large={2: 20_000, 8: 10_000, 32: 3_000, 64: 1_000, 128: 500}, prefix_large=500,
             warmup=20, repeats=5, budget=8.0)
QUICK = Sizes(T_long=3_000, prefix_slow=300, prefix_medium=1_000,
              N_batch=40, T_batch=50, N_subset=8, T_ukf=200,
              T_large={2: 200, 8: 200, 32: 50, 64: 20, 128: 10}, prefix_large=10,
              warmup=5, repeats=2, budget=0.5)


# ---------------------------------------------------------------------------
# Entries and workloads
# ---------------------------------------------------------------------------


@dataclass
class Entry:
    """One row of the table: a library (or engine) run on the workload.

    `n` is how many items (steps, or series for W2) are timed; `steps` the
    steps processed per call. `goal` is the ratio gaussfuse must reach
    against this entry (peer rows in W1-W3) or this entry against the
    workload's `peer` (gaussfuse rows in W4); `goal_group` names entries of
    which only the fastest counts for the goal (two ways to drive filterpy).
    """

    label: str
    library: str
    run: Callable[[int], dict]
    n: int
    steps: int
    note: str = ""
    goal: float | None = None
    goal_group: str | None = None
    compiled: bool = False   # a numba entry: its warm-up is compilation
    mode: str | None = None  # sigma-point engine: the execution mode it must report


@dataclass
class Workload:
    key: str
    title: str
    description: str
    compare: str                      # "filtered" or "smoothed"
    entries: list[Entry]
    reference: Callable[[int], dict]  # gaussfuse on the first n items
    reference_label: str              # the row that *is* the reference
    primary: str                      # gaussfuse row the peers are measured against (W1-W3)
    peer: str | None = None           # W4: the peer row gaussfuse rows are measured against
    notes: list[str] = field(default_factory=list)


def _cached(fn):
    cache = {}

    def wrapper(n):
        if n not in cache:
            cache[n] = fn(n)
        return cache[n]

    wrapper.cache = cache  # the runner seeds it with the reference row's own output
    return wrapper


# ---------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------


def simulate_linear(F, H, Q, R, x0, T, rng):
    """A trajectory and measurements of a linear-Gaussian model (one series)."""
    n = F.shape[0]
    W = rng.standard_normal((T, n)) @ np.linalg.cholesky(Q).T
    xs = np.empty((T, n))
    x = np.asarray(x0, float)
    for k in range(T):
        x = F @ x + W[k]
        xs[k] = x
    V = rng.standard_normal((T, H.shape[0])) @ np.linalg.cholesky(R).T
    return xs, xs @ H.T + V


def simulate_linear_batch(F, H, Q, R, x0, N, T, rng):
    """N independent series at once: states (N, T, n), measurements (N, T, m)."""
    n = F.shape[0]
    W = rng.standard_normal((N, T, n)) @ np.linalg.cholesky(Q).T
    xs = np.empty((N, T, n))
    x = np.broadcast_to(np.asarray(x0, float), (N, n))
    for k in range(T):
        x = x @ F.T + W[:, k]
        xs[:, k] = x
    V = rng.standard_normal((N, T, H.shape[0])) @ np.linalg.cholesky(R).T
    return xs, xs @ H.T + V


def first_prediction(model, prior):
    """gaussfuse's first prediction: the initial belief for pykalman, simdkalman, statsmodels."""
    F, Q = model.F, model.Q
    return F @ prior.mean, F @ prior.cov @ F.T + Q


# ---------------------------------------------------------------------------
# Linear adapters (W1, W2, W3)
# ---------------------------------------------------------------------------


def gaussfuse_linear(model, prior, zs, engine, smooth=False, **options):
    """``run(n)``: gaussfuse's filter (or smoother) on the first n steps; `options` as form= or steady=."""
    def run(n):
        if smooth:
            r = gf.smooth(model, prior, zs[:n], engine=engine, **options)
        else:
            r = gf.filter(model, prior, zs[:n], engine=engine, **options)
        return {"means": r.means, "covs": r.covs}
    return run


def _per_series(one, zs):
    """``run(n)`` for a library that filters one series at a time: `one(z)` -> (means, covs).

    A (T, m) input is cut to its first n steps; an (N, T, m) one to its first
    n series, looped over.
    """
    def run(n):
        if zs.ndim == 3:
            out = [one(z) for z in zs[:n]]
            return {"means": np.stack([o[0] for o in out]), "covs": np.stack([o[1] for o in out])}
        mu, cov = one(zs[:n])
        return {"means": mu, "covs": cov}
    return run


def filterpy_batch(model, prior, zs, smooth=False):
    """filterpy KalmanFilter.batch_filter (+ rts_smoother); (T, m) or a loop over (N, T, m)."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=model.n, dim_z=model.m)
    kf.F, kf.H, kf.Q, kf.R = model.F.copy(), model.H.copy(), model.Q.copy(), model.R.copy()

    def one(z):
        kf.x, kf.P = prior.mean.copy(), prior.cov.copy()
        mu, cov, _, _ = kf.batch_filter(z)
        if smooth:
            mu, cov, _, _ = kf.rts_smoother(mu, cov)
        return mu, cov

    return _per_series(one, zs)


def filterpy_functions(model, prior, zs):
    """filterpy's functional ``predict`` / ``update`` in a Python loop (filter only)."""
    from filterpy.kalman import predict, update

    F, H, Q, R = model.F, model.H, model.Q, model.R

    def one(z):
        T = z.shape[0]
        means, covs = np.empty((T, model.n)), np.empty((T, model.n, model.n))
        x, P = prior.mean.copy(), prior.cov.copy()
        for k in range(T):
            x, P = predict(x, P, F, Q)
            x, P = update(x, P, z[k], R, H)
            means[k], covs[k] = x, P
        return means, covs

    return _per_series(one, zs)


def pykalman_run(model, prior, zs, smooth=False):
    from pykalman import KalmanFilter

    m1, P1 = first_prediction(model, prior)
    kf = KalmanFilter(transition_matrices=model.F, observation_matrices=model.H,
                      transition_covariance=model.Q, observation_covariance=model.R,
                      initial_state_mean=m1, initial_state_covariance=P1)

    def run(n):
        mu, cov = (kf.smooth if smooth else kf.filter)(zs[:n])
        return {"means": mu, "covs": cov}
    return run


def simdkalman_run(model, prior, zs, smooth=False):
    """simdkalman: vectorised over series; one series is a batch of one, (1, T, m)."""
    import simdkalman

    m1, P1 = first_prediction(model, prior)
    kf = simdkalman.KalmanFilter(state_transition=model.F, process_noise=model.Q,
                                 observation_model=model.H, observation_noise=model.R)
    single = zs.ndim == 2

    def run(n):
        data = zs[None, :n] if single else zs[:n]
        if model.m == 1:
            data = data[..., 0]  # (N, T): simdkalman's layout for scalar measurements
        out = kf.compute(data, 0, initial_value=m1, initial_covariance=P1,
                         smoothed=smooth, filtered=not smooth, observations=False)
        states = (out.smoothed if smooth else out.filtered).states
        mu, cov = states.mean, states.cov
        return {"means": mu[0] if single else mu, "covs": cov[0] if single else cov}
    return run


def statsmodels_run(model, prior, zs, smooth=False, tolerance=None):
    """statsmodels' Cython Kalman filter / smoother, storing everything (conserve_memory=0).

    `tolerance` is statsmodels' steady-state test (None: its default, 1e-19).
    For a time-invariant model without missing data, statsmodels stops
    propagating the covariance once the squared Frobenius norm of the change
    in the predicted covariance falls below it, and reuses the gain from then
    on; 0 turns that off, so every step is the full filter as gaussfuse's.
    """
    from statsmodels.tsa.statespace.kalman_smoother import (
        SMOOTHER_STATE,
        SMOOTHER_STATE_COV,
        KalmanSmoother,
    )

    m1, P1 = first_prediction(model, prior)
    n_x, m = model.n, model.m

    def one(z):
        # A new KalmanSmoother per series: re-binding data to one object reuses its
        # compiled filter, which keeps the old data (wrong results, or an IndexError
        # when the length changes), so statsmodels' own models build one per dataset.
        options = {} if tolerance is None else {"tolerance": tolerance}
        kf = KalmanSmoother(k_endog=m, k_states=n_x, k_posdef=n_x, conserve_memory=0,
                            smoother_output=SMOOTHER_STATE | SMOOTHER_STATE_COV, **options)
        kf.bind(np.asfortranarray(z.T))
        kf["design"], kf["obs_cov"] = model.H, model.R
        kf["transition"], kf["selection"], kf["state_cov"] = model.F, np.eye(n_x), model.Q
        kf.initialize_known(m1, P1)
        if smooth:
            r = kf.smooth()
            return r.smoothed_state.T, np.moveaxis(r.smoothed_state_cov, -1, 0)
        r = kf.filter()
        return r.filtered_state.T, np.moveaxis(r.filtered_state_cov, -1, 0)

    return _per_series(one, zs)


# ---------------------------------------------------------------------------
# W1, W3: one long 2-D constant-velocity series; W2: many short 1-D series
# ---------------------------------------------------------------------------


def long_series(T: int):
    model = gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], 4.0 * np.eye(4))
    _, zs = simulate_linear(model.F, model.H, model.Q, model.R, prior.mean, T,
                            np.random.default_rng(20240601))
    return model, prior, zs


def w1_w3(sizes: Sizes, avail: dict[str, bool], engine: str, smooth: bool) -> Workload:
    model, prior, zs = long_series(sizes.T_long)
    T = sizes.T_long
    fast = engine == "numba"
    E = []
    nG = T if fast else min(sizes.prefix_slow, T)  # without numba, the python engine on a prefix
    E.append(Entry(f"gaussfuse engine=\"{engine}\"", "gaussfuse",
                   gaussfuse_linear(model, prior, zs, engine, smooth), nG, nG, compiled=fast,
                   note="" if fast else "prefix"))
    if fast:
        nP = min(sizes.prefix_slow, T)
        E.append(Entry("gaussfuse engine=\"python\"", "gaussfuse",
                       gaussfuse_linear(model, prior, zs, "python", smooth), nP, nP,
                       note="prefix"))
        E.append(Entry("gaussfuse engine=\"python\", form=\"sqrt\" (square-root)", "gaussfuse",
                       gaussfuse_linear(model, prior, zs, "python", smooth, form="sqrt"), nP, nP,
                       note="prefix"))
        if not smooth:
            E.append(Entry("gaussfuse engine=\"numba\", steady=True", "gaussfuse",
                           gaussfuse_linear(model, prior, zs, "numba", steady=True), T, T))
            E.append(Entry("gaussfuse engine=\"numba\", form=\"sqrt\" (square-root)", "gaussfuse",
                           gaussfuse_linear(model, prior, zs, "numba", form="sqrt"), T, T, compiled=True))
    if avail["filterpy"]:
        nM = min(sizes.prefix_medium, T)
        label = "filterpy batch_filter + rts_smoother" if smooth else "filterpy KalmanFilter.batch_filter"
        E.append(Entry(label, "filterpy", filterpy_batch(model, prior, zs, smooth), nM, nM,
                       note="prefix", goal=30.0, goal_group="filterpy"))
        if not smooth:
            E.append(Entry("filterpy predict()/update() functions", "filterpy",
                           filterpy_functions(model, prior, zs), nM, nM,
                           note="prefix", goal=30.0, goal_group="filterpy"))
    if avail["pykalman"]:
        nP = min(sizes.prefix_slow, T)
        E.append(Entry(f"pykalman KalmanFilter.{'smooth' if smooth else 'filter'}", "pykalman",
                       pykalman_run(model, prior, zs, smooth), nP, nP, note="prefix"))
    if avail["simdkalman"]:
        nM = min(sizes.prefix_medium, T)
        E.append(Entry(f"simdkalman compute({'smoothed' if smooth else 'filtered'}), one series",
                       "simdkalman", simdkalman_run(model, prior, zs, smooth), nM, nM, note="prefix"))
    if avail["statsmodels"]:
        E.append(Entry(f"statsmodels KalmanSmoother.{'smooth' if smooth else 'filter'} (Cython)",
                       "statsmodels", statsmodels_run(model, prior, zs, smooth), T, T,
                       goal=None if smooth else 3.0))
    reference = _cached(gaussfuse_linear(model, prior, zs, engine, smooth))
    if smooth:
        return Workload(
            "W3", "filter + RTS smoother, one long series",
            f"2-D constant velocity (4 states, 2 position measurements), {T:,} steps, "
            "filter and Rauch-Tung-Striebel smoother; compared: smoothed means and covariances",
            "smoothed", E, reference, E[0].label, E[0].label)
    return Workload(
        "W1", "filter, one long series",
        f"2-D constant velocity (4 states, 2 position measurements), {T:,} steps, filter only; "
        "compared: filtered means and covariances",
        "filtered", E, reference, E[0].label, E[0].label)


def w2(sizes: Sizes, avail: dict[str, bool], engine: str) -> Workload:
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0, dim=1)
    prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    N, T = sizes.N_batch, sizes.T_batch
    _, zs = simulate_linear_batch(model.F, model.H, model.Q, model.R, prior.mean, N, T,
                                  np.random.default_rng(7))
    nS = min(sizes.N_subset, N)
    fast = engine == "numba"
    nG = N if fast else nS  # without numba, the python engine on a subset
    E = [Entry(f"gaussfuse engine=\"{engine}\", zs ({nG}, {T}, 1)", "gaussfuse",
               gaussfuse_linear(model, prior, zs, engine), nG, nG * T, compiled=fast,
               note="" if fast else f"{nS} series")]
    if fast:
        E.append(Entry("gaussfuse engine=\"python\"", "gaussfuse",
                       gaussfuse_linear(model, prior, zs, "python"), nS, nS * T,
                       note=f"{nS} series"))
    if avail["simdkalman"]:
        E.append(Entry(f"simdkalman compute(filtered), data ({N}, {T})", "simdkalman",
                       simdkalman_run(model, prior, zs), N, N * T, goal=5.0))
    if avail["filterpy"]:
        E.append(Entry("filterpy batch_filter, loop over series", "filterpy",
                       filterpy_batch(model, prior, zs), nS, nS * T, note=f"{nS} series"))
        E.append(Entry("filterpy predict()/update(), loop over series", "filterpy",
                       filterpy_functions(model, prior, zs), nS, nS * T, note=f"{nS} series"))
    if avail["statsmodels"]:
        E.append(Entry("statsmodels KalmanSmoother.filter, loop over series", "statsmodels",
                       statsmodels_run(model, prior, zs), nS, nS * T, note=f"{nS} series"))
    reference = _cached(gaussfuse_linear(model, prior, zs, engine))
    return Workload(
        "W2", "filter, many short series",
        f"{N:,} series x {T} steps, 1-D constant velocity (2 states, 1 measurement), filter only; "
        "steps/s counts series-steps; compared: filtered means and covariances",
        "filtered", E, reference, E[0].label, E[0].label)


# ---------------------------------------------------------------------------
# W4: unscented Kalman filter, range-bearing sensor
# ---------------------------------------------------------------------------

UKF_DT, UKF_Q = 0.1, 0.05
SIGMA_RANGE, SIGMA_BEARING = 0.5, 0.005
_F4 = gf.constant_velocity(dt=UKF_DT, q=UKF_Q, r=1.0, dim=2).F


def f_plain(x):
    return _F4 @ x


def h_plain(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def f_vec(X):
    return X @ _F4.T


def h_vec(X):
    return np.stack([np.hypot(X[:, 0], X[:, 1]), np.arctan2(X[:, 1], X[:, 0])], axis=1)


def fx_filterpy(x, dt):
    return _F4 @ x


try:  # numba is a dependency of gaussfuse, but the python-engine rows do not need it
    import numba
except ImportError:  # pragma: no cover
    numba = None

if numba is not None:
    @numba.njit(cache=True)
    def f_nb(x):
        out = np.empty(4)
        out[0] = x[0] + UKF_DT * x[2]
        out[1] = x[1] + UKF_DT * x[3]
        out[2] = x[2]
        out[3] = x[3]
        return out

    @numba.njit(cache=True)
    def h_nb(x):
        out = np.empty(2)
        out[0] = math.hypot(x[0], x[1])
        out[1] = math.atan2(x[1], x[0])
        return out

    @numba.njit(cache=True)
    def f_nb_vec(X):
        out = np.empty_like(X)
        for i in range(X.shape[0]):
            out[i, 0] = X[i, 0] + UKF_DT * X[i, 2]
            out[i, 1] = X[i, 1] + UKF_DT * X[i, 3]
            out[i, 2] = X[i, 2]
            out[i, 3] = X[i, 3]
        return out

    @numba.njit(cache=True)
    def h_nb_vec(X):
        out = np.empty((X.shape[0], 2))
        for i in range(X.shape[0]):
            out[i, 0] = math.hypot(X[i, 0], X[i, 1])
            out[i, 1] = math.atan2(X[i, 1], X[i, 0])
        return out


def w4_problem(T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, gf.Gaussian, np.ndarray]:
    """W4's F, Q, R, prior and T measurements (also ``ukf_floor.py``'s)."""
    base = gf.constant_velocity(dt=UKF_DT, q=UKF_Q, r=1.0, dim=2)
    F, Q = base.F, base.Q
    R = np.diag([SIGMA_RANGE**2, SIGMA_BEARING**2])
    rng = np.random.default_rng(11)
    x0 = np.array([300.0, 100.0, 5.0, 3.0])
    xs, _ = simulate_linear(F, np.eye(4)[:2], Q, np.eye(2), x0, T, rng)
    truth = h_vec(xs)
    assert truth[:, 0].min() > 50 and np.abs(truth[:, 1]).max() < 2.5, "track must stay clear of ±180°"
    zs = truth + rng.standard_normal((T, 2)) * [SIGMA_RANGE, SIGMA_BEARING]
    prior = gf.Gaussian(x0 + [2.0, -2.0, 0.5, -0.5], np.diag([4.0, 4.0, 1.0, 1.0]))
    return F, Q, R, prior, zs


def w4(sizes: Sizes, avail: dict[str, bool], engine: str) -> Workload:
    T = sizes.T_ukf
    _, Q, R, prior, zs = w4_problem(T)
    opts = dict(method="ukf", alpha=1.0, beta=0.0, kappa=-1.0)
    plain = gf.NonlinearModel(f_plain, h_plain, Q, R)
    vec = gf.NonlinearModel(f_vec, h_vec, Q, R, vectorized=True)

    def gaussfuse_ukf(model, eng, form="cov"):
        def run(n):
            r = gf.filter(model, prior, zs[:n], engine=eng, form=form, **opts)
            return {"means": r.means, "covs": r.covs}

        def actual_mode():  # the sigma-point engine's mode for this model ("compiled" or "python")
            from gaussfuse._kernels.sigma_points import execution_mode
            return execution_mode(model, prior)

        run.actual_mode = actual_mode
        return run

    E = []
    if avail["filterpy"]:
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

        points = MerweScaledSigmaPoints(n=4, alpha=1.0, beta=0.0, kappa=-1.0)
        ukf = UnscentedKalmanFilter(dim_x=4, dim_z=2, dt=UKF_DT, hx=h_plain, fx=fx_filterpy,
                                    points=points)
        ukf.Q, ukf.R = Q.copy(), R.copy()

        def filterpy_ukf(n):
            ukf.x, ukf.P = prior.mean.copy(), prior.cov.copy()
            mu, cov = ukf.batch_filter(zs[:n])
            return {"means": mu, "covs": cov}

        E.append(Entry("filterpy UnscentedKalmanFilter.batch_filter", "filterpy", filterpy_ukf, T, T))
    if engine == "numba":
        compiled = gf.NonlinearModel(f_nb, h_nb, Q, R)
        E.append(Entry("gaussfuse engine=\"numba\", plain Python f, h", "gaussfuse",
                       gaussfuse_ukf(plain, "numba"), T, T, goal=3.0, compiled=True,
                       mode="python"))
        E.append(Entry("gaussfuse engine=\"numba\", vectorized f, h", "gaussfuse",
                       gaussfuse_ukf(vec, "numba"), T, T, goal=10.0, compiled=True,
                       mode="python"))
        E.append(Entry("gaussfuse engine=\"numba\", numba.njit f, h", "gaussfuse",
                       gaussfuse_ukf(compiled, "numba"), T, T, goal=100.0, compiled=True,
                       mode="compiled"))
        compiled_vec = gf.NonlinearModel(f_nb_vec, h_nb_vec, Q, R, vectorized=True)
        E.append(Entry("gaussfuse engine=\"numba\", numba.njit vectorized f, h", "gaussfuse",
                       gaussfuse_ukf(compiled_vec, "numba"), T, T, goal=100.0, compiled=True,
                       mode="compiled"))
        # the compiled square-root UKF (a downdate every step), against the covariance form's rows above
        E.append(Entry("gaussfuse engine=\"numba\", form=\"sqrt\", plain Python f, h", "gaussfuse",
                       gaussfuse_ukf(plain, "numba", "sqrt"), T, T, compiled=True, mode="python"))
        E.append(Entry("gaussfuse engine=\"numba\", form=\"sqrt\", numba.njit f, h", "gaussfuse",
                       gaussfuse_ukf(compiled, "numba", "sqrt"), T, T, compiled=True, mode="compiled"))
    E.append(Entry("gaussfuse engine=\"python\", plain Python f, h", "gaussfuse",
                   gaussfuse_ukf(plain, "python"), T, T))
    E.append(Entry("gaussfuse engine=\"python\", vectorized f, h", "gaussfuse",
                   gaussfuse_ukf(vec, "python"), T, T))
    # the square-root UKF: kappa = -1 gives the centre point a negative weight, so each step downdates
    E.append(Entry("gaussfuse engine=\"python\", form=\"sqrt\", plain Python f, h", "gaussfuse",
                   gaussfuse_ukf(plain, "python", "sqrt"), T, T))
    E.append(Entry("gaussfuse engine=\"python\", form=\"sqrt\", vectorized f, h", "gaussfuse",
                   gaussfuse_ukf(vec, "python", "sqrt"), T, T))
    reference = _cached(gaussfuse_ukf(plain, "python"))
    return Workload(
        "W4", "unscented Kalman filter, range-bearing",
        f"4-state constant velocity, h = [hypot(px, py), atan2(py, px)], R = diag({SIGMA_RANGE}², "
        f"{SIGMA_BEARING}²), {T:,} steps, filter only; unscented points alpha=1, beta=0, kappa=-1 "
        "(filterpy MerweScaledSigmaPoints(4, 1, 0, -1)); the track keeps bearings within ±2.5 rad, "
        "so no angle wrapping is needed; compared: filtered means and covariances",
        "filtered", E, reference, "gaussfuse engine=\"python\", plain Python f, h",
        "gaussfuse engine=\"python\", plain Python f, h",
        peer="filterpy UnscentedKalmanFilter.batch_filter" if avail["filterpy"] else None)


# ---------------------------------------------------------------------------
# W5: large states, filter
# ---------------------------------------------------------------------------

W5_DIMENSIONS = (2, 8, 32, 64, 128)


def random_linear_model(n: int, rng: np.random.Generator) -> gf.LinearModel:
    """n states, m = n/2 measurements: a random stable F, random SPD Q and R, a random H."""
    m = max(n // 2, 1)
    A = rng.standard_normal((n, n))
    F = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A)))  # spectral radius 0.95
    B = rng.standard_normal((n, n))
    C = rng.standard_normal((m, m))
    Q = B @ B.T / n + 0.1 * np.eye(n)
    R = C @ C.T / m + 0.1 * np.eye(m)
    H = rng.standard_normal((m, n)) / np.sqrt(n)
    return gf.LinearModel(F, H, Q, R)


def w5(sizes: Sizes, avail: dict[str, bool], engine: str) -> list[Workload]:
    """One workload per state dimension n: the same model, prior and series for every library."""
    out = []
    for n in W5_DIMENSIONS:
        rng = np.random.default_rng(500 + n)
        model = random_linear_model(n, rng)
        prior = gf.Gaussian(np.zeros(n), np.eye(n))
        T = sizes.T_large[n]
        _, zs = simulate_linear(model.F, model.H, model.Q, model.R, prior.mean, T, rng)
        fast = engine == "numba"
        nP = min(sizes.prefix_large, T)
        E = [Entry(f"gaussfuse engine=\"{engine}\"", "gaussfuse", gaussfuse_linear(model, prior, zs, engine),
                   T if fast else nP, T if fast else nP, compiled=fast, note="" if fast else "prefix")]
        if fast:
            E.append(Entry("gaussfuse engine=\"auto\"", "gaussfuse", gaussfuse_linear(model, prior, zs, "auto"), T, T))
            E.append(Entry("gaussfuse engine=\"python\"", "gaussfuse", gaussfuse_linear(model, prior, zs, "python"),
                           nP, nP, note="prefix"))
        if avail["statsmodels"]:
            E.append(Entry("statsmodels KalmanSmoother.filter (Cython, BLAS; steady-state test on, its default)",
                           "statsmodels", statsmodels_run(model, prior, zs), T, T, goal=1.0))
            E.append(Entry("statsmodels KalmanSmoother.filter (Cython, BLAS; tolerance=0, every step full)",
                           "statsmodels", statsmodels_run(model, prior, zs, tolerance=0.0), T, T))
        reference = _cached(gaussfuse_linear(model, prior, zs, engine))
        out.append(Workload(
            f"W5 n={n}", f"filter, a state of {n} components",
            f"n = {n} states, m = {model.m} measurements, {T:,} steps: a random stable F (spectral radius "
            "0.95), random SPD Q and R, a random H; filter only; compared: filtered means and covariances",
            "filtered", E, reference, E[0].label, E[0].label))
    return out


BUILDERS = {
    "W1": lambda s, a, e: w1_w3(s, a, e, smooth=False),
    "W2": w2,
    "W3": lambda s, a, e: w1_w3(s, a, e, smooth=True),
    "W4": w4,
    "W5": w5,
}
