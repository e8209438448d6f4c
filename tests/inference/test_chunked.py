"""Many series as a dask array: filter, smooth and fit chunk by chunk, on a real dask.distributed cluster.

The oracle is the in-memory batch path on the same array: each series is
filtered on its own, so the chunks must give its results to the last bit
(the pooled fit's sums are added in another order: to round-off). The
cluster is a LocalCluster of 2 worker processes, started here; one test
kills a worker in the middle of a run.
"""

import os
import signal
import time
import warnings

import numpy as np
import pytest

import gaussfuse as gf

da = pytest.importorskip("dask.array")
distributed = pytest.importorskip("distributed")
dask = pytest.importorskip("dask")


@pytest.fixture(scope="module")
def client():
    # The kernels are compiled (or loaded) here first, so that the workers load them from numba's disk cache.
    gf.filter(gf.constant_velocity(1.0, 1.0, 1.0), gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros((2, 3, 1)),
              engine="numba")
    gf.smooth(gf.constant_velocity(1.0, 1.0, 1.0), gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros((2, 3, 1)),
              engine="numba")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=2, processes=True,
                                           dashboard_address=None, silence_logs=50)
        with distributed.Client(cluster) as c:
            yield c
        cluster.close()


def panel(N=40, T=50, seed=0):
    rng = np.random.default_rng(seed)
    model = gf.constant_velocity(0.5, 0.3, 0.8, dim=2)
    sims = gf.simulate(model, gf.Gaussian(np.zeros(4), np.eye(4)), T, size=N, rng=rng)
    zs = np.array(sims.measurements)
    zs[rng.random(zs.shape) < 0.05] = np.nan
    return model, gf.Gaussian(np.zeros(4), 10.0 * np.eye(4)), zs


