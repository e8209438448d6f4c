"""The compiled linear engine (method "kf") equals the readable path.

Every comparison runs ``engine="numba"`` (:mod:`gaussfuse._kernels.linear`)
against ``engine="python"`` (:mod:`gaussfuse.kalman`, the specification)
through ``gf.filter`` and ``gf.smooth``, to 1e-10.
"""

from __future__ import annotations

import threading
import tracemalloc
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba.core.runtime import _nrt_python, rtsys

import _oracle
import gaussfuse as gf
from gaussfuse._kernels import _jit, _rts, kernels, linear

TOL = 1e-10
EPS = np.finfo(float).eps
PER_STEP = ("means", "covs", "predicted_means", "predicted_covs", "innovations", "innovation_covs")
COVARIANCES = ("covs", "predicted_covs", "innovation_covs")


def assert_close(actual, desired, what: str, tol: float = TOL) -> None:
    """Equal to `tol`, relative, with an absolute floor scaled to the size of the values."""
    actual, desired = np.asarray(actual), np.asarray(desired)
    assert actual.shape == desired.shape, f"{what}: shape {actual.shape} != {desired.shape}"
    finite = desired[np.isfinite(desired)]
    scale = max(1.0, float(np.max(np.abs(finite)))) if finite.size else 1.0
    np.testing.assert_allclose(actual, desired, rtol=tol, atol=tol * scale, equal_nan=True, err_msg=what)


def assert_same(got, want) -> None:
    """Every field of two Filter/SmoothResults agrees (None exactly where the other is None).

    A smoother gain ``G = C (P⁻)⁻¹`` is a solve with the prediction ``P⁻``:
    two correct solves differ by up to about ε·cond(P⁻) relative, so G is
    compared directly only where that is below TOL; elsewhere (and where P⁻
    is singular, so that G is not determined on its null space) what the
    smoother uses, ``G P⁻ = C``, is compared. The backward pass multiplies
    the error of step k + 1 by up to ‖G_k‖² (``P_k + G (Pˢ - P⁻) Gᵀ``), so
    the smoothed moments are held to TOL or 100 ε Π_k max(1, ‖G_k‖²), the
    larger (of each series; the product is over its steps).
    """
    assert type(got) is type(want)
    amplified = TOL
    if isinstance(want, gf.SmoothResult) and want.gains.size:
        norms = np.linalg.norm(want.gains, 2, axis=(-2, -1)).reshape(-1, want.gains.shape[-3])
        growth = np.prod(np.maximum(1.0, norms) ** 2, axis=-1)
        amplified = max(TOL, 100 * EPS * float(np.max(growth)))
    for field in fields(want):
        a, b = getattr(got, field.name), getattr(want, field.name)
        if field.name == "filtered":
            assert_same(a, b)
        elif field.name == "gains" and isinstance(want, gf.SmoothResult):
            pred = want.filtered.predicted_covs[..., 1:, :, :]
            assert_close(a @ pred, b @ pred, "gains @ predicted_covs")
            conditioned = EPS * np.linalg.cond(pred) < TOL
            assert_close(a[conditioned], b[conditioned], "gains")
        elif field.name in ("means", "covs") and isinstance(want, gf.SmoothResult):
            assert_close(a, b, field.name, amplified)
        elif b is None:
            assert a is None, field.name
        else:
            assert np.shape(a) == np.shape(b), field.name
            assert_close(a, b, field.name)
    if isinstance(want, gf.FilterResult) and want.innovations is not None:
        # NaN exactly where a component is missing, in both.
        np.testing.assert_array_equal(np.isnan(got.innovations), np.isnan(want.innovations))


# ---------------------------------------------------------------------------
# Random problems: one model, N series with their own controls and gaps
# ---------------------------------------------------------------------------

MATRICES = ("F", "H", "Q", "R", "B")


