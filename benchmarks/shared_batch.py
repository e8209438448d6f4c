"""Batches of series that share one model: compiled throughput, where a chunk computes its covariances once.

    python benchmarks/shared_batch.py

First two batches whose models never reach a covariance fixed point within
the series (so every step of every series would compute its covariance):
2,000 series x 200 steps of a 2-state model whose F and Q change with the
step, and 20 series x 200 steps of a 64-state random walk. Then W2's batch
(``benchmarks/run.py``: 2,000 series x 200 steps), filtered and smoothed in
both forms. Prints steps/s (series x steps), best of several calls after a
warm-up, the calls back to back (``run.py`` interleaves other libraries'
calls between them). Run it on two versions of gaussfuse to compare them.
"""
import time

import numpy as np

import gaussfuse as gf


def best_rate(model, prior, zs, calls, run=gf.filter, **options):
    """Series x steps per second of ``run(model, prior, zs, engine="numba", **options)``, best of `calls`."""
    run(model, prior, zs[:2], engine="numba", **options)  # compile or load
    best = float("inf")
    for _ in range(calls):
        start = time.perf_counter()
        run(model, prior, zs, engine="numba", **options)
        best = min(best, time.perf_counter() - start)
    return zs.shape[0] * zs.shape[1] / best


rng = np.random.default_rng(1)
T = 200
dts = 0.5 + rng.random(T)
F = np.stack([[[1.0, d], [0.0, 1.0]] for d in dts])
Q = np.stack([0.1 * np.array([[d**3 / 3, d**2 / 2], [d**2 / 2, d]]) for d in dts])
small = gf.LinearModel(F, [[1.0, 0.0]], Q, 1.0)
rate = best_rate(small, gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2)), np.cumsum(rng.normal(size=(2000, T, 1)), axis=1), 15)
print(f"2,000 series x {T} steps, 2 states, time-varying F and Q: {rate / 1e6:.2f} M steps/s")
n, m = 64, 32
large = gf.LinearModel(np.eye(n), np.eye(m, n), 0.1 * np.eye(n), np.eye(m))
rate = best_rate(large, gf.Gaussian(np.zeros(n), np.eye(n)), rng.normal(size=(20, T, m)), 3)
print(f"20 series x {T} steps, {n} states, {m} measurements (random walk): {rate / 1e3:.1f} k steps/s")
w2 = gf.constant_velocity(dt=1.0, q=0.1, r=1.0, dim=1)
zs = np.random.default_rng(7).normal(size=(2000, T, 1)).cumsum(axis=1)
prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
for form in ("cov", "sqrt"):
    for run, what in ((gf.filter, "filter"), (gf.smooth, "smoother")):
        rate = best_rate(w2, prior, zs, 7, run, form=form)
        print(f"2,000 series x {T} steps, W2's model, {what}, form={form!r}: {rate / 1e6:.2f} M steps/s")
