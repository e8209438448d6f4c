"""
Irregular timestamps and pandas
===============================

How do I filter measurements that arrive at irregular times, straight from a
pandas DataFrame? Build the model with ``gf.model(motion, sensor)`` and no
``dt``. That gives a :class:`~gaussfuse.TimedModel`, which is
discretised exactly for each step's own time step. Then pass the times as
``times=`` (float seconds, ``datetime64`` values or a pandas
``DatetimeIndex``), or pass a DataFrame whose index is a ``DatetimeIndex``
as ``zs``. ``result.to_pandas()`` returns the estimates as a DataFrame with
the same index.

A model with fixed matrices (one built with ``dt``) accepts only regular
times. Given irregular ones, it raises an error that says how to fix it.
"""

import warnings

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import gaussfuse as gf
from gaussfuse.diagnostics import rmse
from gaussfuse.plotting import plot_series

# %%
# A model without a time step
# ---------------------------
#
# A car moves in the plane with nearly constant velocity. The noise density
# of its acceleration is ``q``. A GPS measures its position with a variance
# of 9 m² per axis. Without ``dt``, :func:`gaussfuse.model` returns a
# ``TimedModel``. Its ``at`` method shows the matrices for given steps: here
# the entry of ``F`` that adds ``dt`` times the velocity to the position.

motion, gps = gf.ConstantVelocity(dim=2, q=0.05), gf.Position(dim=2, r=9.0)
track = gf.model(motion, gps)
print(track)
print("F[x, vx] for steps of 0.5 s and 2 s:", track.at([0.5, 2.0])[0].F[:, 0, 2])

# %%
# A track with gaps
# -----------------
#
# The GPS gives a fix every second, but some fixes are lost, so the gaps
# between rows are 1, 3 or 6 s. We simulate the true states and the fixes at
# those times with :func:`gaussfuse.simulate`, which takes the same
# ``times=``. With T times for T measurements, the prior is one step of
# ``times[1] - times[0]`` before the first measurement.

rng = np.random.default_rng(4)
seconds = np.concatenate([[0.0], np.cumsum(rng.choice([1.0, 1.0, 1.0, 3.0, 6.0], size=120))])
prior = gf.Gaussian([0.0, 0.0, 8.0, 2.0], np.eye(4))
sim = gf.simulate(track, prior, len(seconds), times=seconds, rng=rng)
fixes, truth = sim.measurements, sim.states
print(f"{len(seconds)} fixes over {seconds[-1]:.0f} s; steps from {np.diff(seconds).min():.0f} "
      f"to {np.diff(seconds).max():.0f} s")

# %%
# Three ways to give the times
# ----------------------------
#
# Float seconds, ``datetime64`` values and a ``DatetimeIndex`` describe the
# same instants, so they give the same estimates. The code checks that the
# three smoothed means agree to 1e-9.

start = np.datetime64("2026-05-01T08:00:00")
as_datetime64 = start + (seconds * 1000).astype("timedelta64[ms]")
as_index = pd.DatetimeIndex(as_datetime64)

by_seconds = gf.smooth(track, prior, fixes, times=seconds)
by_datetime64 = gf.smooth(track, prior, fixes, times=as_datetime64)
by_index = gf.smooth(track, prior, fixes, times=as_index)
assert np.allclose(by_datetime64.means, by_seconds.means, rtol=0, atol=1e-9)
assert np.allclose(by_index.means, by_seconds.means, rtol=0, atol=1e-9)

# %%
# A DataFrame in, a DataFrame out
# -------------------------------
#
# A DataFrame with a ``DatetimeIndex`` supplies the times itself. The result's
# ``to_pandas()`` has the same index and one column per state component
# (named by the motion: ``x, y, vx, vy``), plus a standard deviation
# ``<name>_sd`` for each.

log = pd.DataFrame(fixes, columns=["x", "y"], index=as_index)
smoothed = gf.smooth(track, prior, log)
table = smoothed.to_pandas()
print(table[["x", "y", "vx", "x_sd", "vx_sd"]].head().round(2))
assert table.index.equals(log.index)
assert np.allclose(table[["x", "y", "vx", "vy"]].to_numpy(), by_seconds.means, rtol=0, atol=1e-9)

# %%
# An empty cell (NaN or ``pd.NA``) is a missing value: that component is left
# out of that step's update. The code checks that the innovation of the
# emptied cell is NaN and that of the other component is not.

gappy = log.astype("Float64")
gappy.iloc[5, 0] = pd.NA
innovation = gf.filter(track, prior, gappy).innovations[5]
print("innovation at row 5 (x missing):", innovation.round(2))
assert np.isnan(innovation[0]) and not np.isnan(innovation[1])

# %%
# The error for a fixed-dt model
# ------------------------------
#
# A model built with ``dt=1.0`` has one ``F`` and one ``Q``. Given the
# DataFrame's irregular times, it refuses them and says what to do.

per_second = gf.model(motion, gps, dt=1.0)
try:
    gf.filter(per_second, prior, log)
except ValueError as error:
    print(error)

# %%
# Why the time stamps matter
# --------------------------
#
# Given the bare array, without times, the fixed-dt model takes every row as
# one second: it counts rows. Across a 6 s gap it expects the car to move one
# second's distance, so it drags the track behind the fixes. Its innovations
# are then far too large for its own covariances, and the divergence check
# (on by default) warns; we catch the warning and print it. The model that
# reads the time stamps steps by the true dt. The code checks that its RMSE
# is smaller than that of the row-counting model and of the raw fixes.

with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always", gf.DivergenceWarning)
    counted = gf.smooth(per_second, prior, fixes)
for warning in caught:
    print(f"{warning.category.__name__}: {warning.message}")

error_fixes = rmse(fixes, truth[:, :2])
error_counted = rmse(counted.means[:, :2], truth[:, :2])
error_stamped = rmse(smoothed.means[:, :2], truth[:, :2])
print(f"RMSE of the position: raw fixes {error_fixes:.2f} m, rows counted as 1 s {error_counted:.2f} m, "
      f"time stamps read {error_stamped:.2f} m")
assert error_stamped < error_fixes < error_counted

# %%
# The figure shows the error of the x coordinate (estimate minus truth) over
# the first two minutes, with ±2σ bands: the fixes, and both smoothers. The
# row-counting smoother swings away from the truth at the long gaps, far
# outside its own band (after 12 of the 14 six-second gaps; 92 % of its
# steps in these two minutes lie outside ±2σ).

fig, ax = plt.subplots(figsize=(7.5, 3.5), layout="constrained")
first = seconds <= 120
plot_series(seconds[first], counted.means[first] - truth[first], counted.covs[first], ax=ax,
            label="rows counted")
plot_series(seconds[first], smoothed.means[first] - truth[first], smoothed.covs[first],
            zs=fixes[first] - truth[first, :2], ax=ax, label="time stamps read", ylabel="error in x",
            unit="m", time_unit="s")
ax.set_title("Smoothing a track with gaps: error of the x coordinate")
plt.show()