def missing_mask(rng: np.random.Generator, kind: str, T: int, m: int) -> np.ndarray:
    mask = np.zeros((T, m), dtype=bool)
    if kind == "partial":
        mask = rng.random((T, m)) < 0.3
        mask[rng.random(T) < 0.25] = True  # whole rows
    elif kind == "all missing":
        mask[:] = True
    return mask


DEGENERATE = ("none", "zero variances", "tiny variances", "rank-deficient Q", "zero Q")


def degenerate(rng: np.random.Generator, kind: str, problem: dict) -> dict:
    """The problem with its prior covariance and Q made singular or nearly singular as `kind` says.

    "zero variances": components of the prior known exactly and without
    process noise; "tiny variances": prior variances of 1e-30 next to 1e4
    (uncorrelated with the rest); "rank-deficient Q": Q of rank < n
    (one (n, r) factor, r < n, for every step); "zero Q": no process noise.
    F is then a scaled rotation (singular values in [0.5, 1.2]), so that the
    predictions are no worse conditioned than the covariances themselves: a
    nearly singular F with Q = 0 makes P⁻ ill-conditioned (1e13), and both
    engines then differ from the dense oracle by 1e-8.
    """
    if kind == "none":
        return problem
    problem = dict(problem)
    P0, Q, F = problem["P0"].copy(), problem["Q"].copy(), problem["F"]
    n = P0.shape[0]

    def well_conditioned():
        U = np.linalg.qr(rng.normal(size=(n, n)))[0]
        return U * rng.uniform(0.5, 1.2, n)

    problem["F"] = np.stack([well_conditioned() for _ in F]) if F.ndim == 3 else well_conditioned()
    if kind in ("zero variances", "tiny variances"):
        picked = rng.random(n) < 0.5
        picked[rng.integers(n)] = True
        P0[picked], P0[:, picked] = 0.0, 0.0
        if kind == "zero variances":
            Q[..., picked, :], Q[..., :, picked] = 0.0, 0.0
        else:
            P0[picked, picked] = 1e-30
            P0[~picked, ~picked] = 1e4
    elif kind == "rank-deficient Q":
        B = rng.normal(size=(n, int(rng.integers(0, n))))
        Q = np.broadcast_to(B @ B.T, Q.shape).copy()
    elif kind == "zero Q":
        Q[...] = 0.0
    problem["P0"], problem["Q"] = P0, Q
    return problem


@st.composite
def batches(draw):
    """A model with any of F, H, Q, R, B time-varying, a prior, and N series (N, T, m)."""
    n = draw(st.integers(1, 4), label="n")
    m = draw(st.integers(1, 3), label="m")
    T = draw(st.integers(1, 12), label="T")
    N = draw(st.integers(1, 3), label="N")
    p = draw(st.sampled_from([0, 1, 2]), label="p")
    varying = frozenset(
        name for name in MATRICES if (name != "B" or p) and draw(st.booleans(), label=f"{name} varies")
    )
    kind = draw(st.sampled_from(["none", "partial", "all missing"]), label="missing")
    shared_us = bool(p) and draw(st.booleans(), label="one control series for all")
    kind_of_covariances = draw(st.sampled_from(DEGENERATE), label="degenerate covariances")
    seed = draw(st.integers(0, 2**32 - 1), label="seed")
    rng = np.random.default_rng(seed)
    problem = _oracle.random_problem(rng, n, m, T, p, varying, missing_mask(rng, kind, T, m))
    problem = degenerate(rng, kind_of_covariances, problem)
    zs = [problem["zs"]]
    for _ in range(N - 1):
        z = np.where(np.isnan(zs[0]), 0.0, zs[0]) + rng.normal(size=(T, m))
        z[missing_mask(rng, kind, T, m)] = np.nan
        zs.append(z)
    us = None
    if p:
        us = problem["us"] if shared_us else rng.normal(size=(N, T, p))
    model = gf.LinearModel(problem["F"], problem["H"], problem["Q"], problem["R"], problem["B"])
    return model, gf.Gaussian(problem["m0"], problem["P0"]), np.stack(zs), us


