r"""
Smoothing, missing data and the log-likelihood
==============================================

The filter's estimate at step k uses the measurements up to step k only: it
is what an online system can know. Offline, once the whole series is in, the
later measurements say something about the earlier states too. The
Rauch–Tung–Striebel (RTS) smoother adds that information in one backward
pass. This page simulates a track with a stretch of missing measurements,
filters and smooths it, and then looks at the log-likelihood the filter
computes on the way, the quantity used to learn a model's noise from data.
"""

import matplotlib.pyplot as plt
import numpy as np
from scipy.stats import multivariate_normal

import gaussfuse as gf
from gaussfuse import kalman
from gaussfuse.plotting import plot_series

# %%
# A track with a gap
# ------------------
#
# :func:`gaussfuse.constant_velocity` is the nearly-constant-velocity model:
# the state is position and velocity, the velocity wanders as a random walk
# driven by white-noise acceleration of spectral density ``q`` (m²/s³), and
# the position is measured with variance ``r`` (m²) every ``dt`` seconds.
# :func:`gaussfuse.simulate` draws a true track and its measurements. We then
# delete 15 seconds of measurements, the 30 from 25.5 s to 40 s, by setting
# them to NaN: a NaN measurement is missing, and the filter only predicts
# there.

dt, q, r, T = 0.5, 0.2, 1.0, 120
model = gf.constant_velocity(dt, q, r)
prior = gf.Gaussian([0.0, 1.0], np.diag([4.0, 1.0]))
sim = gf.simulate(model, prior, T, rng=0)
truth = sim.states[:, 0]
times = dt * np.arange(1, T + 1)

zs = sim.measurements.copy()  # the simulation's arrays are read-only
gap = np.arange(50, 80)
zs[gap] = np.nan
observed = ~np.isnan(zs[:, 0])

res = gf.filter(model, prior, zs)
sm = gf.smooth(model, prior, zs)
filt_std, smooth_std = np.sqrt(res.covs[:, 0, 0]), np.sqrt(sm.covs[:, 0, 0])

fig, (ax, ax_std) = plt.subplots(2, 1, figsize=(8.0, 6.5), sharex=True, layout="constrained",
                                 gridspec_kw={"height_ratios": [2, 1]})
plot_series(times, res.means, res.covs, zs=zs, truth=truth, ax=ax, label="filtered", ylabel="position",
            unit="m", xlabel="")
plot_series(times, sm.means, sm.covs, ax=ax, label="smoothed", ylabel="position", unit="m", xlabel="")
ax.set_title("Filtered and smoothed positions with ±2σ bands; no measurements in the grey span")
ax_std.plot(times, filt_std, label="filtered")
ax_std.plot(times, smooth_std, label="smoothed")
ax_std.set(xlabel="time (s)", ylabel="std of position (m)")
ax_std.legend(fontsize="small")
for a in (ax, ax_std):
    a.axvspan(times[gap[0]], times[gap[-1]], color="0.9", zorder=0)

# %%
# In the gap the filter can only extrapolate: its band widens at every step
# (checked), and its estimate drifts along the last estimated velocity. The
# smoother knows where the track comes out of the gap, so it bridges the gap
# with a band that is widest in the middle. Everywhere, the smoother's
# covariance is at most the filter's: :math:`P_k - P^s_k` is positive
# semi-definite at every step (checked), since it conditions on more data.

assert np.all(np.diff(filt_std[gap]) > 0)
for P_f, P_s in zip(res.covs, sm.covs):
    assert np.linalg.eigvalsh(P_f - P_s).min() > -1e-12 * np.trace(P_f)


def rmse(estimate, steps):
    return np.sqrt(np.mean((estimate[steps] - truth[steps]) ** 2))


print("position RMSE (m)   observed steps   gap    all steps")
print(f"measurements        {rmse(zs[:, 0], observed):14.3f}")
for name, est in (("filter", res.means[:, 0]), ("smoother", sm.means[:, 0])):
    print(f"{name:19s} {rmse(est, observed):14.3f} {rmse(est, gap):6.3f} {rmse(est, slice(None)):11.3f}")
assert rmse(sm.means[:, 0], slice(None)) < rmse(res.means[:, 0], slice(None))
assert rmse(sm.means[:, 0], observed) < rmse(res.means[:, 0], observed) < rmse(zs[:, 0], observed)