def test_filter_and_smooth_on_the_cluster_equal_the_batch_path(client):
    model, prior, zs = panel()
    lazy = da.from_array(zs, chunks=(7, 25, 2))  # chunked over time too: rejoined, each chunk whole series
    for run in (gf.filter, gf.smooth):
        res = run(model, prior, lazy, engine="numba")
        assert isinstance(res.means, da.Array) and res.means.chunks[0] == (7, 7, 7, 7, 7, 5)
        assert res.covs.shape == (40, 50, 4, 4)
        got = dask.compute(res)[0]
        want = run(model, prior, zs, engine="numba")
        for name in ("means", "covs"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        filt_got, filt_want = getattr(got, "filtered", got), getattr(want, "filtered", want)
        np.testing.assert_array_equal(filt_got.loglik, filt_want.loglik)
        np.testing.assert_array_equal(filt_got.nis, filt_want.nis)
        if run is gf.smooth:
            np.testing.assert_array_equal(got.gains, want.gains)


def test_nothing_runs_until_asked(client):
    model, prior, zs = panel(N=6, T=10)
    calls = []

    def counted(block):
        calls.append(block.shape)
        return block

    lazy = da.from_array(zs, chunks=(2, 10, 2)).map_blocks(counted, dtype=float, meta=np.empty((0, 0, 0)))
    res = gf.filter(model, prior, lazy, engine="python")
    assert calls == [] and res.means.chunks[0] == (2, 2, 2)
    np.testing.assert_array_equal(res.means[:2].compute(scheduler="sync"), gf.filter(model, prior, zs[:2]).means)


def _held_back(block, block_info=None):
    """The input of the last chunk, given only once the test says go: the run is surely unfinished until then.

    Only one: holding back half the chunks (4 of 8) could take all 4 of the cluster's threads, in whatever order
    Dask started them, so that no chunk finished before the wait timed out (it failed so once).
    """
    if block_info[0]["chunk-location"][0] == block_info[0]["num-chunks"][0] - 1:
        distributed.Event("go").wait(timeout=120)
    return block


def _finished_chunks(dask_scheduler):
    """Where each finished task's result is (a chunk's, fused by Dask with its inputs): [(key, worker address)]."""
    return [(str(ts.key), ws.address) for ts in dask_scheduler.tasks.values()
            if ts.state == "memory" for ws in ts.who_has]


def test_a_worker_killed_mid_run_and_the_results_are_the_same(client):
    model, prior, zs = panel(N=40, T=100, seed=1)
    want = gf.smooth(model, prior, zs, engine="numba")
    lazy = da.from_array(zs, chunks=(5, 100, 2)).map_blocks(_held_back, dtype=float, meta=np.empty((0, 0, 0)))
    future = client.compute(gf.smooth(model, prior, lazy, engine="numba").means)
    deadline = time.monotonic() + 120
    while not (finished := client.run_on_scheduler(_finished_chunks)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert finished and not future.done()  # chunks done on some worker, the last waiting
    pids = client.run(os.getpid)
    os.kill(pids[finished[0][1]], signal.SIGKILL)  # the worker holding a finished chunk: it must be redone
    distributed.Event("go", client=client).set()
    np.testing.assert_array_equal(future.result(timeout=300), want.means)
    assert finished[0][1] not in client.run(os.getpid) or client.run(os.getpid)[finished[0][1]] != \
        pids[finished[0][1]]  # a new worker process


def test_pooled_em_and_mle_over_chunks_equal_the_in_memory_fit(client):
    model, prior, zs = panel(N=12, T=40, seed=2)
    lazy = da.from_array(zs, chunks=(5, 40, 2))
    start = gf.constant_velocity(0.5, 1.0, 2.0, dim=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.ConvergenceWarning)
        for learn in (("Q", "R"), ("F", "Q", "R", "m0", "P0")):  # the second needs two passes per M-step
            a = gf.fit(start, prior, zs, learn=learn, method="em", iterations=3, tol=0, engine="numba")
            b = gf.fit(start, prior, lazy, learn=learn, method="em", iterations=3, tol=0, engine="numba")
            np.testing.assert_allclose(b.history, a.history, rtol=1e-12)
            for name in ("F", "Q", "R"):
                np.testing.assert_allclose(getattr(b.model, name), getattr(a.model, name), rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(b.prior.cov, a.prior.cov, rtol=1e-10, atol=1e-12)
        scalar = {"learn": ("Q", "R"), "structure": {"Q": "scalar", "R": "scalar"}}
        a = gf.fit(start, prior, zs, method="mle", engine="numba", **scalar)
        b = gf.fit(start, prior, lazy, method="mle", engine="numba", **scalar)
    assert a.converged and b.converged
    np.testing.assert_allclose(b.model.Q, a.model.Q, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(b.model.R, a.model.R, rtol=1e-8)
    assert b.nobs == a.nobs == int(np.sum(~np.isnan(zs)))


def test_the_standard_errors_of_a_chunked_fit_are_one_pass_over_the_chunks():
    """The Hessian's 2k scores are computed together: on a cluster each pass is a round trip (it was 2k of them).

    Counted as dask computes on the synchronous scheduler; the oracle for the numbers is the in-memory fit.
    """
    from dask.callbacks import Callback

    class Computes(Callback):
        count = 0

        def _start(self, dsk):
            Computes.count += 1

    model, prior, zs = panel(N=6, T=30, seed=2)
    # from the maximum (a diagonal Q: a full one's is singular here): 2 EM iterations from afar leave a gradient
    # whose term in the Hessian hides the curvature, and no standard errors are given there
    diagonal = {"Q": "diagonal"}
    start = gf.fit(gf.constant_velocity(0.5, 1.0, 2.0, dim=2), prior, zs, learn=("Q", "R"), structure=diagonal,
                   method="mle").model
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.ConvergenceWarning)
        want = gf.fit(start, prior, zs, learn=("Q", "R"), structure=diagonal, iterations=2, tol=0)
        with dask.config.set(scheduler="synchronous"), Computes():
            got = gf.fit(start, prior, da.from_array(zs, chunks=(2, 30, 2)), learn=("Q", "R"), structure=diagonal,
                         iterations=2, tol=0)
    k = 4 + 3  # Q's variances, and R (2 x 2, symmetric)
    # EM's passes (the start's, one an iteration, the last), one for the Hessian, and one for the boundary test of
    # its weakly identified variances (Q[0,0] = 0.056 with a standard error of 0.18: learning._unresolved)
    assert Computes.count <= 2 + 4 < 2 * k
    for name in ("Q", "R"):
        np.testing.assert_allclose(got.standard_errors[name], want.standard_errors[name], rtol=1e-6)


def test_dask_input_errors():
    model, prior, zs = panel(N=4, T=5)
    with pytest.raises(ValueError, match=r"`zs` must have shape \(N, T, 2\) .* got shape \(5, 2\)"):
        gf.filter(model, prior, da.from_array(zs[0]))
    with pytest.raises(ValueError, match="`check` must be one of"):
        gf.filter(model, prior, da.from_array(zs), check="loud")
    with pytest.raises(ValueError, match=r"`zs` must have shape \(N, T, 2\) .* got shape \(4, 5, 1\)"):
        gf.fit(model, prior, da.from_array(zs[..., :1]))


def test_dask_input_is_checked_before_any_chunk_runs_and_named_as_the_user_gave_it():
    """The result's structure is read from a short probe series: its shapes named the errors ("got shape (1, 6, 3)"
    for a (5, 10, 3) `zs`), a `us` of the wrong length failed only in compute, no series gave ZeroDivisionError
    and strings NumPy's message (audit BB3)."""
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=0.1 * np.eye(2), R=1.0, B=np.eye(2))
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = da.zeros((5, 10, 1), chunks=(2, 10, 1))
    us = da.zeros((5, 10, 2), chunks=(2, 10, 2))
    for run in (gf.filter, gf.smooth, gf.fit):
        with pytest.raises(ValueError, match=r"^`zs` must have shape \(N, T, 1\) .*; got shape \(5, 10, 3\)\.$"):
            run(model, prior, da.zeros((5, 10, 3), chunks=(2, 10, 3)), us)
        with pytest.raises(ValueError, match=r"^`zs` must have shape .* N >= 1 .*; got shape \(0, 10, 1\)\.$"):
            run(model, prior, da.zeros((0, 10, 1), chunks=(1, 10, 1)), us[:0])
        with pytest.raises(TypeError, match=r"^`zs` must be an array of real numbers; got a dask array of <U1\.$"):
            run(model, prior, da.from_array(np.full((5, 10, 1), "a"), chunks=(2, 10, 1)), us)
        with pytest.raises(TypeError, match=r"^`us` must be a rectangular array"):  # (NumPy's message: review R20)
            run(model, prior, zs, [[[0.0, 0.0]] * 10] * 4 + [[[0.0]] * 10])
        for wrong in ((5, 10, 3), (5, 11, 2)):
            with pytest.raises(ValueError, match=r"^`us` must have shape \(N, T, 2\) = \(5, 10, 2\), the series and "
                                                 rf"steps of `zs`; got shape \({wrong[0]}, {wrong[1]}, {wrong[2]}\)\.$"):
                run(model, prior, zs, da.zeros(wrong, chunks=(2, *wrong[1:])))


def test_an_error_in_a_chunk_names_the_series_by_its_number_in_the_whole_array():
    """A chunk's run counted its series from 0: an inf in series 4 was "at index (0, 7, 0)" (audit BB3)."""
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=0.1 * np.eye(2), R=0.0)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zs = np.zeros((5, 10, 1))
    zs[4, 7, 0] = np.inf
    with pytest.raises(ValueError, match=r"at index \(4, 7, 0\)"):
        gf.filter(model, prior, zs)
    with dask.config.set(scheduler="synchronous"), pytest.raises(ValueError, match=r"at index \(4, 7, 0\)\.$"):
        gf.filter(model, prior, da.from_array(zs, chunks=(2, 10, 1))).means.compute()
    # a model function that fails where series 3's data lead it, with chunks of 2 series and of 1

    def h(x):
        if x[0] > 100:
            raise ValueError("out of range")
        return x[:1]

    model = gf.NonlinearModel(f=lambda x: x, h=h, Q=[[1.0]], R=1.0)
    prior = gf.Gaussian([0.0], [[1e4]])
    zs = np.zeros((5, 4, 1))
    zs[3, 1:] = 1000.0
    with pytest.raises(ValueError) as in_memory:
        gf.filter(model, prior, zs, method="ekf")
    assert str(in_memory.value).startswith("in series 3, at step 2"), str(in_memory.value)
    for size in (2, 1):
        with dask.config.set(scheduler="synchronous"), pytest.raises(ValueError) as chunked:
            gf.filter(model, prior, da.from_array(zs, chunks=(size, 4, 1)), method="ekf").means.compute()
        assert str(chunked.value) == str(in_memory.value)

    def h_own(x):  # a model function's own text with an index in it is not renumbered (review R19)
        if x[0] > 100:
            raise ValueError("table lookup failed at index (0, 2)")
        return x[:1]

    model = gf.NonlinearModel(f=lambda x: x, h=h_own, Q=[[1.0]], R=1.0)
    with pytest.raises(ValueError) as in_memory:
        gf.filter(model, prior, zs, method="ekf")
    with dask.config.set(scheduler="synchronous"), pytest.raises(ValueError) as chunked:
        gf.filter(model, prior, da.from_array(zs, chunks=(2, 4, 1)), method="ekf").means.compute()
    assert str(chunked.value) == str(in_memory.value)
    assert str(chunked.value).startswith("in series 3, ") and str(chunked.value).endswith("at index (0, 2)")


def test_a_model_that_fails_on_zeros_reads_its_structure_from_the_data():
    """The result's structure was read from a probe series of zeros, which led a square root of a level below 0:
    gf.filter failed on a dask array whose every series filters in memory (audit BB3)."""

    def h(x):
        if x[0] < 0:
            raise ValueError("no square root of a negative level")
        return np.sqrt(x[:1])

    model = gf.NonlinearModel(f=lambda x: x, h=h, Q=[[0.01]], R=1e-6)
    prior = gf.Gaussian([50.0], [[1.0]])
    zs = np.sqrt(50.0) + 0.001 * np.random.default_rng(0).normal(size=(4, 3, 1))  # shorter than the probe
    want = gf.filter(model, prior, zs, method="ekf")
    with dask.config.set(scheduler="synchronous"):
        got = gf.filter(model, prior, da.from_array(zs, chunks=(2, 3, 1)), method="ekf")
        np.testing.assert_array_equal(got.means.compute(), want.means)
        np.testing.assert_array_equal(got.covs.compute(), want.covs)
        np.testing.assert_array_equal(got.loglik.compute(), want.loglik)

    # a series shorter than the probe: the data's steps, then missing ones; cycled, it ran across a seam (its last
    # row, then its first) that failed where no series does (review R19)
    def h_range(x):
        if x[0] < 40:
            raise ValueError(f"level {x[0]:.3g} below the sensor's range")
        return x[:1]

    model = gf.NonlinearModel(f=lambda x: np.array([x[0] + x[1], x[1]]), h=h_range, Q=np.diag([1.0, 100.0]), R=0.01)
    prior = gf.Gaussian([50.0, 10.0], np.diag([1.0, 1.0]))
    zs = np.array([[[60.0], [160.0], [260.0]]] * 2)
    want = gf.filter(model, prior, zs, method="ekf")
    with dask.config.set(scheduler="synchronous"):
        got = gf.filter(model, prior, da.from_array(zs, chunks=(1, 3, 1)), method="ekf", check="off")
        np.testing.assert_array_equal(got.means.compute(), want.means)

    # ... nor beyond its end, where the model's own predictions took f out of its domain (review R21)
    model = gf.NonlinearModel(f=lambda x: np.sqrt(x - 1.0), h=lambda x: x, Q=[[1e-4]], R=[[1e-2]])
    prior = gf.Gaussian([10.0], [[1e-4]])
    zs = np.array([[[10.0], [3.0]]] * 3)
    for method in ("ekf", "ukf"):
        want = gf.filter(model, prior, zs, method=method, check="off")
        with dask.config.set(scheduler="synchronous"):
            got = gf.filter(model, prior, da.from_array(zs, chunks=(1, 2, 1)), method=method, check="off")
            np.testing.assert_array_equal(got.means.compute(), want.means)
            np.testing.assert_array_equal(got.covs.compute(), want.covs)

    # ... and its controls are its own: zeros failed an f of log u (review R20)
    def f_log(x, u):
        return np.array([x[0] + np.log(u[0])])

    model = gf.NonlinearModel(f=f_log, h=np.log, Q=[[0.01]], R=[[0.01]], p=1)
    prior = gf.Gaussian([10.0], [[0.01]])
    us = np.random.default_rng(1).uniform(1.0, 1.2, size=(4, 2, 1))
    zs = np.log(10 * np.cumprod(us, axis=1))
    for run in (gf.filter, gf.smooth):
        want = run(model, prior, zs, us, method="ekf", check="off")
        with dask.config.set(scheduler="synchronous"):
            got = run(model, prior, da.from_array(zs, chunks=(2, 2, 1)), us.tolist(), method="ekf", check="off")
            np.testing.assert_array_equal(got.means.compute(), want.means)

    # where the first series' own steps fail, the error names it, as in memory (review R20: it named none)
    model = gf.NonlinearModel(f=lambda x: np.sqrt(x - 1.0), h=lambda x: x, Q=[[1e-6]], R=[[1e-2]])
    prior = gf.Gaussian([10.0], [[1e-6]])
    zs = np.array([[[3.0], [1.4], [0.6], [0.1], [0.1], [0.1]]] * 3)
    with pytest.raises(gf.ModelFunctionError) as in_memory:
        gf.filter(model, prior, zs, method="ekf")
    with pytest.raises(gf.ModelFunctionError) as chunked:
        gf.filter(model, prior, da.from_array(zs, chunks=(1, 6, 1)), method="ekf")
    assert str(chunked.value) == str(in_memory.value) and str(in_memory.value).startswith("in series 0, at step 3")


def test_controls_in_memory_with_chunked_measurements_are_chunked_as_they_are():
    """A NumPy `us` with a dask `zs` raised AttributeError ('numpy.ndarray' object has no attribute 'chunks', or
    'rechunk' under a diffuse prior with a series unobserved); it is chunked over series as `zs` is."""
    rng = np.random.default_rng(0)
    zs, us = rng.normal(size=(4, 20, 1)), rng.normal(size=(4, 20, 1))
    zs[1] = np.nan  # nothing observed: a diffuse fit drops the series
    model = gf.LinearModel(F=0.9, H=1.0, Q=1.0, R=1.0, B=1.0)
    lazy = da.from_array(zs, chunks=(2, 20, 1))
    prior = gf.Gaussian([0.0], [[1.0]])
    with dask.config.set(scheduler="synchronous"):
        for run in (gf.filter, gf.smooth):
            got, want = run(model, prior, lazy, us), run(model, prior, zs, us)
            np.testing.assert_array_equal(np.asarray(got.means), want.means)
            # controls as nested lists, as in memory (review R19: AttributeError)
            np.testing.assert_array_equal(np.asarray(run(model, prior, lazy, us.tolist()).means), want.means)
        for start in (prior, "diffuse"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", gf.ConvergenceWarning)
                got, want = (gf.fit(model, start, data, us, learn=("R",), iterations=3, tol=0) for data in (lazy, zs))
                listed = gf.fit(model, start, lazy, us.tolist(), learn=("R",), iterations=3, tol=0)
            np.testing.assert_allclose(got.history, want.history, rtol=1e-12)
            np.testing.assert_array_equal(listed.history, got.history)
        with pytest.raises(ValueError, match=r"^`us` must have shape \(N, T, 1\) = \(4, 20, 1\), .* got shape \(4, 19, 1\)"):
            gf.filter(model, prior, lazy, us[:, :19])
        with pytest.raises(ValueError, match=r"^`us` must have shape \(N, T, 1\) = \(4, 20, 1\), .* got shape \(20, 1\)"):
            gf.fit(model, prior, lazy, us[0])


@pytest.mark.parametrize("run", [gf.filter, gf.smooth])
def test_a_diffuse_prior_that_takes_more_than_two_steps_to_identify(run):
    """Constant acceleration measured in position: the probe that reads the result's structure ran 2 steps, which
    do not identify 3 states, and raised NotIdentified before any chunk ran (audit X3)."""
    F = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    model = gf.LinearModel(F=F, H=[[1.0, 0.0, 0.0]], Q=0.1 * np.eye(3), R=1.0)
    zs = np.cumsum(np.random.default_rng(0).normal(size=(4, 12, 1)), axis=1)
    with dask.config.set(scheduler="synchronous"):
        got = run(model, "diffuse", da.from_array(zs, chunks=(2, 12, 1)), engine="python", check="off")
        want = run(model, "diffuse", zs, engine="python", check="off")
        np.testing.assert_array_equal(np.asarray(got.means), want.means)
        np.testing.assert_array_equal(np.asarray(got.covs), want.covs)
        assert got.means.shape == want.means.shape and got.covs.shape == want.covs.shape


@pytest.mark.parametrize("run", [gf.filter, gf.smooth])
def test_matrices_per_step_with_chunked_measurements(run):
    """An R per step filtered in memory; with dask input the probe that reads the result's structure ran a few
    steps and raised "the model is time-varying over 9 steps but `zs` has 5 steps" (review R8)."""
    T = 9
    zs = np.random.default_rng(1).normal(size=(4, T, 1))
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=0.1 * np.eye(2),
                           R=np.linspace(0.5, 2.0, T)[:, None, None])
    prior = gf.Gaussian(np.zeros(2), 10.0 * np.eye(2))
    with dask.config.set(scheduler="synchronous"):
        got = run(model, prior, da.from_array(zs, chunks=(2, T, 1)), engine="python")
        want = run(model, prior, zs, engine="python")
        assert got.means.shape == want.means.shape
        np.testing.assert_array_equal(np.asarray(got.means), want.means)
        np.testing.assert_array_equal(np.asarray(got.covs), want.covs)


def test_times_with_chunked_measurements():
    """With `times`, a dask `zs` raised "`times` must have 2 entries ..." (the probe that reads the result's shape
    ran 2 steps at the real times): a TimedModel could not be used with dask at all (audit F)."""
    rng = np.random.default_rng(1)
    zs = rng.normal(size=(4, 5, 1))
    lazy = da.from_array(zs, chunks=(2, 5, 1))
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    timed = gf.model(gf.ConstantVelocity(dim=1, q=0.5), gf.Position(dim=1, r=1.0))
    fixed = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=0.1 * np.eye(2), R=1.0, dt=1.0)
    turning = gf.model(gf.CoordinatedTurn(q_acc=0.1), gf.RangeBearing(r_range=0.5, r_bearing=0.01))
    bearings = np.column_stack([14 + 0.3 * np.arange(6.0), 0.78 + 0.01 * np.arange(6.0)])
    bearings = bearings + 0.01 * rng.normal(size=(3, 6, 2))
    tens = gf.LinearModel(F=[[1.0, 0.01], [0.0, 1.0]], H=[[1.0, 0.0]], Q=0.1 * np.eye(2), R=1.0, dt=0.01)
    cases = [(timed, prior, zs, lazy, [0.0, 1.0, 1.5, 4.0, 4.1, 7.0], {}),
             (fixed, prior, zs, lazy, np.arange(5.0), {}),
             (tens, prior, zs, lazy, 1.7e9 + 0.01 * np.arange(5.0), {}),  # a 10 ms grid of seconds since 1970
             (turning, gf.Gaussian([10.0, 10.0, 1.0, 0.5, 0.01], np.eye(5)), bearings,
              da.from_array(bearings, chunks=(1, 6, 2)), np.cumsum([0.0, 0.5, 1.0, 0.2, 2.0, 0.5]), {"method": "ukf"})]
    with dask.config.set(scheduler="synchronous"):
        for model, start, data, chunks, times, options in cases:
            for run in (gf.filter, gf.smooth):
                got, want = (run(model, start, d, times=times, **options) for d in (chunks, data))
                np.testing.assert_array_equal(np.asarray(got.means), want.means)
                np.testing.assert_array_equal(np.asarray(got.covs), want.covs)
        with pytest.raises(ValueError, match=r"^`times` must have 5 entries, one per measurement, or 6"):
            gf.filter(timed, prior, lazy, times=[0.0, 1.0, 2.0])