def first(us):
    """The controls of series 0 as (T, p)."""
    return None if us is None else (us if us.ndim == 2 else us[0])


HYPOTHESIS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def one_chunk(run, model, prior, zs, us, **options):
    """`run` with the batch as one chunk (one thread): its series share series 0's covariances where they can.

    Asserts that every series has bit for bit the numbers it has alone.
    """
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(_jit, "threads", lambda: 1)
        got = run(model, prior, zs, us, engine="numba", **options)
    for s in range(len(zs)):
        alone = run(model, prior, zs[s:s + 1], None if us is None else us[s:s + 1] if us.ndim == 3 else us,
                    engine="numba", **options)
        assert_identical(_series(got, s), alone)
    return got


@HYPOTHESIS
@given(batches())
def test_filter_equals_readable_path(case):
    model, prior, zs, us = case
    got = one_chunk(gf.filter, model, prior, zs, us)
    assert_same(got, gf.filter(model, prior, zs, us, engine="python"))
    assert got.loglik.shape == (zs.shape[0],)
    np.testing.assert_array_equal(got.last_mean, got.means[:, -1])
    np.testing.assert_array_equal(got.last_cov, got.covs[:, -1])
    np.testing.assert_array_equal(got.covs, np.swapaxes(got.covs, -1, -2))

    # One series given as (T, m): no series axis, a float log-likelihood.
    one = gf.filter(model, prior, zs[0], first(us), engine="numba")
    assert_same(one, gf.filter(model, prior, zs[0], first(us), engine="python"))
    assert isinstance(one.loglik, float)

    # keep: the same numbers for what is kept, None for the rest.
    for keep, dropped in (("means", COVARIANCES), ("last", PER_STEP)):
        kept = gf.filter(model, prior, zs, us, engine="numba", keep=keep)
        for name in PER_STEP:
            if name in dropped:
                assert getattr(kept, name) is None, (keep, name)
            else:
                np.testing.assert_array_equal(getattr(kept, name), getattr(got, name), err_msg=name)
        for name in ("loglik", "last_mean", "last_cov"):
            np.testing.assert_array_equal(getattr(kept, name), getattr(got, name), err_msg=name)


@HYPOTHESIS
@given(batches())
def test_smooth_equals_readable_path(case):
    model, prior, zs, us = case
    got = one_chunk(gf.smooth, model, prior, zs, us)
    assert_same(got, gf.smooth(model, prior, zs, us, engine="python"))
    T, n = zs.shape[1], model.n
    assert got.gains.shape == (zs.shape[0], T - 1, n, n)
    np.testing.assert_array_equal(got.means[:, -1], got.filtered.means[:, -1])
    # The forward pass of the smoother is the filter.
    np.testing.assert_array_equal(got.filtered.covs, gf.filter(model, prior, zs, us, engine="numba").covs)
    one = gf.smooth(model, prior, zs[0], first(us), engine="numba")
    assert_same(one, gf.smooth(model, prior, zs[0], first(us), engine="python"))


def test_one_compiled_signature_serves_every_case():
    rng = np.random.default_rng(3)
    for varying, p, zs_order in ((set(), 0, "C"), ({"F", "R"}, 1, "F"), (set(MATRICES), 2, "C")):
        problem = _oracle.random_problem(rng, 3, 2, 6, p, varying, rng.random((6, 2)) < 0.2)
        model = gf.LinearModel(problem["F"], problem["H"], problem["Q"], problem["R"], problem["B"])
        prior = gf.Gaussian(problem["m0"], problem["P0"])
        zs = np.asarray(problem["zs"], order=zs_order)
        for keep in ("all", "means", "last"):
            gf.filter(model, prior, zs, problem["us"], engine="numba", keep=keep)
            gf.filter(model, prior, zs, problem["us"], engine="numba", keep=keep, form="sqrt")
        gf.smooth(model, prior, np.stack([zs, zs]), problem["us"], engine="numba")
    for kernel in linear.KERNELS:
        assert len(kernel.signatures) == 1, kernel