# %%
# On this draw the smoother beats the filter, which beats the raw
# measurements (checked). That is what happens on average; on a single
# track, and especially across a gap, one run can be luckier than another.
# The covariance comparison above holds for every draw.
#
# The RTS backward recursion
# --------------------------
#
# The smoother starts from the filter's last belief,
# :math:`(m^s_T, P^s_T) = (m_T, P_T)`, and goes back in time. At step k it
# compares the smoothed belief about :math:`x_{k+1}` with the filter's
# prediction of it, :math:`(m^-_{k+1}, P^-_{k+1})`, and passes the correction
# back through the smoother gain :math:`G_k`:
#
# .. math::
#
#    G_k &= P_k F^\top (P^-_{k+1})^{-1}, \\
#    m^s_k &= m_k + G_k (m^s_{k+1} - m^-_{k+1}), \\
#    P^s_k &= P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top.
#
# :math:`P_k F^\top` is the covariance of :math:`x_k` and :math:`x_{k+1}`
# given the data up to k. Since :math:`P^s_{k+1} \preceq P^-_{k+1}`, the
# second term of :math:`P^s_k` is negative semi-definite: that is why
# smoothing never increases a variance. :func:`gaussfuse.kalman.rts_step` is one step; the
# loop below runs the whole backward pass from the filter's output and gives
# :func:`gaussfuse.smooth`'s result (checked to 1e-10).

F = model.F
m_s, P_s = [res.means[-1]], [res.covs[-1]]
for k in range(T - 2, -1, -1):
    m, P, _ = kalman.rts_step(res.means[k], res.covs[k], res.predicted_means[k + 1], res.predicted_covs[k + 1],
                              m_s[0], P_s[0], res.covs[k] @ F.T)
    m_s.insert(0, m)
    P_s.insert(0, P)
assert np.allclose(m_s, sm.means, rtol=1e-10, atol=1e-10)
assert np.allclose(P_s, sm.covs, rtol=1e-10, atol=1e-10)

# %%
# The log-likelihood
# ------------------
#
# The filter also scores the model. Each innovation
# :math:`v_k = z_k - H m^-_k` is, under the model, Gaussian with mean 0 and
# covariance :math:`S_k = H P^-_k H^\top + R`, independent of the earlier
# ones. So the probability density of the whole series factors into one term
# per step:
#
# .. math::
#
#    \log p(z_1, \dots, z_T) = \sum_k \log N(v_k; 0, S_k)
#    = -\tfrac12 \sum_k \left( v_k^\top S_k^{-1} v_k + \log\det S_k + d_k \log 2\pi \right),
#
# summed over the steps with a measurement, with :math:`d_k` the number of
# observed components (a missing measurement adds nothing).
# ``res.loglik`` is this sum; we recompute it from ``res.innovations`` and
# ``res.innovation_covs`` with :mod:`scipy.stats` (checked to 1e-10).

terms = [multivariate_normal.logpdf(res.innovations[k], mean=np.zeros(1), cov=res.innovation_covs[k])
         for k in np.flatnonzero(observed)]
print(f"res.loglik = {res.loglik:.6f}; sum of {len(terms)} innovation log-densities = {np.sum(terms):.6f}")
assert abs(res.loglik - np.sum(terms)) < 1e-10

# %%
# The log-likelihood measures how well a model predicts the data it has not
# yet seen, so it can compare models. The same measurements filtered with a
# process noise ten times the one that generated them:

loglik = {q_try: gf.filter(gf.constant_velocity(dt, q_try, r), prior, zs).loglik for q_try in (q, 10 * q)}
for q_try, value in loglik.items():
    print(f"q = {q_try:4.1f} m²/s³: log-likelihood {value:9.3f}")
assert loglik[q] > loglik[10 * q]

# %%
# The true ``q`` gives the higher log-likelihood on this series (checked).
# Turned around, this is how unknown noise variances are learned: choose the
# ``q`` and ``r`` that maximise the log-likelihood of the measurements.
# :func:`gaussfuse.fit` does that, by maximum likelihood or by EM; see
# :ref:`sphx_glr_auto_tutorial_t07_learning.py`.
