"""
Many series, speed and memory
=============================

Many problems have not one series but thousands: a sensor per machine, a
price per product, a track per target. When they share a model, gaussfuse
filters them in one call. This page shows that call, what the compiled
engine buys, how to keep memory small for long series, and how to spread
the work over chunks with Dask.
"""

# %%
# A batch is a leading axis
# -------------------------
#
# Measurements of shape :math:`(N, T, m)` are :math:`N` independent series
# of :math:`T` steps. Every result gains the same leading axis: ``means``
# has shape :math:`(N, T, n)`, ``loglik`` shape :math:`(N,)`. The model here
# is a constant-velocity model measured in position (:math:`n = 2`,
# :math:`m = 1`), and ``gf.simulate(..., size=N)`` draws 2,000 series of
# 200 steps from it.

import dataclasses
import time

import dask
import dask.array as da
import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf

model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0)
prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
N, T = 2000, 200
zs = gf.simulate(model, prior, T, size=N, rng=0).measurements
print("measurements", zs.shape)

# %%
# The readable path and the compiled one
# --------------------------------------
#
# ``engine="python"`` runs :mod:`gaussfuse.kalman` step by step: it is the
# specification, easy to read and to step through. ``engine="numba"`` runs
# compiled kernels that filter the series of a batch in parallel, and agree
# with the readable path to round-off. The default, ``engine="auto"``,
# picks the compiled path only when it is expected to pay off, counting
# what the process's earlier readable calls would have saved.
#
# The kernels must first be compiled. numba caches them on disk, so a new
# process only loads them, which takes under a second; the very first use
# (an empty cache) compiles them, which takes much longer. A small warm-up
# call pays that cost before anything is timed.

start = time.perf_counter()
_ = gf.filter(model, prior, zs[:2, :10], engine="numba")
print(f"warm-up call (loading or compiling the kernels): {time.perf_counter() - start:.2f} s")

small = zs[:100]  # the readable path gets a smaller batch, to keep this page quick
runs = {}
for engine, batch in (("python", small), ("numba", small), ("numba", zs)):
    start = time.perf_counter()
    runs[engine, len(batch)] = gf.filter(model, prior, batch, engine=engine)
    seconds = time.perf_counter() - start
    steps = batch.shape[0] * batch.shape[1]
    print(f"engine={engine!r:9} {len(batch):>5} series x {T}: {seconds:7.4f} s, {steps / seconds:>11,.0f} steps/s")

readable, compiled = runs["python", 100], runs["numba", 100]
assert np.allclose(readable.means, compiled.means, rtol=0, atol=1e-9)
assert np.allclose(readable.loglik, compiled.loglik, rtol=1e-12)

# %%
# These are the speeds this run measured, on the machine that built this
# page; they vary with the machine, its load and the model, so treat them
# as an illustration. The two paths agree to 1e-9 in the means and 1e-12
# (relative) in the log-likelihoods (checked).
#
# Memory: keep only what you need
# -------------------------------
#
# By default the result holds every step's filtered and predicted means and
# covariances, innovations and their covariances, and the normalised
# innovation squared (``nis``). For :math:`N` series
# that is about :math:`N T (2n + 2n^2 + m + m^2 + 1)` numbers. With
# ``keep="last"`` it holds only the final belief of each series and the
# log-likelihood: enough to continue filtering, to forecast, or to compare
# models, in memory independent of :math:`T`.

full = gf.filter(model, prior, zs, engine="numba")
last = gf.filter(model, prior, zs, engine="numba", keep="last")
print(f"{'field':<17} {'keep=all (bytes)':>17} {'keep=last (bytes)':>18}")
for field in dataclasses.fields(full):
    kept_all, kept_last = getattr(full, field.name), getattr(last, field.name)
    if isinstance(kept_all, np.ndarray):
        size_last = "-" if kept_last is None else f"{kept_last.nbytes:,}"
        print(f"{field.name:<17} {kept_all.nbytes:>17,} {size_last:>18}")
total = {name: sum(a.nbytes for a in dataclasses.astuple(res) if isinstance(a, np.ndarray))
         for name, res in (("all", full), ("last", last))}