# ---------------------------------------------------------------------------
# A published reference: Särkkä & Svensson's car tracking
# ---------------------------------------------------------------------------


def test_car_track_rmse(car_track):
    X, Y = car_track["X"].T, car_track["Y"].T
    model = gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, -1.0], np.eye(4))

    def rmse(estimate):
        return float(np.sqrt(np.mean(np.sum((estimate[:, :2] - X[:, :2]) ** 2, axis=-1))))

    sm = gf.smooth(model, prior, Y, engine="numba", check="raise")  # the published run: no divergence
    assert rmse(sm.filtered.means) == pytest.approx(0.4253824660526518, abs=1e-8)
    assert rmse(sm.means) == pytest.approx(0.26497104638205465, abs=1e-8)
    filtered = gf.filter(model, prior, Y, engine="numba", check="raise")
    assert rmse(filtered.means) == pytest.approx(0.4253824660526518, abs=1e-8)


# ---------------------------------------------------------------------------
# Failures and degenerate cases
# ---------------------------------------------------------------------------


def blind_at_step_3() -> gf.LinearModel:
    """A model whose measurement carries no information and no noise at step 3: S = 0."""
    H = np.array([[[1.0, 0.0]]] * 6)
    H[3] = 0.0
    return gf.LinearModel(F=np.eye(2), H=H, Q=np.eye(2), R=[[0.0]])


def test_not_positive_definite_innovation_covariance_raises_like_the_readable_path():
    model, prior = blind_at_step_3(), gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = np.arange(6.0)
    with pytest.raises(np.linalg.LinAlgError) as python:
        gf.filter(model, prior, zs, engine="python")
    with pytest.raises(np.linalg.LinAlgError) as numba:
        gf.filter(model, prior, zs, engine="numba")
    assert str(numba.value) == str(python.value)
    assert str(numba.value).startswith(
        "at step 3: the innovation covariance S = H P Hᵀ + R is not positive definite, "
        "so it cannot be factorised"
    )
    with pytest.raises(np.linalg.LinAlgError, match="^at step 3: the innovation covariance"):
        gf.smooth(model, prior, zs, engine="numba")


def test_not_positive_definite_names_the_series():
    model, prior = blind_at_step_3(), gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = np.tile(np.arange(6.0)[None, :, None], (4, 1, 1))
    zs[:2, 3] = np.nan  # series 0 and 1 skip the blind step; series 2 and 3 do not
    with pytest.raises(np.linalg.LinAlgError,
                       match=r"^in series 2, at step 3: the innovation covariance S = H P Hᵀ \+ R "
                             r"is not positive definite, so it cannot be factorised: \[\[0\.\]\] \(S is singular to "
                             r"round-off .*\)$"):
        gf.filter(model, prior, zs, engine="numba")
    # Without the failing series, the same batch filters.
    res = gf.filter(model, prior, zs[:2], engine="numba")
    assert np.all(np.isfinite(res.loglik))


def test_singular_prediction_takes_the_least_squares_gain():
    # No process noise and a belief certain of the velocity: P⁻ is singular
    # from the first step, so every smoother gain falls back to least squares.
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=np.zeros((2, 2)), R=[[0.5]])
    prior = gf.Gaussian([0.0, 1.0], np.diag([2.0, 0.0]))
    zs = np.array([[1.2], [1.9], [np.nan], [4.1], [5.0]])
    got = gf.smooth(model, prior, zs, engine="numba")
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(got.filtered.predicted_covs[1])
    assert_same(got, gf.smooth(model, prior, zs, engine="python"))
    batch = gf.smooth(model, prior, np.stack([zs, zs + 1.0]), engine="numba")
    assert_same(batch, gf.smooth(model, prior, np.stack([zs, zs + 1.0]), engine="python"))