def test_a_chunk_spends_its_share_of_the_false_alarm_rate():
    """Each dask chunk's divergence test spent the whole 1e-3: 1,000 one-series chunks warned in 2.6% of calls on
    consistent data (audit N). A window summing to 110 (50 steps, 1 dof each) is past one test's threshold (101)
    but not that of 1,000 series' windows (130): flagged alone, not as a 1/1,000 share, nor in memory."""
    import warnings
    from types import SimpleNamespace

    from gaussfuse.inference import drivers

    nis = np.full((1, 50), 2.2)
    one = SimpleNamespace(nis=nis, innovations=np.zeros((1, 50, 1)), rejected=None)
    with pytest.warns(gf.DivergenceWarning):
        drivers.check_divergence(one, "warn")
    with warnings.catch_warnings():
        warnings.simplefilter("error", gf.DivergenceWarning)
        drivers.check_divergence(one, "warn", share=1e-3)
        many = SimpleNamespace(nis=np.concatenate([nis, np.ones((999, 50))]), innovations=np.zeros((1000, 50, 1)),
                               rejected=None)
        drivers.check_divergence(many, "warn")


@pytest.mark.parametrize("run", [gf.filter, gf.smooth])
def test_a_gate_that_loses_the_track_is_named_for_chunked_series_as_in_memory(run):
    """Every series' level jumps by 100 sd and the gate rejects every later measurement: in memory the call warns
    ("The gate rejected ..."); a dask array of the same series did not, as its chunks ran the divergence check
    without the gate (audit Q)."""
    import dask
    import dask.array as da

    model, prior = gf.LinearModel(F=1.0, H=1.0, Q=0.01, R=1.0), gf.Gaussian(0.0, 1.0)
    zs = np.array(gf.simulate(model, prior, 300, size=4, rng=0).measurements)
    zs[:, 150:] += 100.0
    with pytest.warns(gf.DivergenceWarning, match="The gate rejected"):
        run(model, prior, zs, gate=0.99)
    with dask.config.set(scheduler="synchronous"), pytest.warns(gf.DivergenceWarning, match="The gate rejected"):
        np.asarray(run(model, prior, da.from_array(zs, chunks=(2, 300, 1)), gate=0.99).means)