print(f"total: {total['all'] / 1e6:.1f} MB with keep='all', {total['last'] / 1e6:.3f} MB with keep='last'")
n, m = model.n, model.m
assert abs(total["all"] / (8 * N * T * (2 * n + 2 * n**2 + m + m**2 + 1)) - 1) < 0.01  # the count above
assert np.array_equal(full.last_mean, last.last_mean) and np.array_equal(full.loglik, last.loglik)

# %%
# The same in a figure: the memory each kept field takes, per series, for
# ``keep="all"`` (every step) and ``keep="last"`` (the last belief and the
# log-likelihood).

sizes = {f.name: getattr(full, f.name).nbytes / N for f in dataclasses.fields(full)
         if isinstance(getattr(full, f.name), np.ndarray)}
kept = {name: (getattr(last, name).nbytes / N if isinstance(getattr(last, name), np.ndarray) else 0.0)
        for name in sizes}
fig, ax = plt.subplots(figsize=(7.0, 3.2), layout="constrained")
y = np.arange(len(sizes))
ax.barh(y - 0.2, list(sizes.values()), height=0.4, label='keep="all"')
ax.barh(y + 0.2, list(kept.values()), height=0.4, label='keep="last"')
ax.set(yticks=y, yticklabels=list(sizes), xscale="symlog", xlabel="bytes per series",
       title=f"What a filter result holds, {T} steps, n = {n}, m = {m}")
ax.legend(loc="lower right")

# %%
# The count above matches the total to 1 % (checked), and the final
# beliefs and log-likelihoods are the same either way (checked, bit for
# bit).
#
# A long series in chunks
# -----------------------
#
# The prior is "the belief before the first measurement", so a filter can
# stop and start again: filter a chunk, and give its last belief,
# ``res.last`` (or ``res.last_mean`` and ``res.last_cov``), as the prior of
# the next chunk. A series too long for memory, or one that arrives in
# pieces, is filtered this way with the same result as one pass. The
# log-likelihoods of the chunks add up to that of the whole series.

long_series = gf.simulate(model, prior, 20_000, rng=1).measurements
one_pass = gf.filter(model, prior, long_series, engine="numba", keep="last")
belief, loglik = prior, 0.0
for chunk in np.array_split(long_series, 5):
    res = gf.filter(model, belief, chunk, engine="numba", keep="last")
    belief, loglik = gf.Gaussian(res.last_mean, res.last_cov), loglik + res.loglik
print(f"one pass: loglik {one_pass.loglik:.6f}; five chunks: {loglik:.6f}")
assert np.allclose(belief.mean, one_pass.last_mean, rtol=1e-12, atol=1e-9)
assert np.allclose(belief.cov, one_pass.last_cov, rtol=1e-12, atol=1e-15)
assert np.isclose(loglik, one_pass.loglik, rtol=1e-12)

# %%
# The chunked run ends at the same belief and log-likelihood as one pass,
# to round-off (checked to 1e-12 relative): the sums are not taken in the
# same order, so the last bits may differ.
#
# Scaling out with Dask
# ---------------------
#
# A dask array of shape :math:`(N, T, m)`, chunked over the series (every
# chunk holds whole series), is filtered chunk by chunk. ``gf.filter``
# returns at once, with dask arrays in the result: nothing is computed until
# asked, and ``dask.compute`` computes the fields asked for in one pass over
# the chunks. Each chunk runs the same batch path as an in-memory array, so
# the results are the same, series for series. Here dask runs the chunks on
# its default scheduler, threads in this process.

lazy_zs = da.from_array(zs, chunks=(500, T, 1))
lazy = gf.filter(model, prior, lazy_zs, engine="numba", keep="last")
print("before compute:", lazy.last_mean)
last_mean, lazy_loglik = dask.compute(lazy.last_mean, lazy.loglik)
assert np.array_equal(last_mean, last.last_mean) and np.array_equal(lazy_loglik, last.loglik)
print("after compute:", type(last_mean).__name__, last_mean.shape, "equal to the in-memory result")

# %%
# The results are bit for bit those of the in-memory call (checked, both
# with ``engine="numba"``). On a cluster, create a ``distributed.Client``
# first and the same code runs on its workers. From the command line, a
# long-format table with a series column (a CSV or Parquet file, or a
# directory of them) is filtered partition by partition with
# ``gaussfuse filter DATA -m model.toml --series-column id --out DIR``. The
# page :doc:`/performance` (its section "Many series on a Dask cluster")
# explains how to size the chunks, the memory each one needs, and what a
# cluster does and does not buy on one machine.