# ---------------------------------------------------------------------------
# Memory: keep="last" allocates nothing per step
# ---------------------------------------------------------------------------


def test_keep_last_allocates_nothing_per_step():
    model = gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)  # n = 4, m = 2
    prior = gf.Gaussian(np.zeros(4), np.eye(4))
    T = 100_000
    zs = np.random.default_rng(0).normal(size=(T, 2)).cumsum(axis=0)
    gf.filter(model, prior, zs[:10], engine="numba", keep="last")  # compiled before tracing

    def peak(keep: str) -> int:
        tracemalloc.start()
        try:
            gf.filter(model, prior, zs, engine="numba", keep=keep)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    # A float64 `zs` is neither copied nor scanned through a temporary, so
    # nothing grows with T; the per-step arrays of keep="all" are 23 times `zs`.
    assert peak("last") < 100_000 < zs.nbytes
    assert peak("all") > T * (4 + 16) * 8 * 2


def test_keep_last_kernel_allocations_do_not_grow_with_T():
    model = gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)
    prior = gf.Gaussian(np.zeros(4), np.eye(4))
    zs = np.random.default_rng(1).normal(size=(2, 20_000, 2))

    def allocations(T: int) -> int:
        before = rtsys.get_allocation_stats().alloc
        gf.filter(model, prior, zs[:, :T], engine="numba", keep="last")
        return rtsys.get_allocation_stats().alloc - before

    was_enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        gf.filter(model, prior, zs[:, :5], engine="numba", keep="last")
        short, long = allocations(10), allocations(20_000)
    finally:
        if not was_enabled:
            _nrt_python.memsys_disable_stats()
    assert 0 < short == long  # scratch per call, none per step


# ---------------------------------------------------------------------------
# Compilation: "auto" compiles only for long inputs (the disk cache: tests/_kernels/test_init.py)
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("front", ["filter", "smooth"])
def test_auto_engine_compiles_from_1000_steps(monkeypatch, front):
    """With the kernels in memory, "auto" compiles from 1000 steps (all series together) on."""
    from gaussfuse.inference import drivers

    monkeypatch.setattr(drivers, "kernel_states", lambda *args: dict.fromkeys(kernels(*args[:2]), "loaded"))
    calls = []
    original = getattr(linear, front)

    def spy(*args, **kwargs):
        calls.append(args[3].shape)
        return original(*args, **kwargs)

    monkeypatch.setattr(linear, front, spy)
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.eye(2), R=1.0)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = np.random.default_rng(2).normal(size=(4, 250, 1))
    run = getattr(gf, front)

    below = run(model, prior, zs[:, :249])  # 996 steps in all: the readable path
    assert calls == []
    assert_same(below, run(model, prior, zs[:, :249], engine="python"))

    auto = run(model, prior, zs)  # 1000 steps: compiled
    assert calls == [(4, 250, 1)]
    assert_same(auto, run(model, prior, zs, engine="python"))

    run(model, prior, zs[0, :999])
    assert len(calls) == 1
    run(model, prior, zs.reshape(1000, 1))
    assert calls[-1] == (1, 1000, 1)


# ---------------------------------------------------------------------------
# Batches: chunks of series on a pool of threads, with the numbers of one series at a time
# ---------------------------------------------------------------------------


def assert_identical(got, want) -> None:
    """Every field of two Filter/SmoothResults is bit for bit the same (None where the other is None)."""
    for field in fields(want):
        a, b = getattr(got, field.name), getattr(want, field.name)
        if field.name == "filtered":
            assert_identical(a, b)
        elif b is None:
            assert a is None, field.name
        else:
            np.testing.assert_array_equal(a, b, err_msg=field.name)