def test_a_pooled_fit_names_series_by_their_numbers_in_the_whole_array():
    """Audit NN1: with chunks of 3, the fit named the 6th series "series 2" (its place in its chunk) where the
    in-memory fit and the chunked filter name it 5; and an infinite value was an overflow of a series there, where
    in memory it is refused as `zs` must be finite, at its index."""
    model, prior = gf.constant_velocity(1.0, 0.5, 1.0), gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    zs = np.random.default_rng(0).normal(size=(7, 30, 1))
    zs[5, 12, 0], zs[5, 13, 0] = 1e308, -1e308
    with dask.config.set(scheduler="synchronous"):
        for data in (zs, da.from_array(zs, chunks=(3, 30, 1))):
            with warnings.catch_warnings(), pytest.raises(FloatingPointError, match=r"^in series 5, at step 12"):
                warnings.simplefilter("ignore")
                gf.fit(model, prior, data, learn=("R",), iterations=2)
        zs = np.random.default_rng(0).normal(size=(7, 30, 1))
        zs[4, 3, 0] = np.inf
        for data in (zs, da.from_array(zs, chunks=(3, 30, 1))):
            with pytest.raises(ValueError, match=r"^`zs` must be finite; got an infinite value at index \(4, 3, 0\)"):
                gf.fit(model, prior, data, learn=("R",), iterations=2)