def _batch_problem():
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.1, 0.01]), R=1.0)
    prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    return model, prior, np.random.default_rng(5).normal(size=(40, 30, 1)).cumsum(axis=1)


@pytest.mark.parametrize("front", ["filter", "smooth"])
def test_a_batch_runs_in_chunks_on_several_threads_with_each_series_own_numbers(monkeypatch, front):
    model, prior, zs = _batch_problem()
    run = getattr(gf, front)
    monkeypatch.setattr(_jit, "threads", lambda: 3)  # a pool whatever this machine's cores
    ran = []  # (kernel, lo, hi, thread) of every launch
    for module, name in ((linear, "forward"), (_rts, "backward")):
        kernel = getattr(module, name)

        def spy(lo, hi, *args, _k=kernel, _name=name):
            ran.append((_name, lo, hi, threading.current_thread().name))
            return _k(lo, hi, *args)
        monkeypatch.setattr(module, name, spy)

    batch = run(model, prior, zs, engine="numba")
    for name in ("forward",) + (("backward",) if front == "smooth" else ()):
        chunks = sorted((lo, hi) for kernel, lo, hi, _ in ran if kernel == name)
        assert len(chunks) == len(zs)  # 40 series, up to 16 chunks per thread: one series a chunk
        assert [lo for lo, _ in chunks] == [0] + [hi for _, hi in chunks[:-1]] and chunks[-1][1] == len(zs)
    assert {thread for *_, thread in ran} <= {f"gaussfuse_{i}" for i in range(3)}  # the pool's threads only

    ran.clear()
    for s in (0, 17, 39):  # a series alone runs on the calling thread, with the same bits
        alone = run(model, prior, zs[s:s + 1], engine="numba")
        assert {thread for *_, thread in ran} == {threading.current_thread().name}
        assert_identical(_series(batch, s), alone)


def _series(result, s: int):
    """Series `s` of a batch's Filter/SmoothResult, as a batch of one."""
    return type(result)(**{f.name: _series(v, s) if f.name == "filtered" else None if v is None else v[s:s + 1]
                           for f in fields(result) for v in [getattr(result, f.name)]})


def test_launch_waits_for_every_chunk_and_raises_what_one_raised(monkeypatch):
    monkeypatch.setattr(_jit, "threads", lambda: 2)
    done = []

    def kernel(lo, hi):
        if lo == 0:
            raise ZeroDivisionError("chunk 0")
        threading.Event().wait(0.01)  # still running when chunk 0 has failed
        done.append(lo)

    with pytest.raises(ZeroDivisionError, match="chunk 0"):
        _jit.launch(kernel, 10)
    assert sorted(done) == list(range(1, 10))  # every other chunk had ended when the error came


def _filter_in_a_child(queue):
    model, prior, zs = _batch_problem()
    queue.put(float(gf.filter(model, prior, zs, engine="numba").loglik.sum()))


def test_a_forked_child_runs_batches_on_a_pool_of_its_own(monkeypatch):
    """The parent's pool threads are not copied by fork(): a child that reused the pool would wait forever."""
    import multiprocessing

    monkeypatch.setattr(_jit, "threads", lambda: 2)
    model, prior, zs = _batch_problem()
    want = float(gf.filter(model, prior, zs, engine="numba").loglik.sum())  # the parent's pool has started
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_filter_in_a_child, args=(queue,))
    child.start()
    child.join(timeout=120)  # a guard only: the child ends in well under a second
    if child.is_alive():
        child.kill()
        pytest.fail("the forked child hung on the parent's pool")
    assert child.exitcode == 0
    assert queue.get(timeout=10) == want


@pytest.mark.parametrize("engine", ["numba", "python"])
def test_a_fixed_point_reached_only_to_round_off_is_reused(engine):
    """A random 8-state model's covariance keeps changing in its last bits; it is kept once it changes no more.

    Computing every step (the same matrices given per step) never repeats a
    covariance bit for bit; the time-invariant model keeps one after a few
    dozen steps, and the two agree to round-off.
    """
    rng = np.random.default_rng(508)
    n, m, T = 8, 4, 300
    A = rng.normal(size=(n, n))
    F = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A)))
    model = gf.LinearModel(F, rng.normal(size=(m, n)) / np.sqrt(n), _oracle.random_spd(rng, n),
                           _oracle.random_spd(rng, m))
    zs = rng.normal(size=(T, m))
    prior = gf.Gaussian(np.zeros(n), np.eye(n))
    varying = gf.LinearModel(np.repeat(F[None], T, 0), model.H, model.Q, model.R)
    fast, full = gf.filter(model, prior, zs, engine=engine), gf.filter(varying, prior, zs, engine=engine)
    assert len({full.covs[k].tobytes() for k in range(T - 100, T)}) > 1  # never a bitwise fixed point
    assert len({fast.covs[k].tobytes() for k in range(T - 100, T)}) == 1  # kept
    for name in ("means", "covs", "predicted_covs", "innovation_covs"):
        b = getattr(full, name)
        np.testing.assert_allclose(getattr(fast, name), b, rtol=0, atol=1e-13 * np.abs(b).max(), err_msg=name)
    np.testing.assert_allclose(fast.loglik, full.loglik, rtol=1e-13)