def test_chunks_of_unknown_size_are_refused_before_the_work():
    """Audit NN2: a dask array indexed by a mask, shape (nan, T, m): the filter's graph failed at compute on an
    internal false-alarm rate of NaN, and the fit after its whole search on a NaN count."""
    model, prior = gf.constant_velocity(0.1, 1.0, 0.25), gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    zs = da.from_array(np.random.default_rng(0).normal(size=(10, 40, 1)), chunks=(3, 40, 1))
    masked = zs[zs[:, 0, 0] > -100]
    for call in (lambda: gf.filter(model, prior, masked), lambda: gf.smooth(model, prior, masked),
                 lambda: gf.fit(model, prior, masked, learn=("R",), iterations=2)):
        with pytest.raises(ValueError, match=r"^`zs` has chunks of unknown size \(shape \(nan, 40, 1\)\).*"
                                             r"compute_chunk_sizes\(\)"):
            call()
    masked.compute_chunk_sizes()
    with dask.config.set(scheduler="synchronous"):
        np.testing.assert_array_equal(gf.filter(model, prior, masked).means.compute(),
                                      gf.filter(model, prior, zs.compute()).means)


def test_times_are_checked_whole_before_any_chunk_runs():
    """Audit NN3: the times were checked against a model with fixed matrices on the probe's first steps only: times
    irregular after 20 steps were refused at compute, blamed on a chunk of series; irregular early, the message gave
    the first steps' range, not the whole series'."""
    model, prior = gf.constant_velocity(1.0, 0.5, 1.0), gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    zs = np.random.default_rng(0).normal(size=(6, 30, 1))
    late = np.arange(30.0)
    late[20:] += 0.5
    early = np.cumsum(np.random.default_rng(0).uniform(0.5, 3.0, 30))
    for times in (late, early):
        with pytest.raises(ValueError) as memory:
            gf.filter(model, prior, zs, times=times)
        with pytest.raises(ValueError) as chunked:  # when the call is made: nothing is computed
            gf.filter(model, prior, da.from_array(zs, chunks=(2, 30, 1)), times=times)
        assert str(chunked.value) == str(memory.value) and "are irregular" in str(memory.value)