@pytest.mark.parametrize("keep", ["all", "last"])
def test_the_fixed_point_is_reused_and_agrees_with_computing_every_step(keep):
    """A time-invariant model's kernel reuses the covariance fixed point: what computing every step gives, to round-off.

    The same matrices given per step (a time-varying model) are computed in
    full at every step; the readable path, which reuses the fixed point too,
    agrees to round-off. Missing components leave the fixed point and it is
    found again.
    """
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    T = 400
    rng = np.random.default_rng(11)
    zs = np.cumsum(rng.normal(size=(3, T, 2)), axis=1) * 0.1
    zs[0, 150, 1] = np.nan
    zs[1, 200:210] = np.nan
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))
    varying = gf.LinearModel(np.repeat(model.F[None], T, 0), model.H, model.Q, model.R)
    fast = gf.filter(model, prior, zs, engine="numba", keep=keep)
    full = gf.filter(varying, prior, zs, engine="numba", keep=keep)
    for name in ("means", "covs", "predicted_means", "predicted_covs", "innovations", "innovation_covs", "loglik",
                 "last_mean", "last_cov"):
        a, b = getattr(fast, name), getattr(full, name)
        assert (a is None) == (b is None), name
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * np.nanmax(np.abs(b)), err_msg=name)
    readable = gf.filter(model, prior, zs[0], engine="python", keep=keep)
    np.testing.assert_allclose(fast.last_cov[0], readable.last_cov, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(fast.loglik[0], readable.loglik, rtol=1e-12)


def _gappy_batch(T: int, varying: bool):
    """Six series whose missing components leave series 0's pattern at different steps (see the test)."""
    rng = np.random.default_rng(29)
    n, m, p = 3, 2, 1
    F = np.array([[1.0, 0.5, 0.0], [0.0, 0.9, 0.2], [0.0, 0.0, 0.8]])
    if varying:
        F = F * (1.0 + 0.1 * rng.random((T, 1, 1)))
    model = gf.LinearModel(F, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], 0.1 * np.eye(n), np.diag([0.5, 2.0]),
                           B=[[0.0], [1.0], [0.0]])
    zs = rng.normal(size=(6, T, m)).cumsum(axis=1)
    zs[[0, 1, 3], 4, 1] = np.nan  # series 0's gaps: component 1 at step 4, all at step 10
    zs[[0, 1, 3], 10] = np.nan
    zs[3, T - 5, 0] = np.nan      # series 3 leaves series 0's pattern late, series 2 (no gaps) at step 4
    zs[4, 0] = np.nan             # series 4 at once
    zs[5, T // 2:T // 2 + 3] = np.nan
    us = rng.normal(size=(6, T, p))
    return model, gf.Gaussian(np.zeros(n), 4.0 * np.eye(n)), zs, us


@pytest.mark.parametrize("form", ["cov", "sqrt"])
@pytest.mark.parametrize("varying, T", [(True, 30), (False, 200)])
@pytest.mark.parametrize("front", ["filter", "smooth"])
def test_series_sharing_the_first_series_covariances_keep_their_own_numbers(monkeypatch, front, varying, T, form):
    """A batch's series reuse series 0's covariances and gains while they observe what it observed.

    With one thread the whole batch is one chunk: series 0 records its
    steps, and every other series reuses them until its first step that
    observes other components (step 0, 4, T - 5, T // 2, or never). Each
    series has bit for bit the numbers it has alone, where nothing is
    shared, time-varying or not; the time-invariant model reaches its fixed
    point before T // 2, so series leave the table from the fixed point too.
    The square-root form's series share factors the same way.
    """
    monkeypatch.setattr(_jit, "threads", lambda: 1)
    model, prior, zs, us = _gappy_batch(T, varying)
    run = getattr(gf, front)
    keeps = ("all", "means", "last") if front == "filter" else (None,)
    for keep in keeps:
        options = {"form": form} if keep is None else {"keep": keep, "form": form}
        batch = run(model, prior, zs, us, engine="numba", **options)
        for s in range(len(zs)):
            assert_identical(_series(batch, s), run(model, prior, zs[s:s + 1], us[s:s + 1], engine="numba", **options))
        assert_same(batch, run(model, prior, zs, us, engine="python", **options))


def test_a_series_leaving_the_shared_fixed_point_is_not_tested_for_one_at_that_step(monkeypatch):
    """As alone: the step that leaves the fixed point is not a candidate for a new one.

    Component 1's noise is so large that missing it changes the covariance
    by less than the fixed point's tolerance, so only that rule keeps a
    series that leaves series 0's table from holding a fixed point a step
    earlier than it would alone.
    """
    monkeypatch.setattr(_jit, "threads", lambda: 1)
    model = gf.LinearModel([[1.0, 0.5], [0.0, 0.9]], np.eye(2), 0.1 * np.eye(2), np.diag([0.5, 1e20]))
    prior = gf.Gaussian(np.zeros(2), np.eye(2))
    zs = np.random.default_rng(3).normal(size=(3, 200, 2)).cumsum(axis=1)
    zs[1, 150, 1] = np.nan
    zs[2, 150:152, 1] = np.nan
    batch = gf.filter(model, prior, zs, engine="numba")
    for s in range(3):
        assert_identical(_series(batch, s), gf.filter(model, prior, zs[s:s + 1], engine="numba"))


def test_a_large_state_batch_shares_covariances_with_each_series_own_numbers():
    """From BLAS_FROM states a batch runs as one chunk whatever the threads: series 0's table serves the rest."""
    from gaussfuse._kernels._dense import BLAS_FROM

    rng = np.random.default_rng(41)
    n, m, T = BLAS_FROM, 4, 12
    model = gf.LinearModel(0.9 * np.eye(n) + 0.01 * rng.normal(size=(n, n)), rng.normal(size=(m, n)),
                           _oracle.random_spd(rng, n), _oracle.random_spd(rng, m))
    prior = gf.Gaussian(np.zeros(n), np.eye(n))
    zs = rng.normal(size=(4, T, m))
    zs[2, 5, 0] = np.nan
    batch = gf.filter(model, prior, zs, engine="numba")
    for s in range(len(zs)):
        assert_identical(_series(batch, s), gf.filter(model, prior, zs[s:s + 1], engine="numba"))
    assert_same(batch, gf.filter(model, prior, zs, engine="python"))