def test_a_chunk_of_one_series_is_named_in_the_divergence_warning():
    """Audit NN4: a chunk holding one series of several warned "over steps 0-79" without "of series 9", which a
    call in memory and a chunk of three name."""
    model, prior = gf.constant_velocity(0.1, 1.0, 0.25), gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    zs = np.random.default_rng(0).normal(size=(10, 80, 1)).cumsum(1) * 0.05
    zs[9, 40:] += np.linspace(0.0, 200.0, 40)[:, None]  # series 9 jumps away from the model
    with pytest.warns(gf.DivergenceWarning) as memory:
        gf.filter(model, prior, zs)
    assert len(memory) == 1 and "over steps 0-79 of series 9" in str(memory[0].message)
    for chunks in (3, 1):
        with dask.config.set(scheduler="synchronous"), pytest.warns(gf.DivergenceWarning) as chunked:
            gf.filter(model, prior, da.from_array(zs, chunks=(chunks, 80, 1))).means.compute()
        assert [str(w.message) for w in chunked] == [str(w.message) for w in memory]


def test_a_dask_dataframe_is_refused_naming_zs():
    """Audit NN5: a dask DataFrame was taken for a dask array (AttributeError: no `dtype`), and a dask Series got a
    shape error showing an unevaluated expression."""
    dd = pytest.importorskip("dask.dataframe")
    pd = pytest.importorskip("pandas")
    model, prior = gf.constant_velocity(1.0, 0.5, 1.0), gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    frame = dd.from_pandas(pd.DataFrame({"z": np.arange(6.0)}), npartitions=2)
    for zs, kind in ((frame, "DataFrame"), (frame["z"], "Series")):
        for call in (gf.filter, gf.smooth):
            with pytest.raises(TypeError, match=rf"^`zs` must be a dask array of N series, \(N, T, k\); got a dask "
                                                rf"{kind}"):
                call(model, prior, zs)
        with pytest.raises(TypeError, match=rf"got a dask {kind}"):
            gf.fit(model, prior, zs, learn=("R",))


def test_dated_times_for_a_motion_counting_steps_are_refused_before_any_chunk_runs():
    """Review R44: with a TimedModel the probe steps in float seconds, so a LocalLevel given dates was refused only
    when a chunk ran, blaming that chunk's series."""
    timed = gf.model(gf.LocalLevel(q=0.5), gf.LinearSensor([[1.0]], 1.0))
    zs = da.from_array(np.random.default_rng(0).normal(size=(6, 20, 1)), chunks=(2, 20, 1))
    days = np.arange("2024-01-01", "2024-01-21", dtype="datetime64[D]")
    with pytest.raises(ValueError, match=r"^`times` gives dates or durations, but LocalLevel counts steps"):
        gf.filter(timed, gf.Gaussian([0.0], [[1.0]]), zs, times=days)  # when called: nothing computed
